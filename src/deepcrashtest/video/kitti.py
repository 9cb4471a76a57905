"""Readers for the KITTI tracking layout: labels (label_02), calibration and per-frame poses.

KITTI conventions kept here: rectified camera-2 frame, x right, y down, z forward (metres);
a label's ``location`` is the bottom centre of the 3D box; ``rotation_y`` is the yaw about
the camera y axis (radians, 0 = facing camera +x). Tracking sequences run at 10 Hz.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pandas as pd

from deepcrashtest.errors import UserError
from deepcrashtest.fileio import require_file

KITTI_FPS = 10.0
KITTI_IMAGE_SIZE = (1242, 375)  # width, height (varies by a few pixels per sequence)
KITTI_CAMERA_HEIGHT_M = 1.65

LABEL_COLUMNS = [
    "frame", "track_id", "type", "truncated", "occluded", "alpha",
    "x1", "y1", "x2", "y2", "h", "w", "l", "x", "y", "z", "ry",
]  # fmt: skip


def read_labels(path: str | Path) -> pd.DataFrame:
    """KITTI tracking labels (one file per sequence) as a DataFrame with ``LABEL_COLUMNS``.

    Extra columns (a ``score`` in tracker output) are kept as ``score``.
    """
    p = require_file(path, "KITTI label file")
    try:
        df = pd.read_csv(p, sep=r"\s+", header=None, engine="python")
    except (pd.errors.ParserError, UnicodeDecodeError) as exc:
        raise UserError(f"{p}: not a KITTI label file ({exc})") from None
    if df.shape[1] not in (17, 18):
        raise UserError(f"{p}: expected 17 or 18 columns per KITTI label line, found {df.shape[1]}")
    df.columns = LABEL_COLUMNS + (["score"] if df.shape[1] == 18 else [])
    df["frame"] = df["frame"].astype(int)
    df["track_id"] = df["track_id"].astype(int)
    return df


@dataclass(frozen=True)
class KittiCalib:
    """Projection matrices of one sequence. ``P2`` is the 3x4 left colour camera projection."""

    P2: np.ndarray
    R_rect: np.ndarray
    Tr_velo_cam: np.ndarray
    Tr_imu_velo: np.ndarray | None

    @property
    def K(self) -> np.ndarray:
        """3x3 intrinsics of camera 2, pixels."""
        return self.P2[:, :3].copy()


def read_calib(path: str | Path) -> KittiCalib:
    """Read a KITTI tracking calib file (``P2:`` / ``R0_rect`` or ``R_rect`` / ``Tr_velo_to_cam`` ...)."""
    p = require_file(path, "KITTI calib file")
    rows: dict[str, np.ndarray] = {}
    for line in p.read_text().splitlines():
        if ":" not in line:
            parts = line.split()
            if not parts:
                continue
            key, vals = parts[0], parts[1:]
        else:
            key, rest = line.split(":", 1)
            vals = rest.split()
        try:
            rows[key.strip()] = np.array([float(v) for v in vals])
        except ValueError:
            raise UserError(f"{p}: bad number in calib line {key!r}") from None
    try:
        P2 = rows["P2"].reshape(3, 4)
        R = rows.get("R0_rect", rows.get("R_rect"))
        T = rows.get("Tr_velo_to_cam", rows.get("Tr_velo_cam"))
        if R is None or T is None:
            raise KeyError("R_rect/Tr_velo_cam")
        imu = rows.get("Tr_imu_to_velo", rows.get("Tr_imu_velo"))
        return KittiCalib(P2, R.reshape(3, 3), T.reshape(3, 4), None if imu is None else imu.reshape(3, 4))
    except (KeyError, ValueError) as exc:
        raise UserError(f"{p}: incomplete KITTI calib ({exc})") from None


def read_poses(path: str | Path) -> np.ndarray:
    """Camera poses, one 3x4 row-major matrix per line -> (N, 4, 4) array of T_world_cam.

    Each pose maps camera-frame points of frame k into the camera frame of frame 0 (KITTI
    odometry and ORB-SLAM3 ``CameraTrajectory.txt`` layout).
    """
    p = require_file(path, "pose file")
    try:
        data = np.loadtxt(p, ndmin=2)
    except ValueError as exc:
        raise UserError(f"{p}: not a pose file ({exc})") from None
    if data.shape[1] != 12:
        raise UserError(f"{p}: expected 12 numbers per pose line, found {data.shape[1]}")
    if not np.all(np.isfinite(data)):
        raise UserError(f"{p}: pose file contains non-finite numbers")
    poses = np.tile(np.eye(4), (data.shape[0], 1, 1))
    poses[:, :3, :] = data.reshape(-1, 3, 4)
    return poses


@dataclass(frozen=True)
class KittiSequence:
    """Paths of one KITTI tracking sequence under a ``kitti_tracking`` folder."""

    root: Path
    sequence: int

    @property
    def name(self) -> str:
        return f"{self.sequence:04d}"

    @property
    def labels(self) -> Path:
        return self.root / "label_02" / f"{self.name}.txt"

    @property
    def calib(self) -> Path:
        return self.root / "calib" / f"{self.name}.txt"

    @property
    def poses(self) -> Path:
        return self.root / "orbslam3_poses" / self.name / "CameraTrajectory.txt"

    @property
    def images(self) -> Path:
        return self.root / "image_02" / self.name

    @property
    def detections_pointrcnn(self) -> Path:
        return self.root / "detections_pointrcnn_Car" / f"{self.name}.txt"

    def check(self) -> KittiSequence:
        if not self.root.is_dir():
            raise UserError(f"{self.root}: KITTI tracking folder not found")
        for p in (self.labels, self.calib, self.poses):
            if not p.exists():
                raise UserError(f"{p}: missing for sequence {self.name}")
        return self
