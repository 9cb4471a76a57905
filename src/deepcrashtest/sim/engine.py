"""Public entry points: ``simulate`` (one run, full states) and ``simulate_batch`` (many ego variants).

Both share one vectorised loop (:mod:`deepcrashtest.sim.loop`). Differences:

* ``simulate`` runs one variant and keeps going after an impact: colliding vehicles slide under
  Box2D to rest, the others continue their replay; all states are returned.
* ``simulate_batch`` runs ``B`` variants together; a variant ends at its first collision (its
  delta-v comes from a two-body Box2D impact). Chunks of ``CHUNK`` variants may run in worker
  processes; noise of chunk ``c`` is seeded with ``(seed, c)`` whatever the number of workers, so
  results do not depend on ``workers``. ``simulate`` uses the stream of chunk 0.
"""

from __future__ import annotations

import multiprocessing
from concurrent.futures import ProcessPoolExecutor
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from deepcrashtest.errors import UserError, check_seed
from deepcrashtest.scenario import Scenario
from deepcrashtest.sim.agents import agent_timeline
from deepcrashtest.sim.controllers import controller_name, resolve_controller
from deepcrashtest.sim.loop import Contact, LoopOutput, finish_contacts, is_replay_controller, run_loop
from deepcrashtest.sim.memory import retain_freed_memory
from deepcrashtest.sim.reference import PathSet, build_pathset
from deepcrashtest.sim.replay_batch import replay_batch_available, run_replay_batch
from deepcrashtest.sim.rollout import PackedPaths
from deepcrashtest.sim.vehicle import VehicleLimits
from deepcrashtest.sim.world import World, build_world

CHUNK = 2048


def prepare(scenario: Scenario, dt: float = 0.02, duration: float | None = None) -> World:
    """Build the simulated world of ``scenario`` once, for many ``simulate``/``simulate_batch`` calls.

    The world holds the vehicles' smoothed references (the slow part of a call, ~0.3 s for a KITTI
    drive) and, after the first batch, the agents' recorded run. Pass it instead of the scenario;
    results are identical to passing the scenario (the same world is built either way).
    """
    return build_world(scenario, dt, duration)


def _world(source: Scenario | World, dt: float, duration: float | None) -> World:
    """``source`` itself when it is a prepared World (``dt``/``duration`` must agree), else a new one."""
    if not isinstance(source, World):
        return build_world(source, dt, duration)
    if abs(dt - source.dt) > 1e-12 or (duration is not None and abs(float(duration) - source.duration) > 0.5 * dt):
        raise UserError(
            f"prepared world has dt={source.dt} s and duration {source.duration} s; got dt={dt}, duration={duration}"
        )
    return source


def _rng(seed: int, chunk: int) -> np.random.Generator:
    return np.random.default_rng(np.random.SeedSequence([int(seed), int(chunk)]))


def _num(v: float) -> float | None:
    """A plain float, or None for NaN/inf (JSON has neither)."""
    return float(v) if np.isfinite(v) else None


@dataclass
class SimResult:
    """One simulation run.

    ``states[t, i]`` = x, y, yaw, speed of ``vehicle_ids[i]`` at ``times[t]`` (NaN where absent;
    ``present`` says where it exists). ``collisions``: every contact in time order, with the
    vehicles, impact point (m), relative speed (m/s) and delta-v per vehicle (m/s); the ego's and
    every pair of agents' (a third-party crash). ``metrics["first_contact"]`` is the first of any pair.
    """

    metrics: dict[str, Any]
    times: np.ndarray
    vehicle_ids: list[int]
    states: np.ndarray
    present: np.ndarray
    collisions: list[dict[str, Any]] = field(default_factory=list)
    controller: str = "replay"
    dt: float = 0.02

    @property
    def collision(self) -> dict[str, Any] | None:
        """The first collision involving the ego, or None."""
        ego = self.vehicle_ids[0]
        return next((c for c in self.collisions if ego in c["vehicles"]), None)

    @property
    def first_contact(self) -> dict[str, Any] | None:
        """The first contact of any pair (ego-agent or agent-agent), or None."""
        return self.collisions[0] if self.collisions else None

    def contact_between(self, a: int, b: int) -> dict[str, Any] | None:
        """The first contact between road users ``a`` and ``b`` (ids), or None."""
        return next((c for c in self.collisions if set(c["vehicles"]) == {a, b}), None)

    def present_at(self, t: np.ndarray, column: int) -> tuple[np.ndarray, np.ndarray]:
        """(steps, present) at scenario times ``t`` (s) of the vehicle in column ``column``: each time's nearest step
        of the run (clipped into it) and whether the vehicle exists there, inside the run."""
        k = np.rint(np.asarray(t, float) / self.dt).astype(int)
        inside = (k >= 0) & (k < len(self.times))
        k = np.clip(k, 0, len(self.times) - 1)
        return k, inside & self.present[k, column]

    def pose_at(self, t: float, column: int) -> tuple[float, float, float] | None:
        """(x, y, yaw) (m, m, rad; world frame) of the vehicle in column ``column`` at scenario time ``t`` (s), its
        nearest step (:meth:`present_at`); None where it does not exist then or ``t`` is outside the run."""
        k, present = self.present_at(np.array([t]), column)
        if not present[0]:
            return None
        x, y, yaw = self.states[int(k[0]), column, :3]
        return float(x), float(y), float(yaw)


