"""Road-scale speed readings against KITTI odometry ground truth, thinned to dashcam-like sparsity.

On city dashcam clips the ego speed filter gets few road-scale readings (a few of 40-100 frame pairs), each
from 12-30 road points, and they scatter 2-4x beyond the 1-sigma they state (``bench/speed_filter_readings.py``).
This bench asks the same of a speed truth: it runs :class:`~deepcrashtest.geometry.egomotion.EgoMotionEstimator`
over the shared KITTI odometry frames (calibrated camera, ground-truth poses) and

* ``--road-points N`` (repeatable; 0 = all): each road-plane fit sees at most N of its road points (a seeded
  random subset per fit), the density of a city clip's road;
* ``--keep K`` (repeatable; 1 = all): the speed filter gets only every K-th reading (the others are dropped
  before the filter, the tracking is unchanged), the sparsity of a city clip's readings in time.

Printed per sequence and setting: the readings' count, the median number of road inliers, the normalised
residuals ``(reading - truth) / stated sigma`` (robust scale 1.4826 MAD, the share beyond 3, and the median
``|residual| / truth`` in %) and the smoothed output's median speed error (``eval.egomotion``) and the filter's
outcomes (gated / restart). A stated sigma that matches the scatter gives a robust scale near 1.
The truth of a reading is the camera's distance between its keyframe and its frame over the time between.

Run: PYTHONPATH=src python bench/road_scale_scatter.py [--road-points 0 --road-points 15] [--keep 1 --keep 8]
[--seed 0] [--set OPTION=X]
"""

from __future__ import annotations

import argparse
from itertools import product
from pathlib import Path
from typing import Any

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
DATA = ROOT.parent / "shared" / "data" / "kitti_odometry"


