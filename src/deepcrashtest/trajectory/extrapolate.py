"""Where agents are when the video does not show them (world frame, metres; seconds).

* After an agent leaves the view it continues along the road at its last lateral offset:
  oncoming (D1) at constant speed, same-direction (D0) at min(own speed, ratio x ego speed), so it
  stays slower than the ego. Speed changes are rate-limited (no jump in speed).
* Before a D0T2 agent (an overtaker) appears, it follows the ego at a safe gap behind, mimicking
  the ego's motion, then closes in at a constant relative acceleration and arrives at its first
  observed position with its first observed relative speed. Its relative station only grows, so
  it is behind where it is first seen (never visible earlier) and it keeps its own lane.
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np

from deepcrashtest.trajectory.roadframe import RoadFrame


def speed_profile(t: np.ndarray, v0: float, target: np.ndarray, accel_mps2: float) -> np.ndarray:
    """Speeds at times ``t`` (t[0] = start, speed ``v0``) moving toward ``target`` at <= ``accel_mps2``."""
    v = np.empty(len(t))
    v[0] = v0
    for k in range(1, len(t)):
        step = accel_mps2 * (t[k] - t[k - 1])
        v[k] = v[k - 1] + np.clip(target[k] - v[k - 1], -step, step)
    return np.maximum(v, 0.0)


def along_road(
    frame: RoadFrame,
    s0: float,
    d0: float,
    direction: int,
    t: np.ndarray,
    speed: np.ndarray,
) -> np.ndarray:
    """Points (N, 2) of a vehicle starting at station ``s0``, offset ``d0`` at t[0] and driving along the
    road (``direction`` +1 with the road, -1 against it) with the given speeds (trapezoidal integration)."""
    ds = np.concatenate([[0.0], np.cumsum(0.5 * (speed[1:] + speed[:-1]) * np.diff(t))])
    return frame.point(s0 + direction * ds, d0)


def continue_after(
    frame: RoadFrame,
    last_xy: np.ndarray,
    last_speed: float,
    last_heading: float,
    t_last: float,
    t: np.ndarray,
    oncoming: bool,
    ego_speed: Callable[[np.ndarray], np.ndarray],
    ratio: float,
    accel_mps2: float,
    blend_s: float = 1.5,
) -> np.ndarray:
    """Extrapolated points (N, 2) at times ``t`` (all > ``t_last``) after an agent leaves the view.

    It starts straight along ``last_heading`` (radians) and joins the road-following path within
    ``blend_s`` seconds (smoothstep blend), so neither position nor heading jumps."""
    tt = np.concatenate([[t_last], t])
    if oncoming:
        target = np.full(len(tt), last_speed)
    else:
        target = np.minimum(last_speed, ratio * ego_speed(tt))
    v = speed_profile(tt, last_speed, target, accel_mps2)
    s0, d0 = frame.project(last_xy[None, :])
    direction = -1 if oncoming else 1
    on_road = along_road(frame, float(s0[0]), float(d0[0]), direction, tt, v)
    # blend from straight ahead (last heading) onto the road over blend_s, so the heading turns smoothly
    ds = np.concatenate([[0.0], np.cumsum(0.5 * (v[1:] + v[:-1]) * np.diff(tt))])
    u = np.array([np.cos(last_heading), np.sin(last_heading)])
    straight = last_xy[None, :] + ds[:, None] * u[None, :]
    w = smoothstep((tt - t_last) / blend_s)[:, None]
    return ((1 - w) * straight + w * on_road)[1:]


def smoothstep(x: np.ndarray) -> np.ndarray:
    """0 below 0, 1 above 1, C1 cubic 3x^2 - 2x^3 between."""
    x = np.clip(x, 0.0, 1.0)
    return x * x * (3 - 2 * x)


def continue_before(
    frame: RoadFrame,
    first_xy: np.ndarray,
    first_speed: float,
    first_heading: float,
    t_first: float,
    t: np.ndarray,
    oncoming: bool,
    blend_s: float = 1.5,
) -> np.ndarray:
    """Points (N, 2) at times ``t`` (all < ``t_first``) at constant speed along the road, ending at the
    first observed point (for agents seen a few frames after the start)."""
    s0, d0 = frame.project(first_xy[None, :])
    direction = -1 if oncoming else 1
    on_road = frame.point(s0[0] + direction * first_speed * (t - t_first), d0[0])
    u = np.array([np.cos(first_heading), np.sin(first_heading)])
    straight = first_xy[None, :] + (first_speed * (t - t_first))[:, None] * u[None, :]
    w = smoothstep((t_first - t) / blend_s)[:, None]
    return (1 - w) * straight + w * on_road


def overtaker_relative_station(
    t: np.ndarray, t_first: float, r0: float, w0: float, gap_m: float, rel_accel: float
) -> tuple[np.ndarray, float]:
    """Relative station r(t) = agent - ego (metres) of a D0T2 agent before it is first seen.

    r = -gap (mimics the ego), then a phase of constant relative acceleration ``rel_accel`` from
    relative speed 0 to ``w0`` > 0, then constant relative speed ``w0`` until r(t_first) = r0.
    The gap is enlarged if needed so that the acceleration phase fits. Returns (r, gap used).
    """
    gap = max(gap_m, w0**2 / (2 * rel_accel) - r0)
    tau_a = w0 / rel_accel
    tau_c = (r0 + gap - w0**2 / (2 * rel_accel)) / w0
    tau = t_first - np.asarray(t, dtype=float)  # time before the first sighting
    r = np.where(
        tau <= tau_c,
        r0 - w0 * tau,
        np.where(tau <= tau_c + tau_a, -gap + 0.5 * rel_accel * (tau_c + tau_a - tau) ** 2, -gap),
    )
    return r, gap
