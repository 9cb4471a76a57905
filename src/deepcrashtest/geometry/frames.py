"""Coordinate frames.

* Camera frame: x right, y down, z forward (metres).
* World frame: x forward, y left, z up (metres), origin at the ego's start.

``CAM_TO_WORLD_AXES`` maps camera axes to world axes for a level camera:
world x = camera z, world y = -camera x, world z = -camera y.
"""

from __future__ import annotations

import numpy as np

CAM_TO_WORLD_AXES = np.array([[0.0, 0.0, 1.0], [-1.0, 0.0, 0.0], [0.0, -1.0, 0.0]])


def cam0_points_to_world(points_cam0: np.ndarray) -> np.ndarray:
    """(N, 3) points in the first camera frame -> (N, 3) world points (x fwd, y left, z up)."""
    return np.asarray(points_cam0, dtype=float) @ CAM_TO_WORLD_AXES.T


def transform_points(T: np.ndarray, points: np.ndarray) -> np.ndarray:
    """Apply a 4x4 (or 3x4) rigid transform to (N, 3) points."""
    pts = np.asarray(points, dtype=float)
    return pts @ T[:3, :3].T + T[:3, 3]


def camera_points_to_world(T_cam0_camk: np.ndarray, points_camk: np.ndarray) -> np.ndarray:
    """Points in camera frame k -> world frame, given the pose of camera k in camera-0 coordinates."""
    return cam0_points_to_world(transform_points(T_cam0_camk, points_camk))


def camera_forward_yaw(T_cam0_camk: np.ndarray) -> float:
    """World yaw (radians, CCW from world +x) of camera k's optical axis."""
    fwd = cam0_points_to_world(T_cam0_camk[:3, 2][None, :])[0]
    return float(np.arctan2(fwd[1], fwd[0]))


def camera_yaw_to_world(T_cam0_camk: np.ndarray, ry: np.ndarray) -> np.ndarray:
    """KITTI ``rotation_y`` (about camera y, 0 = facing camera +x) -> world yaw, radians."""
    ry = np.asarray(ry, dtype=float)
    heading_cam = np.stack([np.cos(ry), np.zeros_like(ry), -np.sin(ry)], axis=-1)
    heading_w = cam0_points_to_world(heading_cam @ T_cam0_camk[:3, :3].T)
    return np.arctan2(heading_w[..., 1], heading_w[..., 0])


def rotation_homographies(poses: np.ndarray, K: np.ndarray) -> list[np.ndarray | None]:
    """Per frame k the 3x3 homography ``K R K^-1`` taking frame k-1's pixels to frame k's for the camera's own
    rotation between them (exact for points at infinity; None for frame 0), from the camera poses ``poses``
    ((n, 4, 4) or (n, 3, 4), camera k -> a fixed reference frame, camera axes x right, y down, z forward) and the
    intrinsic matrix ``K`` (px): the image motion a pose log predicts for the tracker's boxes
    (:meth:`~deepcrashtest.perception.track.BoxTracker.update_boxes`' ``motion``)."""
    R = np.asarray(poses, float)[:, :3, :3]
    K = np.asarray(K, float)
    K_inv = np.linalg.inv(K)
    return [None] + [K @ R[k].T @ R[k - 1] @ K_inv for k in range(1, len(R))]
