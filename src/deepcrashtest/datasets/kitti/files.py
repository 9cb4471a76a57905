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
    Tracker results in this layout sometimes carry more columns; as in TrackEval, column 18 is the
    score and later ones are dropped. An empty file (a sequence without objects) gives an empty table.
    """
    p = Path(path)
    if p.is_file() and p.stat().st_size == 0:
        return _empty_table(LABEL_COLUMNS, ints=("frame", "track_id"), objects=("type",))
    require_file(p, "KITTI label file")
    try:
        df = pd.read_csv(p, sep=r"\s+", header=None, engine="python")
    except (pd.errors.ParserError, UnicodeDecodeError) as exc:
        raise UserError(f"{p}: not a KITTI label file ({exc})") from None
    if df.shape[1] < 17:
        raise UserError(f"{p}: expected at least 17 columns per KITTI label line, found {df.shape[1]}")
    df = df.iloc[:, :18]
    df.columns = LABEL_COLUMNS + (["score"] if df.shape[1] == 18 else [])
    df["frame"] = df["frame"].astype(int)
    df["track_id"] = df["track_id"].astype(int)
    return df


def _empty_table(columns: list[str], ints: tuple[str, ...] = (), objects: tuple[str, ...] = ()) -> pd.DataFrame:
    dtypes = {c: (int if c in ints else object if c in objects else float) for c in columns}
    return pd.DataFrame({c: pd.Series(dtype=d) for c, d in dtypes.items()})


#: AB3DMOT detection files: one detection a line, comma separated, KITTI camera-2 frame (the
#: location is the bottom centre of the 3D box); ``type_id`` 1 Pedestrian, 2 Car, 3 Cyclist.
DETECTION_COLUMNS = [
    "frame", "type_id", "x1", "y1", "x2", "y2", "score", "h", "w", "l", "x", "y", "z", "ry", "alpha",
]  # fmt: skip


def read_ab3dmot_detections(path: str | Path) -> pd.DataFrame:
    """3D detections in AB3DMOT's CSV layout (``frame,type,x1,y1,x2,y2,score,h,w,l,x,y,z,ry,alpha``).

    Boxes are pixels, sizes and location metres (camera frame), angles radians; the score is the
    detector's raw confidence (PointRCNN logits: roughly -1 to 16, not a probability).
    """
    p = Path(path)
    if p.is_file() and p.stat().st_size == 0:  # a sequence without any detection
        return _empty_table(DETECTION_COLUMNS, ints=("frame", "type_id"))
    require_file(p, "AB3DMOT detection file")
    try:
        df = pd.read_csv(p, header=None)
    except (pd.errors.ParserError, UnicodeDecodeError) as exc:
        raise UserError(f"{p}: not an AB3DMOT detection file ({exc})") from None
    if df.shape[1] != len(DETECTION_COLUMNS):
        raise UserError(f"{p}: expected {len(DETECTION_COLUMNS)} comma-separated columns, found {df.shape[1]}")
    df.columns = DETECTION_COLUMNS
    if not np.all(np.isfinite(df.drop(columns=["frame", "type_id"]).to_numpy(dtype=float))):
        raise UserError(f"{p}: detection file contains non-finite numbers")
    df["frame"] = df["frame"].astype(int)
    df["type_id"] = df["type_id"].astype(int)
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


# --------------------------------------------------------------------------- oxts (GPS/IMU)
#: The 30 fields of a KITTI oxts packet (``oxts/dataformat.txt``): degrees, metres, radians, m/s,
#: m/s^2, rad/s; yaw 0 = east, counter-clockwise; then accuracies and receiver status integers.
OXTS_FIELDS = [
    "lat", "lon", "alt", "roll", "pitch", "yaw", "vn", "ve", "vf", "vl", "vu", "ax", "ay", "az",
    "af", "al", "au", "wx", "wy", "wz", "wf", "wl", "wu", "pos_accuracy", "vel_accuracy",
    "navstat", "numsats", "posmode", "velmode", "orimode",
]  # fmt: skip
#: Earth radius used by the KITTI devkit's Mercator projection, metres.
EARTH_RADIUS_M = 6378137.0


def read_oxts(path: str | Path) -> pd.DataFrame:
    """Oxts packets as a DataFrame with ``OXTS_FIELDS``, one row per packet.

    ``path`` is a raw-data ``oxts/data`` folder (one packet per ``NNNNNNNNNN.txt``, read in name order)
    or one file with one packet per line (the tracking benchmark's ``oxts/NNNN.txt``).
    """
    p = Path(path)
    files = sorted(p.glob("*.txt")) if p.is_dir() else [require_file(p, "oxts file")]
    if not files:
        raise UserError(f"{p}: no oxts packets (*.txt) found")
    rows: list[list[float]] = []
    for f in files:
        for n, line in enumerate(f.read_text().splitlines(), 1):
            if not line.strip():
                continue
            try:
                vals = [float(v) for v in line.split()]
            except ValueError:
                raise UserError(f"{f}:{n}: bad number in oxts packet") from None
            if len(vals) != len(OXTS_FIELDS):
                raise UserError(f"{f}:{n}: expected {len(OXTS_FIELDS)} oxts fields, found {len(vals)}")
            rows.append(vals)
    if not rows:
        raise UserError(f"{p}: no oxts packets found")
    return pd.DataFrame(rows, columns=OXTS_FIELDS)


def mercator_scale(lat0_deg: float) -> float:
    """Scale of the KITTI Mercator projection for the reference latitude (cos of it)."""
    return float(np.cos(np.deg2rad(lat0_deg)))


def latlon_to_mercator(lat_deg: np.ndarray, lon_deg: np.ndarray, scale: float) -> tuple[np.ndarray, np.ndarray]:
    """Scaled Mercator coordinates (metres east, metres north) of latitudes/longitudes in degrees."""
    lat = np.asarray(lat_deg, dtype=float)
    lon = np.asarray(lon_deg, dtype=float)
    mx = scale * EARTH_RADIUS_M * np.deg2rad(lon)
    my = scale * EARTH_RADIUS_M * np.log(np.tan(np.deg2rad(90.0 + lat) / 2.0))
    return mx, my


def mercator_to_latlon(mx: np.ndarray, my: np.ndarray, scale: float) -> tuple[np.ndarray, np.ndarray]:
    """Inverse of :func:`latlon_to_mercator`, degrees."""
    lon = np.rad2deg(np.asarray(mx, dtype=float) / (scale * EARTH_RADIUS_M))
    lat = 2.0 * np.rad2deg(np.arctan(np.exp(np.asarray(my, dtype=float) / (scale * EARTH_RADIUS_M)))) - 90.0
    return lat, lon


def oxts_to_poses(oxts: pd.DataFrame) -> np.ndarray:
    """(N, 4, 4) poses of the oxts unit relative to the first packet (the KITTI devkit convention).

    Translation: the scaled Mercator projection (scale from the first latitude) plus altitude; rotation
    ``Rz(yaw) Ry(pitch) Rx(roll)``. Pose k maps points of IMU frame k (x forward, y left, z up) into
    IMU frame 0, so pose 0 is the identity.
    """
    if len(oxts) == 0:
        raise UserError("no oxts packets to convert")
    scale = mercator_scale(float(oxts["lat"].iloc[0]))
    mx, my = latlon_to_mercator(oxts["lat"].to_numpy(), oxts["lon"].to_numpy(), scale)
    poses = np.tile(np.eye(4), (len(oxts), 1, 1))
    for i, (rx, ry, rz) in enumerate(oxts[["roll", "pitch", "yaw"]].to_numpy()):
        poses[i, :3, :3] = _rot_z(rz) @ _rot_y(ry) @ _rot_x(rx)
    poses[:, :3, 3] = np.column_stack([mx, my, oxts["alt"].to_numpy()])
    return np.linalg.inv(poses[0]) @ poses


def _rot_x(a: float) -> np.ndarray:
    c, s = np.cos(a), np.sin(a)
    return np.array([[1.0, 0.0, 0.0], [0.0, c, -s], [0.0, s, c]])


def _rot_y(a: float) -> np.ndarray:
    c, s = np.cos(a), np.sin(a)
    return np.array([[c, 0.0, s], [0.0, 1.0, 0.0], [-s, 0.0, c]])


def _rot_z(a: float) -> np.ndarray:
    c, s = np.cos(a), np.sin(a)
    return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])