@dataclass
class BatchResult:
    """Per-variant metrics of a batch, arrays of shape (B,). NaN/inf where not applicable.

    ``collision_agent`` is the id of the vehicle hit (-1 none); ``robustness`` is the minimum
    separation between the ego and any other vehicle (m), negative (minus penetration) on collision.
    """

    collided: np.ndarray
    collision_time: np.ndarray
    collision_agent: np.ndarray
    relative_speed: np.ndarray
    min_distance: np.ndarray
    min_ttc: np.ndarray
    robustness: np.ndarray
    aeb_time: np.ndarray
    warning_time: np.ndarray
    delta_v_ego: np.ndarray
    delta_v_other: np.ndarray

    def __len__(self) -> int:
        return len(self.collided)

    def variant(self, i: int) -> dict[str, Any]:
        """Metrics of variant ``i`` as plain Python values."""
        out: dict[str, Any] = {}
        for name in self.__dataclass_fields__:
            v = getattr(self, name)[i]
            out[name] = bool(v) if v.dtype == bool else int(v) if v.dtype.kind == "i" else _num(float(v))
        return out


# --------------------------------------------------------------------------- ego variants
def _ego_frame_offsets(world: World, offsets: np.ndarray) -> np.ndarray:
    yaw0 = float(world.refs[0].init[2])
    c, s = np.cos(yaw0), np.sin(yaw0)
    return np.column_stack([c * offsets[:, 0] - s * offsets[:, 1], s * offsets[:, 0] + c * offsets[:, 1]])


def _ego_variants(
    world: World, ego_offsets: np.ndarray, ego_paths: np.ndarray | None
) -> tuple[PathSet, np.ndarray, np.ndarray, np.ndarray]:
    """PathSet, path index per variant, world offset per variant and initial states (B, 4)."""
    off = _ego_frame_offsets(world, ego_offsets)
    B = len(off)
    if ego_paths is None:
        ref = world.refs[0]
        init = np.tile(ref.init, (B, 1))
        init[:, :2] += off
        return PathSet.stack([ref], world.dt), np.zeros(B, np.intp), off, init
    traj = world.scenario.ego.trajectory
    t = np.linspace(traj.t[0], traj.t[-1], ego_paths.shape[1])
    yaw = np.interp(t, traj.t, traj.yaw)
    paths, init = build_pathset(t, ego_paths, yaw, world.times, world.dt)
    init[:, :2] += off
    return paths, np.arange(B, dtype=np.intp), off, init


def _packed(
    world: World, variants: tuple[PathSet, np.ndarray, np.ndarray, np.ndarray]
) -> tuple[PackedPaths, np.ndarray, np.ndarray, np.ndarray]:
    """The variants with their path set packed for the replay batch's roll-out, once for every chunk; the path set
    itself is dropped (the roll-out reads only the packed tables and profiles)."""
    paths, q, off, init = variants
    return PackedPaths.pack(paths, float(world.wheelbase[0])), q, off, init


def _check_batch_inputs(ego_offsets: Any, ego_paths: Any) -> tuple[np.ndarray, np.ndarray | None]:
    off = np.asarray(ego_offsets, dtype=float)
    if off.ndim != 2 or off.shape[1] != 2 or len(off) == 0:
        raise UserError(f"ego_offsets must have shape (B, 2), got {off.shape}")
    if not np.isfinite(off).all():
        raise UserError("ego_offsets contains non-finite values")
    if ego_paths is None:
        return off, None
    paths = np.asarray(ego_paths, dtype=float)
    if paths.ndim != 3 or paths.shape[0] != len(off) or paths.shape[2] != 2 or paths.shape[1] < 2:
        raise UserError(f"ego_paths must have shape ({len(off)}, K>=2, 2), got {paths.shape}")
    if not np.isfinite(paths).all():
        raise UserError("ego_paths contains non-finite values")
    return off, paths


