"""Step-back initialisation: every vehicle starts at rest and reaches its first observed state together.

With acceleration a (m/s^2) and first observed speeds v_i (m/s):
t_i = v_i / a (time to reach v_i), d_i = v_i^2 / (2 a) (distance meanwhile), t_max = max t_i,
D_i = d_i + (t_max - t_i) v_i. Vehicle i starts at rest D_i metres behind its first observed
position (along its initial heading), accelerates at a for t_i and then holds v_i; at t_max every
vehicle is at its first observed position with its first observed speed, so the relative
positions and speeds the video starts with are reproduced exactly at t_max. The video follows,
shifted by t_max.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from deepcrashtest.errors import UserError


@dataclass(frozen=True)
class StepBackPlan:
    """Per-vehicle t_i (s), d_i (m), D_i (m) and the common t_max (s) for acceleration ``accel`` (m/s^2)."""

    accel: float
    speeds: np.ndarray
    t_i: np.ndarray
    d_i: np.ndarray
    D_i: np.ndarray
    t_max: float


def plan_step_back(speeds: np.ndarray, accel: float) -> StepBackPlan:
    """Solve the synchronisation equations for first observed speeds ``speeds`` (m/s)."""
    v = np.asarray(speeds, dtype=float)
    if not np.isfinite(accel) or accel <= 0:
        raise UserError(f"step-back acceleration must be > 0 m/s^2 (got {accel})")
    if v.size and (not np.all(np.isfinite(v)) or v.min() < 0):
        raise UserError("step-back needs finite, non-negative first speeds")
    t_i = v / accel
    d_i = v**2 / (2 * accel)
    t_max = float(t_i.max()) if v.size else 0.0
    return StepBackPlan(accel, v, t_i, d_i, d_i + (t_max - t_i) * v, t_max)


def distance_from_rest(t: np.ndarray, v: float, accel: float) -> np.ndarray:
    """Distance (m) covered by time ``t`` (s) starting at rest: 0.5 a t^2 until v is reached, then v t."""
    t = np.asarray(t, dtype=float)
    t_i = v / accel
    return np.where(t <= t_i, 0.5 * accel * t**2, v**2 / (2 * accel) + v * (t - t_i))


def step_back_prefix(first_xy: np.ndarray, heading: float, v: float, plan: StepBackPlan, t: np.ndarray) -> np.ndarray:
    """Points (N, 2) at scenario times ``t`` in [0, t_max] of a vehicle whose first observed position
    ``first_xy`` (metres), heading (radians) and speed ``v`` (m/s) are reached at t_max."""
    D = v**2 / (2 * plan.accel) + (plan.t_max - v / plan.accel) * v
    back = D - distance_from_rest(t, v, plan.accel)
    u = np.array([np.cos(heading), np.sin(heading)])
    return np.asarray(first_xy, float)[None, :] - back[:, None] * u[None, :]
