"""Rolling shutter under camera shake, measured per clip (issue 14 item 5).

For every keyframe pair the ego-motion estimator solves, :func:`~deepcrashtest.geometry.egomotion.rolling_shutter_fit`
compares one rotation with a rotation that changes linearly from the top row to the bottom one, both fitted to
the static points' flow across the direction of travel (which a translation does not move). Printed per clip: the
pairs, the median robust residual (px, at the estimator's work resolution, <= 960 px wide) of each model, the share
of pairs whose residual the row-varying rotation lowers by >= 15 %, and the median flow (px) of its top-to-bottom
change. A global shutter (KITTI's cameras) shows no gain and a change at the noise level; a rolling shutter under
shake shows both. The estimator runs as ``bench/ego_speed_overlays.py`` runs it (default camera with the first
2 s' horizon for crash clips, the chessboard camera for the Udacity highway clip, KITTI's calibration; no road
user masked), its output unchanged (the fit only looks at the pairs) and its median speed printed. ``--correct G``:
in pairs where the row-varying rotation lowers the residual by at least the share ``G``, its flow is taken out of
every point (against the middle row) before the pair is solved (the measured-not-kept experiment of the README).

Run: PYTHONPATH=src python bench/rolling_shutter.py [--clips seq00,ccd_000014] [--frames N] [--set NAME=X]
[--correct G]
"""

from __future__ import annotations

import argparse
from pathlib import Path
from typing import Any

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
DATA = ROOT.parent / "shared" / "data"
CLIPS = {
    "seq00": "kitti_odometry/seq00_frames0000-0159",
    "seq06": "kitti_odometry/seq06_frames0000-0050",
    "highway": "dashcam_udacity/highway_project_video.mp4",
    "ccd_000014": "crash_ccd/ccd_000014.mp4",
    "ccd_000053": "crash_ccd/ccd_000053.mp4",
    "ccd_000080": "crash_ccd/ccd_000080.mp4",
    "ccd_000755": "crash_ccd/ccd_000755.mp4",
    "dad_000487": "crash_dad/dad_000487.mp4",
}

#: The focus of expansion is searched this share of the image height either side of the learned travel's
#: (:func:`~deepcrashtest.geometry.rolling_shutter.rolling_shutter_fit`'s ``search_px``).
SEARCH_SHARE = 0.11


def load(name: str, frames: int) -> tuple[list[np.ndarray], float, Any, int]:
    """(images, fps, camera, dashboard rows) of one clip, as the speed benches run it."""
    import cv2

    from deepcrashtest.geometry.camera import calibrate_chessboard, default_camera
    from deepcrashtest.pipeline.geometry_pass import estimate_camera
    from deepcrashtest.scenario import Camera

    path = DATA / CLIPS[name]
    if path.is_dir():  # KITTI odometry: grey frames, calibrated camera
        from deepcrashtest.datasets.kitti.files import KITTI_CAMERA_HEIGHT_M
        from deepcrashtest.eval.egomotion import read_odometry_calib

        files = sorted((path / "image_0").glob("*.png"))[:frames]
        K = read_odometry_calib(path)
        cam = Camera(fx=K[0, 0], fy=K[1, 1], cx=K[0, 2], cy=K[1, 2], height_m=KITTI_CAMERA_HEIGHT_M)
        return [cv2.imread(str(f), cv2.IMREAD_GRAYSCALE) for f in files], 10.0, cam, 0
    from ego_speed_overlays import read_frames  # (bench/, the script's own folder)

    images, fps = read_frames(path, frames)
    h, w = images[0].shape[:2]
    cam = default_camera(w, h)
    if name == "highway":
        calib, _, _ = calibrate_chessboard(path.parent / "camera_calibration")
        cam = calib.model_copy(update={"height_m": cam.height_m})
    cam, rows, _ = estimate_camera(images[: int(2 * fps) + 1], cam)
    return images, fps, cam, rows


def measure(name: str, frames: int, options: dict[str, float], correct: float) -> str:
    import cv2

    from deepcrashtest.geometry.egomotion import EgoMotionEstimator
    from deepcrashtest.geometry.rolling_shutter import RollingShutterFit, rolling_shutter_fit

    cv2.setNumThreads(2)
    images, fps, cam, rows = load(name, frames)
    fits: list[RollingShutterFit] = []
    corrected = [0]

    class Probe(EgoMotionEstimator):
        """The estimator, each keyframe pair's static scene points measured (and, with ``correct``, the pair's
        row-varying rotation taken out of every point before it is solved)."""

        def _solve(self, p0: np.ndarray, p1: np.ndarray, h: int, moving: bool = False, parallax: float = 0.0) -> Any:
            assert self._K is not None
            K, tr = self._K, self._travel
            foe = (float(K[0, 2]), self._horizon_row())
            if tr is not None and tr[2] > 0.5:
                foe = (float(K[0, 2] + K[0, 0] * tr[0] / tr[2]), float(K[1, 2] + K[1, 1] * tr[1] / tr[2]))
            scene = ~self._road_region(p0[:, 0], p0[:, 1], h) & (np.linalg.norm(p1 - p0, axis=1) > 0.3)
            fit = rolling_shutter_fit(p0[scene], p1[scene], K, foe, h, search_px=SEARCH_SHARE * h)
            if fit is not None:
                fits.append(fit)
                if correct > 0 and fit.rolling_px <= (1.0 - correct) * fit.global_px:
                    p1 = (p1 - fit.row_flow(p0, K, h)).astype(p1.dtype)
                    corrected[0] += 1
            return super()._solve(p0, p1, h, moving, parallax)

    est = Probe(cam, mask_bottom_rows=rows, **options)  # type: ignore[arg-type]
    for i, img in enumerate(images):
        est.update(img, i / fps)
    if not fits:
        return f"{name:12} no pair measured"
    assert est._K is not None  # noqa: SLF001
    g = np.array([f.global_px for f in fits])
    r = np.array([f.rolling_px for f in fits])
    k = np.array([f.change_px(est._K) for f in fits])  # noqa: SLF001
    speed = float(np.median(est.result().speed[1:])) * 3.6
    return (
        f"{name:12} {len(images):4d} {len(fits):5d} {np.median(g):9.2f} {np.median(r):9.2f} "
        f"{100 * np.mean(r <= 0.85 * g):7.0f} % {np.median(k):9.1f} {speed:9.1f} {corrected[0]:9d}"
    )


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--clips", default=",".join(CLIPS), help="comma-separated names of " + ", ".join(CLIPS))
    ap.add_argument("--frames", type=int, default=60, help="frames per clip (from the first)")
    ap.add_argument("--set", action="append", default=[], help="estimator option NAME=NUMBER (repeatable)")
    ap.add_argument("--correct", type=float, default=0.0, help="take the row-varying rotation out at this gain")
    args = ap.parse_args()
    options = {k: float(v) for k, v in (o.split("=", 1) for o in args.set)}
    print(
        f"{'clip':12} {'frm':>4} {'pairs':>5} {'1 rot px':>9} {'row-var':>9} {'gain>=15%':>9} "
        f"{'change px':>9} {'km/h med':>9} {'corrected':>9}"
    )
    for name in filter(None, args.clips.split(",")):
        print(measure(name, args.frames, options, args.correct), flush=True)


if __name__ == "__main__":
    main()
