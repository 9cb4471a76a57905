"""deepcrashtest.sim: the built-in crash simulator (kinematic bicycle + AEB + Box2D impacts), vectorised.

Entry points: :func:`simulate` (one run, all states) and :func:`simulate_batch` (many ego variants
for the search); :func:`prepare` builds a scenario's world once for many calls. Controllers:
``"replay"``, ``"aeb"``, ``"module:callable"`` or any callable taking an
:class:`~deepcrashtest.sim.sensors.Observation` and returning ``(accel, steer)`` arrays.
"""

from deepcrashtest.sim.controllers import AebConfig, AebController, ReplayController, resolve_controller
from deepcrashtest.sim.engine import (
    BatchResult,
    SimResult,
    agent_collisions,
    prepare,
    replay_error,
    simulate,
    simulate_batch,
)
from deepcrashtest.sim.sensors import Observation, SensorConfig

__all__ = [
    "AebConfig",
    "AebController",
    "BatchResult",
    "Observation",
    "ReplayController",
    "SensorConfig",
    "SimResult",
    "agent_collisions",
    "prepare",
    "replay_error",
    "resolve_controller",
    "simulate",
    "simulate_batch",
]
