"""Kinematic single-track (bicycle) model, vectorised over rows (variants x vehicles).

State per row: centre position ``x, y`` (m, world frame), heading ``yaw`` (rad), speed ``v`` (m/s,
>= 0, along the velocity of the centre) and road-wheel steering angle ``steer`` (rad, left positive).
The centre sits midway between the axles (l_r = l_f = wheelbase / 2), so the slip angle of the
centre is ``beta = atan(tan(steer) / 2)`` and the yaw rate ``v * cos(beta) * tan(steer) / wheelbase``.

Limits are applied here, whatever the controller asks: steering angle and rate, acceleration,
braking. Speed is clamped at zero inside the step (the vehicle stops exactly where a constant
deceleration would stop it and never rolls backwards).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from deepcrashtest.scenario import VEHICLE_KINEMATICS

#: Road-user mass by category, kg (typical kerb mass + driver; two-wheelers with their rider; an adult).
CATEGORY_MASS_KG = {
    "car": 1500.0,
    "van": 2200.0,
    "truck": 9000.0,
    "bus": 12000.0,
    "motorcycle": 250.0,
    "bicycle": 95.0,
    "pedestrian": 75.0,
}
#: Categories that move without a vehicle's kinematics: a pedestrian steps sideways, turns on the spot
#: and stops at once, so the simulator replays its reference path exactly (``PathSet.pose_at``)
#: instead of steering a bicycle model along it.
HOLONOMIC_CATEGORIES = frozenset({"pedestrian"})
#: Wheelbase as a fraction of overall length (passenger cars: 2.7 m / 4.5 m).
WHEELBASE_FRACTION = VEHICLE_KINEMATICS.wheelbase_fraction


@dataclass(frozen=True)
class VehicleLimits:
    """Actuator limits of every simulated vehicle (SI units); defaults: ``scenario.VEHICLE_KINEMATICS``,
    the limits stage 2 keeps its crash corrections within."""

    max_steer: float = VEHICLE_KINEMATICS.max_steer_rad  # rad road-wheel angle (~34 deg)
    max_steer_rate: float = VEHICLE_KINEMATICS.max_steer_rate_rps  # rad/s road-wheel angle
    max_accel: float = VEHICLE_KINEMATICS.max_accel_mps2  # m/s^2 (traction)
    max_brake: float = VEHICLE_KINEMATICS.max_brake_mps2  # m/s^2 (tyre-limited on dry asphalt)


def slip_angle(steer: np.ndarray) -> np.ndarray:
    """Slip angle of the centre (rad) for a road-wheel angle ``steer`` with the centre mid-wheelbase."""
    return np.arctan(0.5 * np.tan(steer))


def yaw_rate(v: np.ndarray, steer: np.ndarray, wheelbase: np.ndarray) -> np.ndarray:
    """Yaw rate (rad/s) of the kinematic bicycle at speed ``v`` and road-wheel angle ``steer``."""
    return v * np.cos(slip_angle(steer)) * np.tan(steer) / wheelbase


def velocity_xy(yaw: np.ndarray, v: np.ndarray, steer: np.ndarray) -> np.ndarray:
    """(..., 2) world velocity of the centre, m/s."""
    course = yaw + slip_angle(steer)
    return np.stack([v * np.cos(course), v * np.sin(course)], axis=-1)


def _clip_nan_zero(x: np.ndarray, lo: float, hi: float) -> np.ndarray:
    """``x`` clipped to [lo, hi] (lo <= 0 <= hi), NaN -> 0: ``clip(nan_to_num(x, nan=0))`` without its copies."""
    out = np.minimum(np.maximum(x, lo), hi)
    nan = np.isnan(out)
    return np.where(nan, 0.0, out) if nan.any() else out


def limit_commands(
    accel_cmd: np.ndarray, steer_cmd: np.ndarray, steer: np.ndarray, dt: float, limits: VehicleLimits
) -> tuple[np.ndarray, np.ndarray]:
    """Clip commanded acceleration and steering to the actuator limits; returns (accel, new steer)."""
    accel = _clip_nan_zero(accel_cmd, -limits.max_brake, limits.max_accel)
    target = _clip_nan_zero(steer_cmd, -limits.max_steer, limits.max_steer)
    rate = limits.max_steer_rate * dt
    return accel, steer + np.minimum(np.maximum(target - steer, -rate), rate)


def bicycle_step(
    state: np.ndarray, accel: np.ndarray, steer: np.ndarray, wheelbase: np.ndarray, dt: float
) -> np.ndarray:
    """Advance ``state`` (R, 4) = x, y, yaw, v by ``dt`` with (already limited) ``accel`` and ``steer``.

    The distance travelled is exact for constant acceleration, including stopping inside the step:
    ``tau = min(dt, v / |a|)`` when braking, ``d = v tau + a tau^2 / 2``. Heading and position use
    the mean speed of the step (``d / dt``). Returns a new (R, 4) array.
    """
    x, y, yaw, v = state[:, 0], state[:, 1], state[:, 2], state[:, 3]
    braking = accel < 0.0
    t_stop = np.where(braking, v / np.where(braking, -accel, 1.0), np.inf)
    tau = np.minimum(dt, t_stop)
    dist = v * tau + 0.5 * accel * tau * tau
    v_new = np.maximum(v + accel * tau, 0.0)
    v_mean = dist / dt
    beta = slip_angle(steer)
    yaw_new = yaw + v_mean * np.cos(beta) * np.tan(steer) / wheelbase * dt
    course = 0.5 * (yaw + yaw_new) + beta
    out = np.empty_like(state)
    out[:, 0] = x + dist * np.cos(course)
    out[:, 1] = y + dist * np.sin(course)
    out[:, 2] = yaw_new
    out[:, 3] = v_new
    return out
