"""Small edits to a Scenario's trajectories: move one waypoint, or shift a whole trajectory.

These are the fixes the reference paper's editing tools make before simulating (a bad initial
position, two boxes that overlap): minor lateral/longitudinal displacements of waypoints.

Every edit keeps the rest of the vehicle consistent with its new positions, over the same times:

* speed and yaw change by exactly as much as the motion derived from the positions changes
  (central differences, as in :mod:`deepcrashtest.datasets.kitti.scenario`). A trajectory whose speed
  was derived from its positions therefore stays derived from them; measured details (label yaw,
  smoothed speeds) are kept where nothing moved. Yaw only follows the motion where the vehicle
  moves (>= :data:`MOVING_MPS` before and after the edit): a parked car keeps its heading.
* a spline parameterisation (:class:`~deepcrashtest.scenario.SplineParams`, same knots and degree)
  gets the least-squares change of its control points that reproduces the displacement of the samples.
* the edit is appended, as one readable line, to ``provenance.history``.

The result is a new Scenario made by :meth:`Scenario.evolve` (the input is never changed), validated
as a whole, so an edit that breaks the schema is refused with a :class:`~deepcrashtest.errors.ScenarioError`
naming the field. A waypoint drag on a processed scenario that would need more than the physical
acceleration limit is refused first, with the falloff (or the shorter move) that would work.

Frames: world frame (x forward, y left, metres). "Vehicle frame" means each sample's own heading:
``d_lon`` along ``yaw``, ``d_lat`` to the left of it.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from typing import Any

import numpy as np

from deepcrashtest.errors import UserError
from deepcrashtest.scenario import MAX_ACCEL_MPS2, Scenario, Vehicle, wrap_angle

#: Below this speed (m/s) the direction of motion is noise: yaw is not changed there.
MOVING_MPS = 0.5
#: Largest displacement an edit accepts, metres (these are minor fixes, not new scenarios).
MAX_DISPLACEMENT_M = 200.0
#: Default half-width of the smooth falloff of a waypoint drag, seconds (see ``bench/viewer_drag.py``).
DEFAULT_FALLOFF_S = 1.5
#: Falloffs tried, shortest first, when a drag is refused, to say which one would work (seconds).
FALLOFF_LADDER_S = (0.5, 0.75, 1.0, 1.5, 2.0, 3.0, 4.0, 6.0, 8.0)


class EditError(UserError, ValueError):
    """An edit request that cannot be applied (unknown vehicle, bad index, non-finite number...)."""


def apply_edit(scenario: Scenario, edit: Mapping[str, Any]) -> Scenario:
    """Apply one edit given as a JSON object and return the new (validated) Scenario.

    ``{"kind": "move_waypoint", "vehicle_id": 3, "index": 12, "x": 10.0, "y": -2.0, "falloff_s": 1.5}``
    or ``{"kind": "shift", "vehicle_id": 3, "d_lon": 1.0, "d_lat": -0.5}``.
    """
    if not isinstance(edit, Mapping):
        raise EditError(f"edit: expected a JSON object, got {type(edit).__name__}")
    kind = edit.get("kind")
    if kind == "move_waypoint":
        _only(edit, {"kind", "vehicle_id", "index", "x", "y", "falloff_s"})
        return move_waypoint(
            scenario,
            _int(edit, "vehicle_id"),
            _int(edit, "index"),
            _num(edit, "x"),
            _num(edit, "y"),
            falloff_s=_num(edit, "falloff_s", DEFAULT_FALLOFF_S),
        )
    if kind == "shift":
        _only(edit, {"kind", "vehicle_id", "d_lon", "d_lat"})
        return shift_trajectory(scenario, _int(edit, "vehicle_id"), _num(edit, "d_lon", 0.0), _num(edit, "d_lat", 0.0))
    raise EditError(f"edit.kind must be 'move_waypoint' or 'shift' (got {kind!r})")


def move_waypoint(
    scenario: Scenario, vehicle_id: int, index: int, x: float, y: float, falloff_s: float = DEFAULT_FALLOFF_S
) -> Scenario:
    """Move sample ``index`` of a vehicle to world ``(x, y)``; neighbours within ``falloff_s`` follow.

    The neighbours move by the same displacement times a raised-cosine weight of their time
    distance (1 at the waypoint, 0 at ``falloff_s`` seconds), so a drag does not create a jump
    that no car could drive; ``falloff_s = 0`` moves the single waypoint.
    """
    veh = _vehicle(scenario, vehicle_id)
    a = veh.trajectory.arrays()
    n = len(a["t"])
    if not 0 <= index < n:
        raise EditError(f"edit.index {index} is outside vehicle {vehicle_id}'s {n} samples")
    _finite(x=x, y=y, falloff_s=falloff_s)
    if falloff_s < 0:
        raise EditError(f"edit.falloff_s must be >= 0 (got {falloff_s})")
    dx, dy = x - a["x"][index], y - a["y"][index]
    _limit(math.hypot(dx, dy))
    if scenario.stage == "processed":
        amax = drag_accel(veh, index, dx, dy, falloff_s)
        if amax > MAX_ACCEL_MPS2:
            raise EditError(
                f"moving vehicle {vehicle_id}'s waypoint {math.hypot(dx, dy):.2f} m with a drag falloff of "
                f"{falloff_s:g} s needs |acceleration| {amax:.1f} m/s^2, above the physical limit "
                f"{MAX_ACCEL_MPS2:g} m/s^2; {drivable_alternatives(veh, index, dx, dy, falloff_s)} would work"
            )
    w = falloff_weights(a["t"], index, falloff_s)
    note = (
        f"move_waypoint vehicle={vehicle_id} index={index} t={a['t'][index]:.3f}s to ({x:.3f}, {y:.3f}) m "
        f"[d=({dx:+.3f}, {dy:+.3f}) m, falloff {falloff_s:g} s]"
    )
    return _replace(scenario, veh, a["x"] + w * dx, a["y"] + w * dy, note)


def shift_trajectory(scenario: Scenario, vehicle_id: int, d_lon: float, d_lat: float) -> Scenario:
    """Shift every sample by ``d_lon`` along its own heading and ``d_lat`` to its left (metres).

    On a straight path this is a translation (speed and yaw unchanged); on a curve the lateral
    shift gives the parallel path, whose length, and so speed, is recomputed.
    """
    veh = _vehicle(scenario, vehicle_id)
    _finite(d_lon=d_lon, d_lat=d_lat)
    _limit(math.hypot(d_lon, d_lat))
    a = veh.trajectory.arrays()
    c, s = np.cos(a["yaw"]), np.sin(a["yaw"])
    x = a["x"] + d_lon * c - d_lat * s
    y = a["y"] + d_lon * s + d_lat * c
    if scenario.stage == "processed":
        amax = accel_after(veh, x, y)
        if amax > MAX_ACCEL_MPS2:
            dx, dy = x - a["x"], y - a["y"]
            frac = largest_fraction(lambda f: accel_after(veh, a["x"] + f * dx, a["y"] + f * dy) <= MAX_ACCEL_MPS2)
            raise EditError(
                f"shifting vehicle {vehicle_id} by {d_lon:+.2f} m along and {d_lat:+.2f} m across its heading needs "
                f"|acceleration| {amax:.1f} m/s^2 (a parallel path of a curve is longer or shorter), above the "
                f"physical limit {MAX_ACCEL_MPS2:g} m/s^2; a shift of at most {_cm_down(frac * d_lon):+.2f} m along "
                f"and {_cm_down(frac * d_lat):+.2f} m across would work"
            )
    note = f"shift vehicle={vehicle_id} d_lon={d_lon:+.3f} m d_lat={d_lat:+.3f} m (vehicle frame)"
    return _replace(scenario, veh, x, y, note)


def falloff_weights(t: np.ndarray, index: int, falloff_s: float) -> np.ndarray:
    """Raised-cosine weights in time around sample ``index``: 1 there, 0 beyond ``falloff_s`` seconds."""
    w = np.zeros(len(t))
    if falloff_s <= 0:
        w[index] = 1.0
        return w
    d = np.abs(np.asarray(t, float) - t[index]) / falloff_s
    inside = d < 1.0
    w[inside] = 0.5 * (1.0 + np.cos(np.pi * d[inside]))
    return w


def motion(t: np.ndarray, x: np.ndarray, y: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Speed (m/s) and direction of motion (rad) from positions, central differences in time."""
    if len(t) < 2:
        return np.zeros(len(t)), np.zeros(len(t))
    vx, vy = np.gradient(x, t), np.gradient(y, t)
    return np.hypot(vx, vy), np.arctan2(vy, vx)


