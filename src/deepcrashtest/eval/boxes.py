"""Box overlaps used by the tracking evaluation.

2D boxes: ``(x1, y1, x2, y2)`` pixels. World boxes (3D): ``(x, y, z, l, w, h, yaw)`` with (x, y) the
centre on the ground and z the bottom of the box in the world frame (x forward, y left, z up; metres),
yaw radians counter-clockwise from world +x, l along the heading.
"""

from __future__ import annotations

import numpy as np
from shapely.geometry import Polygon


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
