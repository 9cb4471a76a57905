"""Step-back initialisation: every vehicle starts at rest and reaches its first observed state together.

With acceleration a (m/s^2) and first observed speeds v_i (m/s):
t_i = v_i / a (time to reach v_i), d_i = v_i^2 / (2 a) (distance meanwhile), t_max = max t_i,
D_i = d_i + (t_max - t_i) v_i. Vehicle i starts at rest D_i metres behind its first observed
position (along its initial heading), accelerates at a for t_i and then holds v_i; at t_max every
vehicle is at its first observed position with its first observed speed, so the relative
positions and speeds the video starts with are reproduced exactly at t_max. The video follows,
shifted by t_max.

A lead-in longer than ``t_cap`` (what drivers do in the seconds before a crash, not a drag race) is
cut to ``t_cap``: vehicles faster than ``a t_cap`` then start at ``v_i - a t_cap`` instead of rest,
so nobody is launched from far away and parked or crawling vehicles stay where they were seen.
"""

from __future__ import annotations

from dataclasses import dataclass, replace

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


def plan_step_back(speeds: np.ndarray, accel: float, t_cap: float | None = None) -> StepBackPlan:
    """Solve the synchronisation equations for first observed speeds ``speeds`` (m/s), t_max <= ``t_cap`` (s)."""
    v = np.asarray(speeds, dtype=float)
    if not np.isfinite(accel) or accel <= 0:
        raise UserError(f"step-back acceleration must be > 0 m/s^2 (got {accel})")
    if v.size and (not np.all(np.isfinite(v)) or v.min() < 0):
        raise UserError("step-back needs finite, non-negative first speeds")
    t_max = float(v.max() / accel) if v.size else 0.0
    if t_cap is not None:
        t_max = min(t_max, float(t_cap))
    v_start = np.maximum(v - accel * t_max, 0.0)
    t_i = (v - v_start) / accel
    d_i = (v**2 - v_start**2) / (2 * accel)
    return StepBackPlan(accel, v, t_i, d_i, d_i + (t_max - t_i) * v, t_max)


def distance_from_rest(t: np.ndarray, v: float, accel: float, v_start: float = 0.0) -> np.ndarray:
    """Distance (m) covered by time ``t`` (s) starting at ``v_start`` (default rest): accelerating at
    ``accel`` until v is reached, then holding v."""
    t = np.asarray(t, dtype=float)
    t_i = (v - v_start) / accel
    ramp = v_start * t + 0.5 * accel * t**2
    return np.where(t <= t_i, ramp, (v**2 - v_start**2) / (2 * accel) + v * (t - t_i))


def step_back_prefix(first_xy: np.ndarray, heading: float, v: float, plan: StepBackPlan, t: np.ndarray) -> np.ndarray:
    """Points (N, 2) at scenario times ``t`` in [0, t_max] of a vehicle whose first observed position
    ``first_xy`` (metres), heading (radians) and speed ``v`` (m/s) are reached at t_max."""
    v_start = max(v - plan.accel * plan.t_max, 0.0)
    t_i = (v - v_start) / plan.accel
    D = (v**2 - v_start**2) / (2 * plan.accel) + (plan.t_max - t_i) * v
    back = D - distance_from_rest(t, v, plan.accel, v_start)
    u = np.array([np.cos(heading), np.sin(heading)])
    return np.asarray(first_xy, float)[None, :] - back[:, None] * u[None, :]


@dataclass(frozen=True)
class LeadIn:
    """One vehicle's step-back lead-in: from rest (or ``plan``'s capped start) along ``heading`` (rad) to its first
    observed position ``first_xy`` (m) and speed ``speed`` (m/s), reached at ``plan.t_max``."""

    first_xy: np.ndarray
    heading: float
    speed: float
    plan: StepBackPlan

    def positions(self, t: np.ndarray, accel: float | None = None) -> np.ndarray:
        """Points (N, 2) at scenario times ``t`` (s, within [0, t_max]); ``accel`` (m/s^2): this vehicle's own
        acceleration instead of the plan's (a gentler one starts it nearer its first observed position)."""
        plan = self.plan if accel is None else replace(self.plan, accel=float(accel))
        return step_back_prefix(self.first_xy, self.heading, self.speed, plan, t)

    def gentler_accels(self, steps: int = 8) -> np.ndarray:
        """Accelerations (m/s^2) below the plan's, gentlest last, down to the one that still starts from rest
        (``speed / t_max``); none where the plan's lead-in is capped (the vehicle does not start from rest)."""
        lo = self.speed / self.plan.t_max if self.plan.t_max > 0 else np.inf
        if not lo < self.plan.accel:
            return np.zeros(0)
        return np.linspace(self.plan.accel, lo, steps + 1)[1:]
