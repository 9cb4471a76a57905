"""KITTI's 3D boxes in the image: a camera-frame box (bottom centre, l w h, ``rotation_y``) projected
through a 3x4 camera matrix to the 2D box KITTI's own labels follow (pixels, clipped to the image;
NaN when behind the camera or wholly outside the image).

Camera frame: x right, y down, z forward, metres; ``rotation_y`` radians about the camera's y axis
(KITTI's convention); image boxes ``(x1, y1, x2, y2)`` pixels.
"""

from __future__ import annotations

import numpy as np

WORLD_BOX_COLUMNS = ["wx", "wy", "wz", "l", "w", "h", "wyaw"]
"""World-box columns of a KITTI table placed in the Scenario's world frame (``world.world_table``): bottom
centre x, y, z (world x forward, y left, z up), length, width, height (m), yaw (rad)."""


def camera_box_corners(bottom_centre: np.ndarray, length: float, width: float, height: float, ry: float) -> np.ndarray:
    """(8, 3) corners of a KITTI 3D box in the camera frame (x right, y down, z forward), metres."""
    c, s = np.cos(ry), np.sin(ry)
    x = np.array([1, 1, -1, -1, 1, 1, -1, -1]) * length / 2
    z = np.array([1, -1, -1, 1, 1, -1, -1, 1]) * width / 2
    y = np.array([0, 0, 0, 0, -1, -1, -1, -1]) * height
    rot = np.array([[c, 0, s], [0, 1, 0], [-s, 0, c]])
    return (rot @ np.vstack([x, y, z])).T + np.asarray(bottom_centre, dtype=float)


def project_box(
    P: np.ndarray,
    bottom_centre: np.ndarray,
    length: float,
    width: float,
    height: float,
    ry: float,
    image_size: tuple[int, int],
) -> np.ndarray:
    """The 2D box (pixels, clipped to the image) around a camera-frame 3D box; NaNs when the box is
    behind the camera or wholly outside the image (the rule KITTI's own 2D boxes follow)."""
    corners = camera_box_corners(bottom_centre, length, width, height, ry)
    if np.any(corners[:, 2] < 0.1):
        return np.full(4, np.nan)
    uvw = np.hstack([corners, np.ones((8, 1))]) @ P.T
    uv = uvw[:, :2] / uvw[:, 2:3]
    width, height = image_size
    x1, y1 = np.clip(uv.min(axis=0), 0, [width - 1, height - 1])
    x2, y2 = np.clip(uv.max(axis=0), 0, [width - 1, height - 1])
    if x2 - x1 < 1 or y2 - y1 < 1:
        return np.full(4, np.nan)
    return np.array([x1, y1, x2, y2])


def project_boxes(
    P: np.ndarray, bottom: np.ndarray, lwh: np.ndarray, ry: np.ndarray, image_size: tuple[int, int]
) -> np.ndarray:
    """:func:`project_box` for (n,) boxes at once: bottom centres (n, 3), sizes (n, 3) l w h, yaws (n,)
    -> (n, 4) pixels (NaN rows: behind the camera or outside the image)."""
    bottom = np.asarray(bottom, dtype=float).reshape(-1, 3)
    n = len(bottom)
    if n == 0:
        return np.zeros((0, 4))
    c, s = np.cos(ry), np.sin(ry)
    x = np.array([1, 1, -1, -1, 1, 1, -1, -1])[None, :] * lwh[:, 0:1] / 2
    z = np.array([1, -1, -1, 1, 1, -1, -1, 1])[None, :] * lwh[:, 1:2] / 2
    y = np.array([0, 0, 0, 0, -1, -1, -1, -1])[None, :] * lwh[:, 2:3]
    corners = np.stack([c[:, None] * x + s[:, None] * z, y, -s[:, None] * x + c[:, None] * z], axis=-1)
    corners += bottom[:, None, :]
    uvw = np.concatenate([corners, np.ones((n, 8, 1))], axis=-1) @ P.T
    behind: np.ndarray = np.asarray((corners[:, :, 2] < 0.1).any(axis=1))
    uv = uvw[:, :, :2] / np.where(behind[:, None, None], 1.0, uvw[:, :, 2:3])
    width, height = image_size
    lo = np.clip(uv.min(axis=1), 0, [width - 1, height - 1])
    hi = np.clip(uv.max(axis=1), 0, [width - 1, height - 1])
    out = np.hstack([lo, hi])
    bad = behind | (hi[:, 0] - lo[:, 0] < 1) | (hi[:, 1] - lo[:, 1] < 1)
    out[bad] = np.nan
    return out
