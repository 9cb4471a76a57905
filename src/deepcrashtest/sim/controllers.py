"""Ego controllers: the plug-in interface, ``replay`` and ``aeb``, and loading a user's controller.

Interface (vectorised over ``n`` variants stepped together)::

    class MyController:
        needs_sensors = True          # optional (default True): build radar/camera/GNSS observations
        def reset(self, n, dt, seed): # optional: called once before the run
            ...
        def __call__(self, obs):      # obs: deepcrashtest.sim.sensors.Observation
            return accel, steer       # (n,) arrays: m/s^2 (negative = braking), road-wheel angle rad
        brake_level: np.ndarray       # optional (n,) int: 0 none, 1 warning, 2 partial, 3 full braking
        def select(self, keep):       # optional: keep the state of rows ``keep`` (index array) only;
            ...                       # lets a batch drop finished variants (faster)

A plain function ``f(obs) -> (accel, steer)`` works too. Commands are clipped to the vehicle's
limits (steering angle and rate, +4 / -9 m/s^2). ``obs.replay_accel`` / ``obs.replay_steer`` are the
recorded driver's commands, so a driver-assistance function can pass them through and override.
"""

from __future__ import annotations

import importlib
import importlib.util
import inspect
import sys
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from deepcrashtest.errors import UserError
from deepcrashtest.sim.sensors import Observation

ControllerFn = Callable[[Observation], tuple[np.ndarray, np.ndarray]]


class ReplayController:
    """Follow the recorded path and speed profile (the commands are computed by the engine)."""

    needs_sensors = False

    def __call__(self, obs: Observation) -> tuple[np.ndarray, np.ndarray]:
        return obs.replay_accel, obs.replay_steer


@dataclass
class AebConfig:
    """Time-to-collision thresholds (s) and decelerations (m/s^2) of the built-in AEB."""

    ttc_warning: float = 2.6
    ttc_partial: float = 1.6
    ttc_full: float = 0.9
    partial_decel: float = 4.0
    full_decel: float = 9.0
    persistence_steps: int = 2  # consecutive steps a level must be met (noise rejection)
    lateral_margin: float = 0.3  # m added to the ego half width for the in-path test
    require_camera: bool = True  # braking needs radar + camera confirmation
    min_closing_speed: float = 0.5  # m/s
    oncoming_speed: float = 2.0  # m/s: targets approaching faster over ground are oncoming


class AebController:
    """Automatic emergency braking on radar + camera fusion with a time-to-collision rule.

    A target is in the ego's predicted path (arc from IMU yaw rate and speed) when the lateral offset
    of its nearest point from that arc is under half the ego width plus a margin. TTC = range /
    closing speed (radar). Oncoming targets (moving towards the ego over ground, the classic false
    alarm on curves) only count for full braking. Levels: warning, partial braking, full braking, each confirmed for
    ``persistence_steps``; braking demands ``min(driver, -decel)``. Full braking latches until the
    ego stands still, then the brake is held (the driver has to take over).
    """

    needs_sensors = True

    def __init__(self, config: AebConfig | None = None) -> None:
        self.cfg = config or AebConfig()
        self.brake_level = np.zeros(0, dtype=int)

    def reset(self, n: int, dt: float, seed: int) -> None:
        self.brake_level = np.zeros(n, dtype=int)
        self._count = np.zeros((3, n), dtype=int)
        self._latched = np.zeros(n, dtype=bool)

    def select(self, keep: np.ndarray) -> None:
        """Keep the state of rows ``keep`` only (the engine drops finished variants)."""
        self.brake_level, self._count, self._latched = self.brake_level[keep], self._count[:, keep], self._latched[keep]

    def __call__(self, obs: Observation) -> tuple[np.ndarray, np.ndarray]:
        if len(self.brake_level) != obs.n:
            self.reset(obs.n, obs.dt, 0)
        c = self.cfg
        valid = obs.radar_valid & (obs.camera_valid if c.require_camera else True)
        r = np.where(valid, obs.radar_range, 1e6)
        az = np.where(valid, obs.radar_azimuth, 0.0)
        xf, yf = r * np.cos(az), r * np.sin(az)
        kappa = obs.yaw_rate / np.maximum(obs.speed, 1.0)
        lateral = yf - 0.5 * kappa[:, None] * xf * xf
        in_path = valid & (np.abs(lateral) <= 0.5 * obs.ego_width + c.lateral_margin)
        rate = np.where(valid, obs.radar_range_rate, 0.0)
        closing = -rate
        # oncoming targets (ground speed towards the ego) only count for full braking at short TTC
        oncoming = obs.speed[:, None] + rate * np.cos(az) < -c.oncoming_speed
        ttc_all = np.where(in_path & (closing > c.min_closing_speed), r / np.maximum(closing, 1e-6), np.inf)
        ttc = np.where(oncoming, np.inf, ttc_all).min(axis=1, initial=np.inf)
        ttc_any = ttc_all.min(axis=1, initial=np.inf)
        met = np.stack([ttc < c.ttc_warning, ttc < c.ttc_partial, ttc_any < c.ttc_full])
        self._count = np.where(met, self._count + 1, 0)
        confirmed = self._count >= c.persistence_steps
        level = np.where(confirmed[2], 3, np.where(confirmed[1], 2, np.where(confirmed[0], 1, 0)))
        self._latched |= level == 3
        level = np.where(self._latched, 3, level)
        self.brake_level = level
        demand = np.where(level == 3, -c.full_decel, np.where(level == 2, -c.partial_decel, np.inf))
        accel = np.minimum(obs.replay_accel, demand)
        return accel, obs.replay_steer


