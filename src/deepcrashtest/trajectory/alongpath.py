"""Distance along a path: its cumulative arc length and the points at given distances along it.

The most basic module of ``trajectory/`` (NumPy only): the road frame's stations, the ego's and every road
user's re-timing along its own path (``egotraction``, ``traction``) all measure distance here. Positions in
metres (world frame: x forward, y left).
"""

from __future__ import annotations

import numpy as np


def arc_length(xy: np.ndarray) -> np.ndarray:
    """Cumulative distance (m, N) along the points ``xy`` (N, 2), 0 at the first."""
    return np.concatenate([[0.0], np.cumsum(np.hypot(*np.diff(xy, axis=0).T))])


def along_path(xy: np.ndarray, s: np.ndarray, s_new: np.ndarray) -> np.ndarray:
    """Points (M, 2) at distances ``s_new`` (M,) along the path ``xy`` (N, 2) whose samples lie at the
    non-decreasing distances ``s`` (N,); continued straight along the end steps beyond its ends."""
    keep = np.concatenate([[True], np.diff(s) > 1e-9])
    ss, pts = s[keep], xy[keep]
    out = np.column_stack([np.interp(s_new, ss, pts[:, 0]), np.interp(s_new, ss, pts[:, 1])])
    if len(ss) >= 2:
        u0 = (pts[1] - pts[0]) / (ss[1] - ss[0])
        u1 = (pts[-1] - pts[-2]) / (ss[-1] - ss[-2])
        lo, hi = s_new < ss[0], s_new > ss[-1]
        out[lo] = pts[0] + (s_new[lo] - ss[0])[:, None] * u0
        out[hi] = pts[-1] + (s_new[hi] - ss[-1])[:, None] * u1
    return out
