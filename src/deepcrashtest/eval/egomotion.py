"""Monocular ego-motion against KITTI odometry ground truth (speed error, heading drift).

A KITTI odometry folder holds ``image_0/*.png`` (left greyscale frames), ``poses.txt`` (one 3x4
camera-0 pose per frame, frame 0 = identity, metres), a calibration file whose first line (or
``P0:`` line) is the 3x4 projection matrix of camera 0, and optionally ``times.txt`` (seconds;
10 Hz when absent). The camera is 1.65 m above the road (KITTI set-up).

Figures:

* ``distance_error_pct``: |estimated - true| path length over the sequence, % of true (the mean
  speed error);
* ``speed_error_median_pct``: median over frame pairs of |v_est - v_true| / v_true (frames with
  v_true > 1 m/s);
* ``yaw_drift_deg_per_100m``: |estimated - true| heading at the last frame per 100 m of true path;
* ``yaw_error_max_deg``: largest heading error along the sequence.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import cv2
import numpy as np

from deepcrashtest.datasets.kitti.files import KITTI_CAMERA_HEIGHT_M, read_poses
from deepcrashtest.errors import UserError
from deepcrashtest.geometry.egomotion import EgoMotion, EgoMotionEstimator
from deepcrashtest.geometry.frames import camera_forward_yaw, camera_points_to_world
from deepcrashtest.scenario import Camera

KITTI_ODOMETRY_FPS = 10.0


def read_odometry_calib(folder: Path) -> np.ndarray:
    """3x3 intrinsics of camera 0 from the folder's ``calib*.txt`` (first projection matrix)."""
    files = sorted(folder.glob("calib*.txt"))
    if not files:
        raise UserError(f"{folder}: no calib*.txt with the camera-0 projection matrix")
    for line in files[0].read_text().splitlines():
        vals = line.split(":", 1)[-1].split()
        if len(vals) == 12:
            try:
                return np.array([float(v) for v in vals]).reshape(3, 4)[:, :3]
            except ValueError:
                break
    raise UserError(f"{files[0]}: no 3x4 projection matrix found")


def frame_times(folder: Path, n: int) -> np.ndarray:
    times = folder / "times.txt"
    if times.exists():
        t = np.loadtxt(times, ndmin=1)[:n]
        if len(t) == n:
            return t - t[0]
    return np.arange(n) / KITTI_ODOMETRY_FPS


def run_odometry(folder: str | Path, max_frames: int | None = None) -> tuple[EgoMotion, np.ndarray, np.ndarray]:
    """Run the estimator over a KITTI odometry folder; returns (result, true poses, times)."""
    root = Path(folder)
    if not root.is_dir():
        raise UserError(f"{root}: odometry folder not found")
    images = sorted((root / "image_0").glob("*.png"))
    if len(images) < 2:
        raise UserError(f"{root}/image_0: needs at least 2 PNG frames")
    poses = read_poses(root / "poses.txt")
    n = min(len(images), len(poses), max_frames or len(images))
    K = read_odometry_calib(root)
    cam = Camera(
        fx=K[0, 0], fy=K[1, 1], cx=K[0, 2], cy=K[1, 2], height_m=KITTI_CAMERA_HEIGHT_M,
        intrinsics_source="kitti_calib", height_source="kitti_calib",
    )  # fmt: skip
    times = frame_times(root, n)
    est = EgoMotionEstimator(cam)
    for i in range(n):
        img = cv2.imread(str(images[i]), cv2.IMREAD_GRAYSCALE)
        if img is None:
            raise UserError(f"{images[i]}: unreadable image")
        est.update(img, float(times[i]))
    return est.result(), poses[:n], times


def egomotion_errors(ego: EgoMotion, poses: np.ndarray, times: np.ndarray) -> dict[str, Any]:
    """Compare an estimated ego track with true camera poses (see the module docstring)."""
    xy = np.array([camera_points_to_world(T, np.zeros((1, 3)))[0, :2] for T in poses])
    yaw = np.unwrap(np.array([camera_forward_yaw(T) for T in poses]))
    step = np.hypot(*np.diff(xy, axis=0).T)
    dt = np.diff(times)
    v_true = step / dt
    v_est = ego.speed[1:]
    moving = v_true > 1.0
    true_len = float(step.sum())
    est_len = float(np.sum(ego.speed[1:] * dt))
    yaw_err = np.degrees(np.abs(ego.yaw - (yaw - yaw[0])))
    rel = np.abs(v_est[moving] - v_true[moving]) / v_true[moving]
    return {
        "frames": int(len(times)),
        "path_length_m": round(true_len, 2),
        "estimated_length_m": round(est_len, 2),
        "distance_error_pct": round(100 * abs(est_len - true_len) / max(true_len, 1e-9), 2),
        "speed_error_median_pct": round(100 * float(np.median(rel)), 2) if rel.size else None,
        "speed_error_p90_pct": round(100 * float(np.percentile(rel, 90)), 2) if rel.size else None,
        "mean_speed_true_mps": round(float(v_true.mean()), 3),
        "heading_change_true_deg": round(float(np.degrees(yaw[-1] - yaw[0])), 2),
        "yaw_error_final_deg": round(float(yaw_err[-1]), 3),
        "yaw_error_max_deg": round(float(yaw_err.max()), 3),
        "yaw_drift_deg_per_100m": round(float(yaw_err[-1]) / max(true_len, 1e-9) * 100, 3),
        "valid_fraction": round(float(ego.valid.mean()), 3),
        "warnings": ego.warnings,
    }


def evaluate_egomotion(data: str | Path, max_frames: int | None = None) -> dict[str, Any]:
    """Evaluate one odometry folder, or every ``seq*`` folder under ``data``."""
    root = Path(data)
    if not root.is_dir():
        raise UserError(f"{root}: odometry folder not found")
    if (root / "poses.txt").exists():
        folders = [root]
    else:
        folders = sorted(p for p in root.iterdir() if (p / "poses.txt").exists())
    if not folders:
        raise UserError(f"{root}: no poses.txt here or in its sub-folders (expected KITTI odometry frames)")
    out: dict[str, Any] = {"sequences": {}}
    for f in folders:
        ego, poses, times = run_odometry(f, max_frames)
        out["sequences"][f.name] = egomotion_errors(ego, poses, times)
    seqs = list(out["sequences"].values())
    total = sum(s["path_length_m"] for s in seqs)
    out["total_path_m"] = round(total, 2)
    out["distance_error_pct"] = round(
        100 * abs(sum(s["estimated_length_m"] for s in seqs) - total) / max(total, 1e-9), 2
    )
    out["speed_error_median_pct"] = max(s["speed_error_median_pct"] or 0.0 for s in seqs)
    out["yaw_drift_deg_per_100m"] = max(s["yaw_drift_deg_per_100m"] for s in seqs)
    return out