BUILTIN = {"replay": ReplayController, "aeb": AebController}


def resolve_controller(spec: str | Any) -> Any:
    """``"replay"``, ``"aeb"``, ``"module:callable"``, ``"path/file.py:callable"`` or an object -> controller.

    A class named in a spec is instantiated without arguments; a callable object is used as is.
    """
    if not isinstance(spec, str):
        if not callable(spec):
            raise UserError(f"controller {spec!r} is not callable")
        return _instance(spec, repr(spec))
    if spec in BUILTIN:
        return BUILTIN[spec]()
    if ":" not in spec:
        raise UserError(f"controller {spec!r}: expected replay, aeb or module:callable")
    mod_name, _, attr = spec.rpartition(":")
    try:
        if mod_name.endswith(".py"):
            path = Path(mod_name)
            if not path.is_file():
                raise UserError(f"controller {spec!r}: no such file {path}")
            name = f"deepcrashtest_user_{path.stem}"
            sp = importlib.util.spec_from_file_location(name, path)
            if sp is None or sp.loader is None:
                raise UserError(f"controller {spec!r}: cannot load {path}")
            module = importlib.util.module_from_spec(sp)
            sys.modules[name] = module
            sp.loader.exec_module(module)
        else:
            module = importlib.import_module(mod_name)
    except UserError:
        raise
    except ImportError as exc:
        raise UserError(f"controller {spec!r}: cannot import {mod_name}: {exc}") from None
    except Exception as exc:  # the user's module failed while loading (SyntaxError, its own errors)
        raise UserError(f"controller {spec!r}: loading {mod_name} failed: {type(exc).__name__}: {exc}") from None
    obj = getattr(module, attr, None)
    if obj is None:
        raise UserError(f"controller {spec!r}: {mod_name} has no {attr!r}")
    if not callable(obj):
        raise UserError(f"controller {spec!r}: {attr!r} in {mod_name} is a {type(obj).__name__}, not callable")
    return _instance(obj, repr(spec))


def _instance(obj: Any, label: str) -> Any:
    """A class -> an instance made without arguments (checked callable); a callable as is."""
    if not inspect.isclass(obj):
        return obj
    try:
        inst = obj()
    except Exception as exc:
        raise UserError(f"controller {label}: creating {obj.__name__}() failed: {type(exc).__name__}: {exc}") from None
    if not callable(inst):
        raise UserError(f"controller {label}: {obj.__name__} instances are not callable (define __call__)")
    return inst


def call_controller(controller: Any, obs: Any, n: int) -> tuple[np.ndarray, np.ndarray]:
    """Call ``controller(obs)`` for ``n`` ego rows; returns (acceleration m/s^2, steering rad) arrays (n,).

    A user controller that raises, returns something other than two numbers or arrays of ``n``, or returns a
    non-finite value is reported as a UserError naming it and the problem.
    """
    name = controller_name(controller)
    try:
        res = controller(obs)
    except UserError:
        raise
    except Exception as exc:
        raise UserError(f"controller {name} raised {type(exc).__name__}: {exc}") from None
    if isinstance(res, str | bytes) or not isinstance(res, tuple | list) or len(res) != 2:
        raise UserError(
            f"controller {name} returned {_describe(res)}; expected (acceleration, steering): two numbers or arrays"
        )
    out = []
    for label, r in zip(("acceleration", "steering"), res, strict=True):
        try:
            a = np.asarray(r, dtype=float)
            a = np.array(np.broadcast_to(a, (n,)), dtype=float)
        except (TypeError, ValueError):
            raise UserError(
                f"controller {name} returned {label} {_describe(r)}; expected a number or {n} numbers"
            ) from None
        if not np.isfinite(a).all():
            raise UserError(f"controller {name} returned a non-finite {label} (NaN or infinity)")
        out.append(a)
    return out[0], out[1]


def _describe(v: Any) -> str:
    text = repr(v)
    return f"{type(v).__name__} {text[:60]}{'...' if len(text) > 60 else ''}"


def controller_name(spec: str | Any) -> str:
    """A short name for reports."""
    return spec if isinstance(spec, str) else getattr(spec, "__name__", type(spec).__name__)
