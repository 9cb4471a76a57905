"""Distance along a path: its cumulative arc length, the points at given distances along it, and the closest
distances at given times whose acceleration stays within bounds.

The most basic module of ``trajectory/`` (NumPy and SciPy only): the road frame's stations and the re-timing
of the raw ego (``egotraction``, on a uniform 0.1 s grid) and of every processed road user (``traction``, at
its own sample times, with weights and held ranges) along its own path all go through here; the bounded
least squares is SciPy's ``lsq_linear`` (bvls). Positions in metres (world frame: x forward, y left), times
in seconds, accelerations in m/s^2.
"""

from __future__ import annotations

import numpy as np
from scipy.optimize import lsq_linear


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


def along_accel(t: np.ndarray, s: np.ndarray) -> np.ndarray:
    """Acceleration (m/s^2, N-2) at the inner samples of the distances ``s`` (m) at times ``t`` (s): the change
    of the speed between the two neighbouring intervals over half their summed length."""
    if len(t) < 3:
        return np.zeros(0)
    v = np.diff(s) / np.diff(t)
    return np.diff(v) / (0.5 * (t[2:] - t[:-2]))


MAX_SAMPLES = 300
"""The most samples one least squares takes (its cost grows as their cube: 1,200 took 1.8 s, the 5,000 of a 200 s
track minutes and gigabytes); a longer stretch is re-timed in consecutive pieces. 300: 12 s at 25 fps, 30 s on the
ego's 0.1 s grid, longer than any crash clip's road user."""
LOOK_AHEAD = 100
"""Samples each piece solves beyond what it keeps, so that it ends heading where the next one goes."""
JOIN_WEIGHT = 1e3
"""Weight of a piece's first two samples, held where the piece before put them (position and speed carry on)."""


def bounded_distances(
    t: np.ndarray,
    s: np.ndarray,
    a_max: float,
    b_max: float,
    weight: np.ndarray | None = None,
    free_s: float = np.inf,
    lead_s: float = -np.inf,
    impact_s: float = np.inf,
) -> np.ndarray:
    """The distances (m, N) at the increasing times ``t`` (s, N) closest to ``s`` (weighted least squares,
    ``weight`` (N,) or all 1) whose first speed is >= 0 and whose :func:`along_accel` lies in
    [-``b_max``, ``a_max``] (m/s^2) after ``lead_s`` and up to ``free_s`` (s; elsewhere unbounded), its braking
    unbounded from ``impact_s`` (s) on (a crash stops a vehicle harder than its brakes); never decreasing. More
    than ``MAX_SAMPLES`` samples are solved in consecutive pieces of at most that many, each kept but for its last
    ``LOOK_AHEAD`` samples and the next starting on the last two kept (held there, ``JOIN_WEIGHT``)."""
    n = len(t)
    w = np.ones(n) if weight is None else np.asarray(weight, float)
    if n <= MAX_SAMPLES:
        return _bounded(t, s, a_max, b_max, w, free_s, lead_s, impact_s)
    out = np.empty(n)
    lo = 0
    while True:
        hi = min(n, lo + MAX_SAMPLES)
        ss, ww = s[lo:hi].copy(), w[lo:hi].copy()
        if lo:
            ss[:2], ww[:2] = out[lo : lo + 2], np.maximum(ww[:2], JOIN_WEIGHT)
        piece = _bounded(t[lo:hi], ss, a_max, b_max, ww, free_s, lead_s, impact_s)
        if hi == n:
            out[lo:hi] = piece
            return np.maximum.accumulate(out)
        keep = MAX_SAMPLES - LOOK_AHEAD  # the rest only shapes where the kept part ends
        out[lo : lo + keep] = piece[:keep]
        lo += keep - 2


def _bounded(
    t: np.ndarray,
    s: np.ndarray,
    a_max: float,
    b_max: float,
    w: np.ndarray,
    free_s: float,
    lead_s: float,
    impact_s: float = np.inf,
) -> np.ndarray:
    """:func:`bounded_distances` in one least squares (SciPy's ``lsq_linear``, bvls)."""
    n = len(t)
    A = np.hstack([np.ones((n, 1)), (t - t[0])[:, None], np.maximum(t[:, None] - t[None, 1:-1], 0.0)])
    inner = t[1:-1]
    unbounded = (inner > free_s + 1e-6) | (inner < lead_s + 1e-6)
    half = np.where(unbounded, np.inf, 0.5 * (t[2:] - t[:-2]))
    lb = np.concatenate([[-np.inf, 0.0], np.where(inner >= impact_s - 1e-6, -np.inf, -b_max * half)])
    ub = np.concatenate([[np.inf, np.inf], a_max * half])
    x = lsq_linear(A * w[:, None], s * w, bounds=(lb, ub), method="bvls").x
    return np.maximum.accumulate(A @ x)
