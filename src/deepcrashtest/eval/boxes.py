"""Box overlaps and projections used by the tracking evaluation.

2D boxes: ``(x1, y1, x2, y2)`` pixels. World boxes (3D): ``(x, y, z, l, w, h, yaw)`` with (x, y) the
centre on the ground and z the bottom of the box in the world frame (x forward, y left, z up; metres),
yaw radians counter-clockwise from world +x, l along the heading.
"""

from __future__ import annotations

import numpy as np
from shapely.geometry import Polygon

WORLD_BOX_COLUMNS = ["wx", "wy", "wz", "l", "w", "h", "wyaw"]


def iou_2d(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """(N, M) intersection over union of 2D boxes; 0 for degenerate boxes."""
    inter = _intersection_2d(a, b)
    area_a = _area_2d(a)
    area_b = _area_2d(b)
    union = area_a[:, None] + area_b[None, :] - inter
    ok = (area_a[:, None] > 0) & (area_b[None, :] > 0) & (union > 0)
    return np.where(ok, inter / np.where(ok, union, 1.0), 0.0)


def ioa_2d(a: np.ndarray, regions: np.ndarray) -> np.ndarray:
    """(N, M) fraction of each box of ``a`` covered by each region (intersection over a's area)."""
    inter = _intersection_2d(a, regions)
    area_a = _area_2d(a)
    ok = area_a > 0
    return np.where(ok[:, None], inter / np.where(ok, area_a, 1.0)[:, None], 0.0)


def _area_2d(a: np.ndarray) -> np.ndarray:
    a = np.asarray(a, dtype=float).reshape(-1, 4)
    return np.clip(a[:, 2] - a[:, 0], 0, None) * np.clip(a[:, 3] - a[:, 1], 0, None)


def _intersection_2d(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    a = np.asarray(a, dtype=float).reshape(-1, 4)
    b = np.asarray(b, dtype=float).reshape(-1, 4)
    w = np.minimum(a[:, None, 2], b[None, :, 2]) - np.maximum(a[:, None, 0], b[None, :, 0])
    h = np.minimum(a[:, None, 3], b[None, :, 3]) - np.maximum(a[:, None, 1], b[None, :, 1])
    return np.clip(w, 0, None) * np.clip(h, 0, None)


def bev_distance(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """(N, M) bird's-eye (ground-plane) distance between box centres, metres; NaN where unknown."""
    a = np.asarray(a, dtype=float).reshape(-1, 7)
    b = np.asarray(b, dtype=float).reshape(-1, 7)
    return np.hypot(a[:, None, 0] - b[None, :, 0], a[:, None, 1] - b[None, :, 1])


def bev_corners(box: np.ndarray) -> np.ndarray:
    """(4, 2) ground-plane corners of one world box, counter-clockwise."""
    x, y, _, length, width, _, yaw = box
    c, s = np.cos(yaw), np.sin(yaw)
    local = np.array([[1, 1], [-1, 1], [-1, -1], [1, -1]]) * [length / 2, width / 2]
    return local @ np.array([[c, s], [-s, c]]) + [x, y]


def iou_3d(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """(N, M) 3D IoU of oriented world boxes (yaw about the vertical): exact polygon overlap on the
    ground times the vertical overlap, over the union of volumes. 0 where a box is unknown (NaN)."""
    a = np.asarray(a, dtype=float).reshape(-1, 7)
    b = np.asarray(b, dtype=float).reshape(-1, 7)
    out = np.zeros((len(a), len(b)))
    if out.size == 0:
        return out
    reach = np.hypot(a[:, 3], a[:, 4])[:, None] / 2 + np.hypot(b[:, 3], b[:, 4])[None, :] / 2
    near = bev_distance(a, b) < reach  # NaN compares False: unknown boxes never overlap
    if not near.any():
        return out
    polys_a = {i: Polygon(bev_corners(a[i])) for i in np.unique(np.nonzero(near)[0])}
    polys_b = {j: Polygon(bev_corners(b[j])) for j in np.unique(np.nonzero(near)[1])}
    for i, j in zip(*np.nonzero(near), strict=True):
        area = polys_a[i].intersection(polys_b[j]).area
        dz = min(a[i, 2] + a[i, 5], b[j, 2] + b[j, 5]) - max(a[i, 2], b[j, 2])
        inter = area * max(dz, 0.0)
        vol_a = a[i, 3] * a[i, 4] * a[i, 5]
        vol_b = b[j, 3] * b[j, 4] * b[j, 5]
        union = vol_a + vol_b - inter
        out[i, j] = inter / union if union > 0 else 0.0
    return out


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