def run(
    images: list[np.ndarray],
    poses: np.ndarray,
    times: np.ndarray,
    K: np.ndarray,
    road_points: int,
    keep: int,
    seed: int,
    options: dict[str, Any],
    focal_ratio: float = 1.0,
) -> dict[str, Any]:
    """One estimator run over the frames with the thinning; readings against the truth and the output's errors."""
    from deepcrashtest.datasets.kitti.files import KITTI_CAMERA_HEIGHT_M
    from deepcrashtest.eval.egomotion import egomotion_errors
    from deepcrashtest.geometry import egomotion
    from deepcrashtest.scenario import Camera

    rng = np.random.default_rng(seed)
    fit = egomotion.fit_plane_motion

    def thinned(x0: np.ndarray, p1: np.ndarray, *a: Any, **kw: Any) -> Any:
        if road_points > 0 and len(x0) > road_points:
            pick = np.sort(rng.choice(len(x0), road_points, replace=False))
            x0, p1 = x0[pick], p1[pick]
        return fit(x0, p1, *a, **kw)

    f, h = K[0, 0] * focal_ratio, KITTI_CAMERA_HEIGHT_M / focal_ratio  # the same focal x height: the same scale
    cam = Camera(fx=f, fy=K[1, 1] * focal_ratio, cx=K[0, 2], cy=K[1, 2], height_m=h)
    est = egomotion.EgoMotionEstimator(cam, **options)
    step = est._filter.step  # noqa: SLF001 (the bench thins what the filter is given)
    count = [0]

    def sparse_step(dt: float, z: float | None, var: float) -> float:
        if z is not None:
            count[0] += 1
            if (count[0] - 1) % keep:
                z = None
        return step(dt, z, var)

    est._filter.step = sparse_step  # type: ignore[method-assign]  # noqa: SLF001
    centre = poses[:, :3, 3]
    rows = []
    egomotion.fit_plane_motion = thinned  # type: ignore[assignment]
    try:
        for img, t in zip(images, times, strict=True):
            kf_time, before = est._kf_time, len(est._filter.readings)  # noqa: SLF001
            state = est.update(img, float(t))
            if len(est._filter.readings) > before and state.raw_speed:  # noqa: SLF001
                _, z, var, _ = est._filter.readings[-1]  # noqa: SLF001
                k0, k1 = int(np.argmin(np.abs(times - kf_time))), int(np.argmin(np.abs(times - t)))
                truth = float(np.linalg.norm(centre[k1] - centre[k0])) / max(float(t - kf_time), 1e-3)
                rows.append((z, var, truth, state.road_points))
    finally:
        egomotion.fit_plane_motion = fit  # type: ignore[assignment]
    outcomes = [o for *_, o in est._filter.readings]  # noqa: SLF001
    r = np.array(rows).reshape(-1, 4)
    moving = r[:, 2] > 1.0
    norm = (r[moving, 0] - r[moving, 2]) / np.sqrt(r[moving, 1])
    rel = np.abs(r[moving, 0] - r[moving, 2]) / r[moving, 2]
    errors = egomotion_errors(est.result(), poses, times)
    return {
        "readings": int(moving.sum()),
        "inliers": float(np.median(r[moving, 3])) if moving.any() else 0.0,
        "scale": 1.4826 * float(np.median(np.abs(norm))) if len(norm) else float("nan"),
        "beyond3": float(np.mean(np.abs(norm) > 3)) if len(norm) else float("nan"),
        "rel_pct": 100 * float(np.median(rel)) if len(rel) else float("nan"),
        "speed_err": errors["speed_error_median_pct"],
        "dist_err": errors["distance_error_pct"],
        "yaw": errors["yaw_drift_deg_per_100m"],
        "gated": outcomes.count("gated"),
        "restart": outcomes.count("restart"),
    }


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--data", default=str(DATA))
    ap.add_argument("--road-points", type=int, action="append", default=[], help="at most N road points per fit")
    ap.add_argument("--keep", type=int, action="append", default=[], help="the filter gets every K-th reading")
    ap.add_argument("--seed", type=int, action="append", default=[], help="thinning seed (repeatable)")
    ap.add_argument("--focal", type=float, action="append", default=[], help="assumed over true focal (repeatable)")
    ap.add_argument("--set", action="append", default=[], help="estimator option NAME=NUMBER (repeatable)")
    args = ap.parse_args()
    import cv2

    from deepcrashtest.datasets.kitti.files import read_poses
    from deepcrashtest.eval.egomotion import frame_times, read_odometry_calib

    cv2.setNumThreads(2)
    options = {k: float(v) for k, v in (o.split("=", 1) for o in args.set)}
    print(
        f"{'sequence':26} {'pts':>4} {'keep':>4} {'seed':>4} {'f':>4} {'n':>4} {'inl':>5} {'scale':>6} {'>3sd':>5} "
        f"{'|e|/v %':>7} {'out err %':>9} {'dist %':>6} {'yaw/100m':>8} {'gated':>5} {'rest':>4}"
    )
    for folder in sorted(p for p in Path(args.data).iterdir() if (p / "poses.txt").exists()):
        images = [cv2.imread(str(p), cv2.IMREAD_GRAYSCALE) for p in sorted((folder / "image_0").glob("*.png"))]
        poses = read_poses(folder / "poses.txt")[: len(images)]
        times = frame_times(folder, len(images))
        K = read_odometry_calib(folder)
        grid = product(args.road_points or [0], args.keep or [1], args.seed or [0], args.focal or [1.0])
        for n, keep, seed, focal in grid:
            s = run(images, poses, times, K, n, keep, seed, options, focal)
            print(
                f"{folder.name:26} {n:4d} {keep:4d} {seed:4d} {focal:4.2f} {s['readings']:4d} {s['inliers']:5.0f} "
                f"{s['scale']:6.2f} {s['beyond3']:5.2f} {s['rel_pct']:7.1f} {s['speed_err']!s:>9} "
                f"{s['dist_err']!s:>6} {s['yaw']!s:>8} {s['gated']:5d} {s['restart']:4d}",
                flush=True,
            )


if __name__ == "__main__":
    main()