# --------------------------------------------------------------------------- single run
def simulate(
    scenario: Scenario | World,
    controller: Any = "replay",
    dt: float | None = None,
    seed: int = 0,
    duration: float | None = None,
) -> SimResult:
    """Simulate ``scenario`` (or a world from :func:`prepare`) once with the ego driven by ``controller``.

    ``dt`` defaults to 0.02 s (a prepared world: its own).
    """
    check_seed(seed)
    world = _world(scenario, _dt(scenario, dt), duration)
    ctrl = resolve_controller(controller)
    paths, q, off, init = _ego_variants(world, np.zeros((1, 2)), None)
    out = run_loop(world, paths, q, off, init, ctrl, _rng(seed, 0), physics_mode=True, seed=seed)
    assert out.states is not None and out.present is not None
    return SimResult(
        metrics=_metrics(world, out),
        times=world.times.copy(),
        vehicle_ids=list(world.ids),
        states=out.states,
        present=out.present,
        collisions=[_contact_dict(world, c) for c in out.contacts],
        controller=controller_name(controller),
        dt=world.dt,
    )


def agent_collisions(world: World) -> list[dict[str, Any]] | None:
    """``simulate(world).collisions`` (replay controller) where the ego touches nobody, without the per-step run:
    the agents' contacts of the recorded run (:meth:`~deepcrashtest.sim.agents.AgentTimeline.agent_contacts`;
    the agents never see an ego that touches nobody, so theirs is the same run), with Box2D's delta-v and points.
    None where the ego's own replay touches someone (one batch variant, the ego's reference) or the run is not
    kept: only :func:`simulate` knows those.
    """
    recorded = agent_timeline(world, VehicleLimits()).agent_contacts()
    if recorded is None or simulate_batch(world, np.zeros((1, 2))).collided[0]:
        return None
    found, phys = recorded
    contacts = [Contact(t, a, b, rel) for a, b, t, rel in found]
    finish_contacts(contacts, phys)
    return [_contact_dict(world, c) for c in contacts]


def _contact_dict(world: World, c: Contact) -> dict[str, Any]:
    return {
        "time": round(c.time, 4),
        "vehicles": [world.ids[c.a], world.ids[c.b]],
        "point": None if c.point is None else [float(c.point[0]), float(c.point[1])],
        "relative_speed": _num(c.relative_speed),
        "delta_v": {str(world.ids[k]): _num(v) for k, v in c.delta_v.items()},
    }


def _metrics(world: World, out: LoopOutput) -> dict[str, Any]:
    collided = bool(out.collided[0])
    j = int(out.collision_agent[0])
    return {
        "collided": collided,
        "collision_time": _num(out.collision_time[0]),
        "collision_vehicle": world.ids[j] if j >= 0 else None,
        "relative_speed": _num(out.relative_speed[0]),
        "delta_v_ego": _num(out.delta_v_ego[0]),
        "delta_v_other": _num(out.delta_v_other[0]),
        "min_distance": _num(max(out.min_distance[0], 0.0)),
        "min_ttc": _num(out.min_ttc[0]),
        "robustness": _num(out.min_distance[0]),
        "aeb_time": _num(out.aeb_time[0]),
        "warning_time": _num(out.warning_time[0]),
        "n_collisions": len(out.contacts),
        "first_contact": _first_contact(world, out),
    }


def _first_contact(world: World, out: LoopOutput) -> dict[str, Any] | None:
    """Time (s), pair (ids) and relative speed (m/s) of the first contact of any two road users."""
    if not out.contacts:
        return None
    c = out.contacts[0]
    return {
        "time": round(c.time, 4),
        "vehicles": [world.ids[c.a], world.ids[c.b]],
        "relative_speed": _num(c.relative_speed),
    }


# --------------------------------------------------------------------------- batch
_JOB: dict[str, Any] = {}


def _run_chunk(c: int) -> LoopOutput:
    job = _JOB
    size = job["chunk"]
    lo, hi = c * size, min((c + 1) * size, job["B"])
    paths, q, off, init = job["variants"]
    if job["fast"]:  # the packed paths serve every chunk: released after the batch's only one
        return run_replay_batch(job["world"], paths, q[lo:hi], off[lo:hi], init[lo:hi], release=size >= job["B"])
    return run_loop(
        job["world"],
        paths,
        q[lo:hi],
        off[lo:hi],
        init[lo:hi],
        resolve_controller(job["controller"]),
        _rng(job["seed"], c),
        physics_mode=False,
        seed=job["seed"],
    )


def _dt(source: Scenario | World, dt: float | None) -> float:
    return dt if dt is not None else source.dt if isinstance(source, World) else 0.02