def _derived(veh: Vehicle, x: np.ndarray, y: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Speed and yaw of ``veh`` after its positions become ``x, y`` (see the module docstring)."""
    a = veh.trajectory.arrays()
    v_old, h_old = motion(a["t"], a["x"], a["y"])
    v_new, h_new = motion(a["t"], x, y)
    speed = np.maximum(a["speed"] + (v_new - v_old), 0.0)
    moving = (v_old >= MOVING_MPS) & (v_new >= MOVING_MPS)
    yaw = a["yaw"] + np.where(moving, wrap_angle(h_new - h_old), 0.0)
    return speed, yaw


def _replace(scenario: Scenario, veh: Vehicle, x: np.ndarray, y: np.ndarray, note: str) -> Scenario:
    """The scenario with ``veh``'s positions replaced; yaw, speed and spline follow (``Scenario.evolve``)."""
    speed, yaw = _derived(veh, x, y)
    traj = veh.trajectory.model_copy(
        update={"x": x.tolist(), "y": y.tolist(), "yaw": yaw.tolist(), "speed": speed.tolist()}
    )
    update: dict[str, Any] = {"trajectory": traj}
    if veh.spline is not None:
        dcx, dcy = spline_control_shift(veh, x - np.asarray(veh.trajectory.x), y - np.asarray(veh.trajectory.y))
        update["spline"] = veh.spline.model_copy(
            update={"cx": (np.asarray(veh.spline.cx) + dcx).tolist(), "cy": (np.asarray(veh.spline.cy) + dcy).tolist()}
        )
    new_veh = veh.model_copy(update=update)
    history = [*scenario.provenance.history, note]
    changes: dict[str, Any] = {"provenance": scenario.provenance.model_copy(update={"history": history})}
    if veh.id == scenario.ego.id:
        changes["ego"] = new_veh
    else:
        changes["agents"] = [new_veh if a.id == veh.id else a for a in scenario.agents]
    return scenario.evolve(**changes)


def accel_after(veh: Vehicle, x: np.ndarray, y: np.ndarray) -> float:
    """Largest |acceleration| (m/s^2) of ``veh`` once its positions are ``x, y`` (speed as the edit derives it)."""
    t = np.asarray(veh.trajectory.t, float)
    if len(t) < 2:
        return 0.0
    speed, _ = _derived(veh, x, y)
    return float(np.abs(np.diff(speed) / np.diff(t)).max())


def drag_accel(veh: Vehicle, index: int, dx: float, dy: float, falloff_s: float) -> float:
    """Largest |acceleration| (m/s^2) of ``veh`` after moving sample ``index`` by ``(dx, dy)`` with ``falloff_s``."""
    a = veh.trajectory.arrays()
    w = falloff_weights(a["t"], index, falloff_s)
    return accel_after(veh, a["x"] + w * dx, a["y"] + w * dy)


def largest_fraction(drivable: Any, steps: int = 12) -> float:
    """The largest fraction f in [0, 1] of an edit with ``drivable(f)`` true (bisection; 0 when none)."""
    lo, hi = 0.0, 1.0
    for _ in range(steps):
        mid = 0.5 * (lo + hi)
        if drivable(mid):
            lo = mid
        else:
            hi = mid
    return lo


def _cm_down(v: float) -> float:
    """``v`` rounded towards zero to whole centimetres (a suggestion printed with 2 decimals must still work)."""
    return math.copysign(math.floor(abs(v) * 100.0) / 100.0, v)


def drivable_alternatives(veh: Vehicle, index: int, dx: float, dy: float, falloff_s: float) -> str:
    """What would work instead of a drag that breaks :data:`MAX_ACCEL_MPS2`: a longer falloff, or a shorter move."""
    d = math.hypot(dx, dy)
    falloff = next(
        (f for f in FALLOFF_LADDER_S if f > falloff_s and drag_accel(veh, index, dx, dy, f) <= MAX_ACCEL_MPS2), None
    )
    frac = largest_fraction(lambda f: drag_accel(veh, index, f * dx, f * dy, falloff_s) <= MAX_ACCEL_MPS2)
    parts = []
    if falloff is not None:
        parts.append(f"a drag falloff of {falloff:g} s")
    if frac * d >= 0.01:
        parts.append(f"a move of at most {_cm_down(frac * d):.2f} m at {falloff_s:g} s")
    return " or ".join(parts) if parts else "a smaller move with a longer falloff"


def spline_control_shift(veh: Vehicle, dx: np.ndarray, dy: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Least-squares (minimum-norm) change of the spline's control points matching sample displacements.

    The spline is x(t), y(t) = BSpline(knots, cx|cy, degree); samples outside the knots' base
    interval are clamped onto it. A constant displacement moves every control point it constrains
    by that constant (B-splines sum to one).
    """
    from scipy.interpolate import BSpline

    sp = veh.spline
    assert sp is not None
    knots, k = np.asarray(sp.knots, float), sp.degree
    t = np.clip(np.asarray(veh.trajectory.t, float), knots[k], knots[-k - 1])
    basis = BSpline.design_matrix(t, knots, k).toarray()
    sol = np.linalg.lstsq(basis, np.column_stack([dx, dy]), rcond=None)[0]
    return sol[:, 0], sol[:, 1]


def _vehicle(scenario: Scenario, vehicle_id: int) -> Vehicle:
    try:
        return scenario.vehicle(vehicle_id)
    except KeyError:
        ids = [v.id for v in scenario.vehicles()]
        raise EditError(f"edit.vehicle_id {vehicle_id} is not a vehicle of this scenario (ids: {ids})") from None


def _only(edit: Mapping[str, Any], allowed: set[str]) -> None:
    extra = sorted(set(edit) - allowed)
    if extra:
        raise EditError(f"edit: unknown field(s) {extra} for kind {edit.get('kind')!r}")


def _int(edit: Mapping[str, Any], key: str) -> int:
    v = edit.get(key)
    if isinstance(v, bool) or not isinstance(v, int):
        raise EditError(f"edit.{key} must be an integer (got {v!r})")
    return v


def _num(edit: Mapping[str, Any], key: str, default: float | None = None) -> float:
    v = edit.get(key, default)
    if isinstance(v, bool) or not isinstance(v, int | float):
        raise EditError(f"edit.{key} must be a number (got {v!r})")
    _finite(**{key: float(v)})
    return float(v)


def _finite(**values: float) -> None:
    for name, v in values.items():
        if not math.isfinite(v):
            raise EditError(f"edit.{name} must be a finite number (got {v})")


def _limit(d: float) -> None:
    if d > MAX_DISPLACEMENT_M:
        raise EditError(f"edit moves a waypoint {d:.1f} m: more than the {MAX_DISPLACEMENT_M:g} m allowed")
