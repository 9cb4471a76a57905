"""One metric scale from many frame pairs at once (issue 14 item 5): diagnosis of the road-scale conditioning.

The estimator (:class:`~deepcrashtest.geometry.egomotion.EgoMotionEstimator`) gives one road-scale reading per
keyframe pair, from a 3-parameter road-plane homography fit on that pair's road points, and the speed filter
fuses them. On the 10 fps CCD clips most pairs keep too few road points for a reading, and the few readings
swing with a 1 % change of the camera. This bench records every keyframe pair the estimator solves (its road
points, rotation, translation direction, time span) and fits the speed of the whole clip, or of sliding windows,
in ONE robust fit over all the pairs' road points (:func:`deepcrashtest.geometry.road_motion.fit_joint_speed`): a
constant speed ``v`` (m/s) makes pair ``k``'s plane scale ``v dt_k / h``; the pairs' translation direction is the
learned direction of travel (``travel``) or each pair's essential matrix (``pair``); ``+shift``: each pair's road
points also get their own image shift (the road rows' rotation error: rolling shutter, a shaking mount).

Printed per clip and variant: the per-pair readings' median (what the filter sees), the joint fit's speed and its
1-sigma, the pairs and points that entered it, and the truth (overlay / ground truth); with ``--tracks``, the lead
car's closing speed from its box width (:func:`lead_closing`, a second scale cue at the same camera).
``--jitter N`` repeats the run at focal lengths 1..N % either side with the height scaled to keep ``fx * h`` (the
conditioning check: a measurement that depended on the camera only through ``fx * h`` would not move).

Run: PYTHONPATH=src python bench/ego_speed_joint.py [--clips ccd_000014,seq06,seq00,highway] [--tracks DIR]
[--fx PX --height M] [--jitter N] [--window S] [--modes pair,travel,pair+shift,travel+shift] [--min-cond X]
(``seq00`` / ``seq06``: the shared KITTI odometry frames with their calibration; ``highway``: the Udacity clip with
its chessboard camera; ``ccd_000014``: the default camera unless ``--fx`` / ``--height``)
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path
from typing import Any

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
DATA = ROOT.parent / "shared" / "data"
LABELS = ROOT / "bench" / "labels" / "ego_speed_overlays.json"


def clip_frames(name: str, args: argparse.Namespace) -> tuple[list[np.ndarray], float, Any, int, Any, np.ndarray]:
    """(frames, fps, camera, dashboard rows, boxes or None, true speed per frame m/s / NaN)."""
    import cv2
    import pandas as pd

    from deepcrashtest.geometry.camera import calibrate_chessboard, default_camera

    if name.startswith("seq"):
        from deepcrashtest.datasets.kitti.files import KITTI_CAMERA_HEIGHT_M, read_poses
        from deepcrashtest.eval.egomotion import frame_times, read_odometry_calib
        from deepcrashtest.scenario import Camera

        folder = next((DATA / "kitti_odometry").glob(f"{name}_*"))
        imgs = [cv2.imread(str(p), cv2.IMREAD_GRAYSCALE) for p in sorted((folder / "image_0").glob("*.png"))]
        poses = read_poses(folder / "poses.txt")[: len(imgs)]
        K = read_odometry_calib(folder)
        cam = Camera(fx=K[0, 0], fy=K[1, 1], cx=K[0, 2], cy=K[1, 2], height_m=KITTI_CAMERA_HEIGHT_M)
        times = frame_times(folder, len(imgs))
        pos = np.array([p[:3, 3] for p in poses])
        v = np.r_[np.nan, np.linalg.norm(np.diff(pos, axis=0), axis=1) / np.diff(times)]
        return imgs, 1.0 / float(np.median(np.diff(times))), cam, 0, None, v
    if name == "highway":
        video = DATA / "dashcam_udacity" / "highway_project_video.mp4"
        last = 250
    else:
        entry = json.loads(LABELS.read_text())["clips"][name]
        video, last = DATA / entry["video"], max(r["last_frame"] for r in entry["readings"])
    cap = cv2.VideoCapture(str(video))
    fps = float(cap.get(cv2.CAP_PROP_FPS))
    imgs = []
    while len(imgs) <= last:
        ok, img = cap.read()
        if not ok:
            break
        imgs.append(img)
    h, w = imgs[0].shape[:2]
    truth = np.full(len(imgs), np.nan)
    if name == "highway":
        calib, _, _ = calibrate_chessboard(video.parent / "camera_calibration")
        cam = calib.model_copy(update={"height_m": default_camera(w, h).height_m})
    else:
        cam = default_camera(w, h)
        if args.fx:
            cam = cam.model_copy(update={"fx": args.fx, "fy": args.fx})
        if args.height:
            cam = cam.model_copy(update={"height_m": args.height})
        for r in entry["readings"]:
            truth[r["first_frame"] : r["last_frame"] + 1] = r["kmh"] / 3.6
    from deepcrashtest.pipeline.geometry_pass import estimate_camera

    cam, rows, _ = estimate_camera(imgs[: int(2 * fps) + 1], cam)
    tracks = Path(args.tracks) / name / "tracks.csv" if args.tracks else None
    boxes = pd.read_csv(tracks) if tracks is not None and tracks.exists() else None
    return imgs, fps, cam, rows, boxes, truth


def lead_closing(boxes: Any, fps: float, fx: float, width_m: float = 1.8, step_s: float = 0.8) -> str:
    """The longest car track's closing speed (km/h) over about ``step_s`` from its detected box widths (depth
    ``fx W / w``, a car ``width_m`` wide): the ego's speed when that car stands, and like the road's scale
    proportional to the focal length (this second scale cue gives no focal length, but checks the road's scale at
    the same camera)."""
    cars = boxes[(boxes.category == "car") & (boxes.state == "detected")]  # the tracker's predictions are no evidence
    if not len(cars):
        return "no car track"
    track = cars[cars.track_id == cars.track_id.value_counts().idxmax()].sort_values("frame")
    depth = fx * width_m / (track.x2 - track.x1).to_numpy(float)
    frames = track.frame.to_numpy(int)
    parts = []
    k = 0
    while k < len(frames) - 1:
        j = min(int(np.searchsorted(frames, frames[k] + step_s * fps)), len(frames) - 1)
        dt = (frames[j] - frames[k]) / fps
        parts.append(f"{frames[k]}-{frames[j]}: {(depth[k] - depth[j]) / dt * 3.6:.0f}")
        k = j
    return f"lead car (track {int(track.track_id.iloc[0])}) closing km/h at fx {fx:.0f} px: " + ", ".join(parts)


def joint(pairs: list[dict[str, Any]], height_m: float, mode: str, min_cond: float) -> Any:
    """:func:`fit_joint_speed` for a mode written ``pair`` / ``travel``, ``+shift`` for its ``free_shift``."""
    from deepcrashtest.geometry.road_motion import fit_joint_speed

    base, _, shift = mode.partition("+")
    return fit_joint_speed(pairs, height_m, base, min_cond=min_cond, free_shift=shift == "shift")


def run(name: str, args: argparse.Namespace, cam_scale: float = 1.0) -> None:
    from deepcrashtest.geometry.egomotion import EgoMotionEstimator

    imgs, fps, cam, rows, boxes, truth = clip_frames(name, args)
    if cam_scale != 1.0:
        cam = cam.model_copy(update={"fx": cam.fx * cam_scale, "fy": cam.fy * cam_scale,
                                     "height_m": cam.height_m / cam_scale})  # fmt: skip
    est = EgoMotionEstimator(cam, mask_bottom_rows=rows, keep_pairs=True)
    raw = []
    for i, img in enumerate(imgs):
        b = boxes[boxes.frame == i][["x1", "y1", "x2", "y2"]].to_numpy(float) if boxes is not None else None
        raw.append(est.update(img, i / fps, b).raw_speed)
    speed = est.result().speed
    pairs = est.pairs
    fin = np.array([r for r in raw if r is not None and r > 0.0])
    true_mean = float(np.nanmean(truth[1:]))
    line = (
        f"{name:11} fx {cam.fx:6.0f} h {cam.height_m:.3f}: truth {true_mean * 3.6:5.1f} km/h | filter mean "
        f"{float(np.mean(speed[1:])) * 3.6:5.1f} | per-pair readings {len(fin)}/{len(pairs)} median "
        f"{(np.median(fin) * 3.6 if len(fin) else float('nan')):5.1f}"
    )
    for mode in args.modes.split(","):
        fit = joint(pairs, cam.height_m, mode, args.min_cond)
        if fit is None:
            line += f" | joint-{mode}: none"
            continue
        line += (
            f" | joint-{mode} {fit.speed * 3.6:5.1f} +- {fit.speed_std * 3.6:4.1f} ({fit.pairs} pairs, "
            f"{fit.points} pts, {fit.inliers} inl)"
        )
    print(line, flush=True)
    if boxes is not None:
        print(f"{'':11} {lead_closing(boxes, fps, cam.fx)}")
    if args.window > 0:
        t1 = np.array([p["t1"] for p in pairs])
        for end in np.arange(args.window, t1.max() + 1e-6, args.window / 2):
            sel = [p for p, t in zip(pairs, t1, strict=True) if end - args.window < t <= end]
            fr = slice(int(round((end - args.window) * fps)) + 1, int(round(end * fps)) + 1)
            tm = float(np.nanmean(truth[fr])) * 3.6
            parts = []
            for mode in args.modes.split(","):
                fit = joint(sel, cam.height_m, mode, args.min_cond)
                parts.append(f"{mode} {'none' if fit is None else f'{fit.speed * 3.6:5.1f}'}")
            print(f"{'':11} window {end - args.window:4.1f}-{end:4.1f} s truth {tm:5.1f}: " + ", ".join(parts))


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--clips", default="ccd_000014")
    ap.add_argument("--tracks", default="")
    ap.add_argument("--fx", type=float, default=None)
    ap.add_argument("--height", type=float, default=None)
    ap.add_argument("--jitter", type=int, default=0)
    ap.add_argument("--window", type=float, default=0.0, help="also sliding windows of S seconds (half overlap)")
    ap.add_argument("--modes", default="pair,travel,pair+shift,travel+shift")
    ap.add_argument("--min-cond", type=float, default=0.0, help="fit_joint_speed's min_cond")
    args = ap.parse_args()
    import cv2

    cv2.setNumThreads(1)
    for name in args.clips.split(","):
        for k in range(-args.jitter, args.jitter + 1):
            run(name, args, 1.0 + 0.01 * k)


if __name__ == "__main__":
    main()
