"""KITTI camera-frame boxes <-> the Scenario's world frame, through the sequence's ego poses.

Ground-plane positions come from :func:`deepcrashtest.datasets.kitti.scenario.kitti_world_transform`,
the very transform that places the agents of a KITTI Scenario, so evaluated positions and Scenario
positions are the same numbers. Heights (z up) and yaws use the same poses.
"""

from __future__ import annotations

import numpy as np
import pandas as pd

from deepcrashtest.datasets.kitti.boxes import WORLD_BOX_COLUMNS, project_box
from deepcrashtest.datasets.kitti.files import KITTI_IMAGE_SIZE
from deepcrashtest.datasets.kitti.scenario import kitti_world_transform
from deepcrashtest.geometry.frames import (
    CAM_TO_WORLD_AXES,
    camera_points_to_world,
    camera_yaw_to_world,
    transform_points,
)


class KittiWorld:
    """World frame of one KITTI sequence, from its (N, 4, 4) camera poses (T_cam0_camk)."""

    def __init__(self, poses: np.ndarray):
        self.poses = poses
        self.to_world, self.ego_xy, self.ego_yaw = kitti_world_transform(poses)
        zero = np.zeros((1, 3))
        self.origin_xy = camera_points_to_world(poses[0], zero)[0, :2] - self.to_world(0, zero)[0]
        self._inverse = np.linalg.inv(poses)

    @property
    def n_frames(self) -> int:
        return len(self.poses)

    def boxes_to_world(self, frame: int, xyz: np.ndarray, lwh: np.ndarray, ry: np.ndarray) -> np.ndarray:
        """(n, 7) world boxes of KITTI boxes seen in ``frame``: bottom centres ``xyz`` (n, 3) and sizes
        ``lwh`` (n, 3) in metres, ``ry`` (n,) the KITTI rotation_y, camera frame of that image."""
        out = np.empty((len(xyz), 7))
        if len(xyz) == 0:
            return out
        out[:, :2] = self.to_world(frame, xyz)
        out[:, 2] = camera_points_to_world(self.poses[frame], xyz)[:, 2]
        out[:, 3:6] = lwh
        out[:, 6] = camera_yaw_to_world(self.poses[frame], ry)
        return out

    def world_to_camera(self, frame: int, points: np.ndarray) -> np.ndarray:
        """(n, 3) world points -> camera frame of ``frame`` (x right, y down, z forward)."""
        p = np.array(points, dtype=float).reshape(-1, 3)
        p[:, :2] += self.origin_xy
        return transform_points(self._inverse[frame], p @ CAM_TO_WORLD_AXES)

    def yaw_to_camera(self, frame: int, yaw: np.ndarray) -> np.ndarray:
        """World yaws -> KITTI ``rotation_y`` in the camera of ``frame``."""
        yaw = np.asarray(yaw, dtype=float)
        heading = np.stack([np.cos(yaw), np.sin(yaw), np.zeros_like(yaw)], axis=-1) @ CAM_TO_WORLD_AXES
        cam = heading @ self._inverse[frame][:3, :3].T
        return np.arctan2(-cam[..., 2], cam[..., 0])

    def image_boxes(self, frame: int, world: np.ndarray, P2: np.ndarray) -> np.ndarray:
        """(n, 4) image boxes of world boxes in ``frame`` (NaN rows: not in the image)."""
        out = np.full((len(world), 4), np.nan)
        if len(world) == 0:
            return out
        bottom = self.world_to_camera(frame, world[:, :3])
        ry = self.yaw_to_camera(frame, world[:, 6])
        for i, (b, (length, width, height), r) in enumerate(zip(bottom, world[:, 3:6], ry, strict=True)):
            out[i] = project_box(P2, b, length, width, height, r, KITTI_IMAGE_SIZE)
        return out


def frame_index(frames: np.ndarray, n_frames: int) -> list[np.ndarray]:
    """Row indices of each frame 0..n_frames-1 (rows of other frames are left out)."""
    frames = np.asarray(frames, dtype=int)
    order = np.argsort(frames, kind="stable")
    bounds = np.searchsorted(frames[order], np.arange(n_frames + 1))
    return [order[bounds[f] : bounds[f + 1]] for f in range(n_frames)]


def world_table(world: KittiWorld, table: pd.DataFrame) -> pd.DataFrame:
    """``table`` (KITTI rows with a ``frame`` column) with the world box columns added."""
    out = table.copy()
    boxes = np.full((len(table), 7), np.nan)
    xyz = table[["x", "y", "z"]].to_numpy(dtype=float)
    lwh = table[["l", "w", "h"]].to_numpy(dtype=float)
    ry = table["ry"].to_numpy(dtype=float)
    for f, idx in enumerate(frame_index(table["frame"].to_numpy(), world.n_frames)):
        if len(idx):
            boxes[idx] = world.boxes_to_world(f, xyz[idx], lwh[idx], ry[idx])
    for i, c in enumerate(WORLD_BOX_COLUMNS):
        out[c] = boxes[:, i]
    return out
