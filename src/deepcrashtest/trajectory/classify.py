"""Trajectory classes of the reference paper, decided along the road relative to the ego.

* D0 = same direction as the ego, D1 = oncoming. Direction: the agent's heading against the road
  tangent at its position (|difference| > 90 deg = oncoming). A moving agent's heading is the
  direction of its net displacement; a parked/static agent's is its box yaw.
* D0T1: in view from the first frame. D0T2: enters later from behind (it is faster than the ego
  and first seen closer than ``overtake_entry_gap_m`` ahead). D0T3: enters later from ahead.
* D1T1: in view at the start, the ego passes it. D1T2: in view at the start, not passed.
  D1T3: enters later, passed. D1T4: enters later, not passed. "Passed" = its centre crosses behind
  the ego's centre (station along the road) before the end of the scenario, counting the
  constant-speed extrapolation after it leaves the view.

Parked/static agents (``static`` below) get the class their box heading and their visibility
give (a static car can never overtake: late ones are D0T3); they are not moved (see pipeline).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True)
class ClassFeatures:
    """What the class is decided from (stations in metres along the road, speeds in m/s)."""

    oncoming: bool
    in_view_at_start: bool
    static: bool
    entry_gap_m: float
    """Agent station minus ego station when first seen."""
    entry_rel_speed_mps: float
    """Agent speed along the ego's direction minus the ego's, when first seen."""
    passed: bool
    """The agent's station drops below the ego's before the end."""


def trajectory_class(f: ClassFeatures, overtake_entry_gap_m: float) -> str:
    """D0T1 .. D1T4 from the features (rules in the module docstring)."""
    if not f.oncoming:
        if f.in_view_at_start:
            return "D0T1"
        if not f.static and f.entry_rel_speed_mps > 0 and f.entry_gap_m < overtake_entry_gap_m:
            return "D0T2"
        return "D0T3"
    if f.in_view_at_start:
        return "D1T1" if f.passed else "D1T2"
    return "D1T3" if f.passed else "D1T4"


def is_oncoming(heading: float, road_tangent: float) -> bool:
    """Heading (radians) more than 90 deg away from the road tangent (radians)."""
    return bool(np.cos(heading - road_tangent) < 0)


def is_static(t: np.ndarray, xy: np.ndarray, speed_mps: float, min_displacement_m: float) -> bool:
    """Parked/static: net displacement below ``min_displacement_m`` or below ``speed_mps`` x duration."""
    disp = float(np.hypot(*(xy[-1] - xy[0])))
    return disp < max(min_displacement_m, speed_mps * float(t[-1] - t[0]))


def circular_mean(angles: np.ndarray) -> float:
    a = np.asarray(angles, dtype=float)
    return float(np.arctan2(np.sin(a).mean(), np.cos(a).mean()))