def simulate_batch(
    scenario: Scenario | World,
    ego_offsets: Any,
    ego_paths: Any = None,
    controller: Any = "replay",
    seed: int = 0,
    dt: float | None = None,
    duration: float | None = None,
    workers: int = 1,
    chunk_size: int = CHUNK,
    stepwise: bool = False,
) -> BatchResult:
    """Simulate ``B`` ego variants of ``scenario`` (or of a world from :func:`prepare`) together.

    ``ego_offsets`` (B, 2): start offsets (longitudinal, lateral) in metres in the ego's initial
    frame (x forward, y left); the whole ego reference is translated by it (the ego drives the same
    manoeuvre from a shifted start). ``ego_paths`` (B, K, 2), optional: perturbed ego reference
    positions (world frame, metres) at K times equally spaced over the ego trajectory's span
    ``[t[0], t[-1]]``; the ego follows them in time. ``workers`` > 1 runs chunks of
    ``chunk_size`` variants in that many processes (fork); results do not depend on ``workers``.
    ``dt`` defaults to 0.02 s (a prepared world: its own). Passing a prepared world skips
    rebuilding it; its agents' run is recorded by the first batch and reused by the next ones.
    With the replay controller the variants run through :mod:`deepcrashtest.sim.replay_batch` (the
    whole run of every ego at once, same outcomes); ``stepwise=True`` forces the per-step loop instead.
    """
    check_seed(seed)
    retain_freed_memory()
    off, paths = _check_batch_inputs(ego_offsets, ego_paths)
    world = _world(scenario, _dt(scenario, dt), duration)
    ctrl = resolve_controller(controller)  # fail early on a bad spec
    B = len(off)
    _JOB.clear()
    if chunk_size < 1:
        raise UserError(f"chunk_size must be >= 1 (got {chunk_size})")
    fast = not stepwise and is_replay_controller(ctrl) and replay_batch_available(world)
    variants = _packed(world, _ego_variants(world, off, paths)) if fast else _ego_variants(world, off, paths)
    _JOB.update(world=world, variants=variants, controller=controller, seed=seed, B=B, chunk=chunk_size, fast=fast)
    chunks = list(range((B + chunk_size - 1) // chunk_size))
    try:
        if workers > 1 and len(chunks) > 1:
            agent_timeline(world, VehicleLimits()).record_all()  # once, shared by the forked workers
            ctx = multiprocessing.get_context("fork")
            with ProcessPoolExecutor(max_workers=min(workers, len(chunks)), mp_context=ctx) as pool:
                outs = list(pool.map(_run_chunk, chunks))
        else:
            outs = [_run_chunk(c) for c in chunks]
    finally:
        _JOB.clear()

    def cat(name: str) -> np.ndarray:
        return np.concatenate([getattr(o, name) for o in outs])

    agent = cat("collision_agent")
    ids = np.array(world.ids)
    md = cat("min_distance")
    return BatchResult(
        collided=cat("collided"),
        collision_time=cat("collision_time"),
        collision_agent=np.where(agent >= 0, ids[np.maximum(agent, 0)], -1),
        relative_speed=cat("relative_speed"),
        min_distance=np.maximum(md, 0.0),
        min_ttc=cat("min_ttc"),
        robustness=md,
        aeb_time=cat("aeb_time"),
        warning_time=cat("warning_time"),
        delta_v_ego=cat("delta_v_ego"),
        delta_v_other=cat("delta_v_other"),
    )


# --------------------------------------------------------------------------- replay error
def replay_error(scenario: Scenario, result: SimResult, until_collision: bool = True) -> dict[str, Any]:
    """RMS distance (m) between simulated centres and the scenario's samples, per vehicle and overall.

    Compared at every sample time inside the run where the vehicle exists (and, by default,
    before the first collision). Returns ``{"ego": m, "agents": m, "all": m, "per_vehicle": {id: m}}``.
    """
    t_stop = result.times[-1]
    if until_collision and result.collisions:
        t_stop = min(c["time"] for c in result.collisions)
    per: dict[str, float] = {}
    sq_all: list[np.ndarray] = []
    sq_agents: list[np.ndarray] = []
    for i, v in enumerate(scenario.vehicles()):
        a = v.trajectory.arrays()
        k, pres = result.present_at(a["t"], i)
        pres &= a["t"] <= t_stop
        if not pres.any():
            continue
        d2 = (result.states[k[pres], i, 0] - a["x"][pres]) ** 2 + (result.states[k[pres], i, 1] - a["y"][pres]) ** 2
        per[str(v.id)] = float(np.sqrt(d2.mean()))
        sq_all.append(d2)
        if i > 0:
            sq_agents.append(d2)

    def rms(parts: list[np.ndarray]) -> float | None:
        return float(np.sqrt(np.concatenate(parts).mean())) if parts else None

    return {"ego": per.get(str(scenario.ego.id)), "agents": rms(sq_agents), "all": rms(sq_all), "per_vehicle": per}
