"""The ego within its traction: its measured distance along its path re-timed so that a vehicle can drive it.

A dashcam's monocular ego-motion takes its metric scale from the road's parallax; where the road gives
none for a while (snow, a textureless road, a rescaled or re-filmed copy of the clip) the speed is held
and then jumps to the next measurement (ccd_000053 upscaled to 1920x1080: 1.4 -> 7 m/s within 1 s,
6.4 m/s^2; filmed off a screen: 3.3 -> 9.7 m/s, 7.3 m/s^2). The simulator's vehicle accelerates at most
``Kinematics.max_accel_mps2`` and brakes at most ``max_brake_mps2``: its replay of such a path lagged
1-1.4 m behind it and missed the crash the scenario was made to have.

Here the ego's distance along its (raw) path, smoothed as stage 2 smooths it, is replaced by the closest one
(least squares on a 0.1 s grid, ``alongpath.bounded_distances``, as every processed road user's in ``traction``)
whose acceleration stays within ``margin`` x those limits (the rest is the replay's path follower's headroom),
and every agent is moved with the ego at its time: the agents were placed relative to the camera and stay where
the camera saw them (the raw scenario's reprojection is unchanged; the error of a held speed is the ego's,
common to everything it placed). An ego that already keeps within the limits is unchanged.

A crash of the ego is an impact, not braking: from the crash on its braking is unbounded and its distances are
smoothed apart from the approach's, so that an ego-motion's reading of the impact's stop (ccd_000053 filmed off a
screen: 13.3 -> 1.5 m/s within 0.2 s of the crash) is not re-timed back into the approach (it was: 11.1 -> 8.7 m/s
over its last 0.5 s, and the processed ego then asked 12 m/s^2 at the crash). Times in seconds, positions in metres
(world frame), accelerations in m/s^2.
"""

from __future__ import annotations

import numpy as np

from deepcrashtest.scenario import Kinematics, Scenario, kinematics
from deepcrashtest.trajectory.alongpath import along_path, arc_length, bounded_distances
from deepcrashtest.trajectory.egoheading import carry_with_ego, smooth_series

GRID_S = 0.1
"""Spacing (s) of the re-timed profile's samples: its acceleration is constant between them."""
MIN_TRAVEL_M = 1.0
"""An ego that travels less than this (metres) is left alone (a parked camera's noise)."""


def ego_within_traction(
    raw: Scenario,
    window_s: float,
    margin: float,
    warnings: list[str],
    kin: Kinematics | None = None,
    impact_s: float = np.inf,
) -> tuple[Scenario, float]:
    """``raw`` with the ego re-timed along its path within ``margin`` x its kinematics' acceleration and
    braking (its speed smoothed over ``window_s`` s, as stage 2 smooths it; braking unbounded from the ego's crash
    at ``impact_s``, s, world time, on; inf: no crash of the ego) and every agent moved with it
    (see the module docstring); returns it and the largest shift of the ego (metres, 0: unchanged)."""
    kin = kin or kinematics(raw.ego.category)
    e = raw.ego.trajectory.arrays()
    t, xy = e["t"], np.column_stack([e["x"], e["y"]])
    s = arc_length(xy)
    if len(t) < 5 or s[-1] < MIN_TRAVEL_M:
        return raw, 0.0
    m = int(np.ceil((t[-1] - t[0]) / GRID_S - 1e-9)) + 1
    tg = np.linspace(t[0], t[-1], m)
    dt = float(tg[1] - tg[0])
    sg = np.interp(tg, t, _smoothed_apart(t, s, window_s, impact_s))
    a_max, b_max = margin * kin.max_accel_mps2, margin * kin.max_brake_mps2
    acc = np.diff(sg, 2) / dt**2
    before = tg[1:-1] < impact_s - 1e-6
    if m < 4 or (acc.max() <= a_max and acc[before].min(initial=0.0) >= -b_max):
        return raw, 0.0
    ds = np.interp(t, tg, bounded_distances(tg, sg, a_max, b_max, impact_s=impact_s) - sg)
    shift = along_path(xy, s, s + ds) - xy
    largest = float(np.hypot(*shift.T).max())
    warnings.append(
        f"ego: its measured speed changes at up to {max(acc.max(), -acc.min()):.1f} m/s^2 (ego-motion scale "
        f"held where the road gave none?), more than a vehicle's {a_max:.1f} / -{b_max:.1f} m/s^2; re-timed "
        f"along its path within them (moved up to {largest:.1f} m), the agents moved with it"
    )
    return carry_with_ego(raw, t, shift), largest


def _smoothed_apart(t: np.ndarray, s: np.ndarray, window_s: float, impact_s: float) -> np.ndarray:
    """The distances ``s`` (m) at ``t`` (s) smoothed over ``window_s`` on either side of ``impact_s`` (s) apart: the
    impact's stop is not smeared into the approach."""
    after = t > impact_s + 1e-6
    if after.sum() < 5 or (~after).sum() < 5:
        return smooth_series(t, s, window_s)
    return np.concatenate([smooth_series(t[~after], s[~after], window_s), smooth_series(t[after], s[after], window_s)])
