"""The simulated world of a Scenario: time grid, vehicle sizes and masses, reference motions.

Existence convention: a vehicle exists from its ``trajectory.t[0]`` to ``trajectory.t[-1]``
(rounded to the grid) and is absent outside that span: after its last sample it leaves the world,
because nothing observed says where it went (a vehicle kept alive at constant velocity could cause
collisions that never happened). Two exceptions: the ego exists for the whole run (it is the
system under test; past its last sample it holds its last heading and speed), and a vehicle that
has collided stays in the world, sliding under Box2D physics, to the end of the run.

Agents of a processed scenario replay their trajectories exactly (:func:`exact_agents`): they are
recorded road users, not systems under test, and stage 2 already made their paths smooth and the
crash happen; steering them along a re-smoothed path with the vehicle model missed the crash by
decimetres on slow, noisy tracks. The ego always drives the vehicle model.
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace
from typing import Any

import numpy as np

from deepcrashtest.errors import ScenarioError, UserError
from deepcrashtest.scenario import Scenario, interp_heading
from deepcrashtest.sim.reference import PathSet, Reference, reference_from_trajectory
from deepcrashtest.sim.vehicle import CATEGORY_MASS_KG, HOLONOMIC_CATEGORIES, WHEELBASE_FRACTION, VehicleLimits

MAX_DURATION_S = 600.0


@dataclass
class World:
    """Everything about a scenario the simulation loop needs (index 0 is the ego).

    Build it once with :func:`build_world` (or ``sim.prepare``) and pass it to ``simulate_batch``
    as often as needed: it is not modified by a run, except for the agents' recorded run
    (``sim.agents.agent_timeline``), which is computed on first use and cached in ``timelines``.
    """

    scenario: Scenario
    dt: float
    times: np.ndarray  # (T,) s
    ids: list[int]
    length: np.ndarray  # (N,) m
    width: np.ndarray  # (N,) m
    wheelbase: np.ndarray  # (N,) m
    mass: np.ndarray  # (N,) kg
    holonomic: np.ndarray  # (N,) bool: replays its reference exactly (pedestrians; agents of a processed scenario)
    refs: list[Reference]
    agent_paths: PathSet | None
    duration: float = 0.0  # s, times[-1]
    timelines: dict[VehicleLimits, Any] = field(default_factory=dict, repr=False, compare=False)
    """Cache of ``sim.agents.AgentTimeline`` per vehicle limits (filled by ``sim.agents.agent_timeline``)."""

    @property
    def n_agents(self) -> int:
        return len(self.ids) - 1

    @property
    def half(self) -> np.ndarray:
        """(N, 2) half length, half width."""
        return 0.5 * np.column_stack([self.length, self.width])


def exact_agents(scenario: Scenario) -> bool:
    """Whether the agents replay their trajectories exactly (a processed scenario: stage 2 made them
    smooth and crash-consistent, so the crash happens when each takes its recorded pose) instead of
    being steered along a re-smoothed path by the vehicle model (raw, label-derived tracks)."""
    return scenario.stage == "processed"


def _reference(vid: int, traj: Any, times: np.ndarray, dt: float, smooth: bool) -> Reference:
    """:func:`reference_from_trajectory`, a refusal naming the vehicle."""
    try:
        return reference_from_trajectory(traj, times, dt, smooth=smooth)
    except ScenarioError as exc:
        raise ScenarioError(f"vehicle {vid}: {exc}") from None


def _own_headings(vehicles: list[Any], refs: list[Reference], times: np.ndarray) -> np.ndarray:
    """(M, T) heading (rad) of each moving agent's trajectory at the grid ``times`` (s), held before its first
    and after its last sample; NaN for static agents (they hold their pose).

    An agent replayed exactly takes its scenario heading rather than its path's direction: stage 2 keeps a
    moving agent's heading fitted to its boxes where the video saw it (``trajectory/agentheading.py``), and
    its path's direction is the monocular track's (range noise, or the ego-motion's error: ccd_000487's
    car crossing broadside was replayed pointing at the camera, reprojection IoU 0.43)."""
    out = np.full((len(vehicles), len(times)), np.nan)
    for row, (v, r) in enumerate(zip(vehicles, refs, strict=True)):
        if not r.static:
            a = v.trajectory.arrays()
            out[row] = interp_heading(times, a["t"], a["yaw"])
    return out


def _facing(ref: Reference, yaw: np.ndarray) -> Reference:
    """``ref`` starting with its own heading ``yaw`` (T,) rad at its first grid step (a moving agent replayed
    exactly, see :func:`_own_headings`), or ``ref`` itself where it has none."""
    if ref.static or not np.isfinite(yaw[ref.start]):
        return ref
    return replace(ref, init=np.array([ref.init[0], ref.init[1], yaw[ref.start], ref.init[3]]))


def build_world(scenario: Scenario, dt: float = 0.02, duration: float | None = None) -> World:
    """Resample every vehicle's trajectory into references on a uniform grid of step ``dt``."""
    if not (np.isfinite(dt) and 0.001 <= dt <= 0.1):
        raise UserError(f"time step dt={dt} s is outside 0.001-0.1 s")
    dur = scenario.duration() if duration is None else float(duration)
    if not (np.isfinite(dur) and 0.0 < dur <= MAX_DURATION_S):
        raise UserError(f"duration {dur} s must be > 0 and <= {MAX_DURATION_S:.0f} s")
    times = np.arange(int(round(dur / dt)) + 1) * dt
    if len(times) < 2:
        raise UserError(f"duration {dur} s is shorter than one time step ({dt} s)")
    vehicles = scenario.vehicles()
    exact = exact_agents(scenario)
    refs = [_reference(v.id, v.trajectory, times, dt, not exact) for v in vehicles]
    yaw_ref = _own_headings(vehicles[1:], refs[1:], times) if exact and len(refs) > 1 else None
    if yaw_ref is not None:
        refs[1:] = [_facing(r, yaw) for r, yaw in zip(refs[1:], yaw_ref, strict=True)]
    agent_paths = PathSet.stack(refs[1:], dt, yaw_ref) if len(refs) > 1 else None
    length = np.array([v.length for v in vehicles], float)
    return World(
        scenario=scenario,
        dt=float(dt),
        times=times,
        ids=[v.id for v in vehicles],
        length=length,
        width=np.array([v.width for v in vehicles], float),
        wheelbase=WHEELBASE_FRACTION * length,
        mass=np.array([CATEGORY_MASS_KG[v.category] for v in vehicles], float),
        holonomic=np.array([(exact and i > 0) or v.category in HOLONOMIC_CATEGORIES for i, v in enumerate(vehicles)]),
        refs=refs,
        agent_paths=agent_paths,
        duration=float(times[-1]),
    )
