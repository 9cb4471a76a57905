"""Every processed road user within its traction and braking: a path that asks more is re-timed along itself.

Stage 2 changes each path's speed after the raw ego's re-timing (``trajectory.egotraction``): its smoothing
(Savitzky-Golay + two-level spline), the crash correction (whose fallback, where no correction within the
steering limits exists, bounds only the acceleration it adds on each axis), the lead-in and the final spline.
On a copy of ccd_000053 filmed off a screen the raw ego, re-timed within 3.4 m/s^2, came out of the smoothing
at 4.12 m/s^2, 1.6 s before the crash; the simulator's vehicle (``Kinematics.max_accel_mps2``, 4 m/s^2) lags
such a path. Here the distance along such a path is replaced by the closest one (least squares,
``alongpath.bounded_distances``, as the raw ego's in ``egotraction``) whose acceleration between samples
stays within ``margin`` x those limits; its samples from ``pin_s`` on (a crash pair's contact and the overlap
after it) are held where they are (weighted ``PIN_WEIGHT`` times, their own speed changes left as they are:
the impact's), so the crash keeps its time and place. The path's shape is unchanged. Times in seconds,
positions in metres (world frame), accelerations in m/s^2.
"""

from __future__ import annotations

import numpy as np

from deepcrashtest.scenario import Kinematics
from deepcrashtest.trajectory.alongpath import along_path, arc_length, bounded_distances

PIN_WEIGHT = 1e3
"""Weight of a pinned sample's distance against 1 for the others: pinned samples move by millimetres."""
WINDOW_S = 1.5
"""Only the samples within this many seconds of where a path asks too much are re-timed (the speed change
is spread over them; the whole path's least squares cost 20-80 s CPU on the highway clip's long tracks)."""


def beyond_traction(t: np.ndarray, speed: np.ndarray, kin: Kinematics) -> np.ndarray:
    """(len(t) - 1,) True for each pair of consecutive samples (times ``t`` s, strictly increasing) between which
    the speed ``speed`` (m/s) rises faster than ``kin.max_accel_mps2`` or falls faster than ``kin.max_brake_mps2``."""
    acc = np.diff(speed) / np.diff(t)
    return (acc > kin.max_accel_mps2) | (acc < -kin.max_brake_mps2)


def exceeding_s(t: np.ndarray, speed: np.ndarray, kin: Kinematics, lead_s: float = -np.inf) -> np.ndarray:
    """Times (s) of the consecutive samples between which the speeds ``speed`` (m/s) at times ``t`` (s) change
    beyond ``kin``'s traction (:func:`beyond_traction`; ``np.gradient``'s values are weighted means of these, so
    they keep within the limits too); only intervals from ``lead_s`` on."""
    if len(t) < 2:
        return np.zeros(0)
    bad = np.nonzero(beyond_traction(t, speed, kin) & (t[:-1] >= lead_s - 1e-6))[0]
    return np.concatenate([t[bad], t[bad + 1]])


def retimed_within(
    t: np.ndarray,
    xy: np.ndarray,
    kin: Kinematics,
    margin: float,
    pin_s: float | None = None,
    around_s: np.ndarray | None = None,
    lead_s: float = -np.inf,
) -> np.ndarray:
    """The path ``xy`` (m, N x 2) at times ``t`` (s) re-timed along itself within ``margin`` x ``kin``'s
    acceleration and braking, its samples from ``pin_s`` (s) on held (module docstring). ``around_s``: only
    within ``WINDOW_S`` of these times (s), each stretch of them on its own, the samples beyond held (the whole
    path: None). ``lead_s``: the samples up to it (s; the step-back lead-in from rest, built within the limits)
    held as they are."""
    if len(t) < 4:
        return xy
    s = arc_length(xy)
    weight = np.ones(len(t)) if pin_s is None else np.where(t >= pin_s - 1e-6, PIN_WEIGHT, 1.0)
    weight[t <= lead_s + 1e-6] = PIN_WEIGHT
    free = np.inf if pin_s is None else pin_s  # the held samples' own speed changes (the impact's) are left
    s_new = s.copy()
    a_max, b_max = margin * kin.max_accel_mps2, margin * kin.max_brake_mps2
    for lo, hi in _windows(t, around_s):
        w = weight[lo:hi].copy()
        w[: 2 if lo else 0] = PIN_WEIGHT  # held where it joins the rest: position and speed
        w[len(w) - 2 if hi < len(t) else len(w) :] = PIN_WEIGHT
        s_new[lo:hi] = bounded_distances(t[lo:hi], s[lo:hi], a_max, b_max, w, free, lead_s)
    return along_path(xy, s, s_new)


def _windows(t: np.ndarray, around_s: np.ndarray | None) -> list[tuple[int, int]]:
    """Sample ranges ``[lo, hi)`` to re-time: within ``WINDOW_S`` (s) of the times ``around_s`` (s) and 2 samples
    more each side, ranges that overlap or touch merged into one; the whole path without ``around_s``. Apart,
    each is its own least squares: a track whose speed jumps at both ends of its 20 s solved at once cost
    seconds (the least squares grows as the cube of its samples: 2 s for 770 samples on the highway clip)."""
    if around_s is None or not len(around_s):
        return [(0, len(t))]
    out: list[tuple[int, int]] = []
    for a in np.unique(around_s):
        lo = max(0, int(np.searchsorted(t, a - WINDOW_S)) - 2)
        hi = min(len(t), int(np.searchsorted(t, a + WINDOW_S)) + 2)
        if out and lo <= out[-1][1]:
            out[-1] = (out[-1][0], max(hi, out[-1][1]))
        else:
            out.append((lo, hi))
    return out
