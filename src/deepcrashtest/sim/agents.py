"""The other vehicles (agents) of a simulation: their live state and, for batches, a recorded timeline.

Agents replay their references (Stanley + PID), touch each other (Box2D from then on) and never
depend on the ego in a batch: there a variant ends at its first collision, so the ego never enters
the physics world. The agents' whole run is therefore the same for every variant and every call:
:class:`AgentTimeline` computes it once per :class:`~deepcrashtest.sim.world.World` (in segments
of ``SEGMENT`` steps, all kept when small) and the batch loop reads it. ``simulate`` (one variant,
the ego slides into the agents after an impact) steps an :class:`AgentSet` live instead.
Both run exactly the same operations in the same order, so results are bit-identical.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from deepcrashtest.scenario import brush_past
from deepcrashtest.sim.boxes import contact_fraction, sat_gap
from deepcrashtest.sim.follow import Follower
from deepcrashtest.sim.physics import PhysicsWorld
from deepcrashtest.sim.vehicle import VehicleLimits, bicycle_step, limit_commands, velocity_xy, yaw_rate
from deepcrashtest.sim.world import World

#: Steps computed together by a timeline.
SEGMENT = 512
#: Largest timeline (steps x agents) kept in memory for reuse (~128 bytes each).
MAX_CACHED_ENTRIES = 1_000_000


def agent_gaps(ag: np.ndarray, ah: np.ndarray) -> np.ndarray:
    """(M, M) separating-axis gaps between agent boxes ``ag`` (M, >=3) with half extents ``ah`` (M, 2)."""
    return sat_gap(
        ag[:, None, 0], ag[:, None, 1], ag[:, None, 2], ah[:, None, 0], ah[:, None, 1],
        ag[None, :, 0], ag[None, :, 1], ag[None, :, 2], ah[None, :, 0], ah[None, :, 1],
    )  # fmt: skip


class AgentSet:
    """Live state of the ``M`` agents (vehicle indices 1..M) and the Box2D world they share with the ego."""

    def __init__(self, world: World, limits: VehicleLimits) -> None:
        self.world, self.lim = world, limits
        refs = world.refs[1:]
        M = self.M = world.n_agents
        self.half = world.half[1:]
        self.start = np.array([r.start for r in refs], dtype=int)
        self.end = np.array([r.end for r in refs], dtype=int)
        self.static = np.array([r.static for r in refs], dtype=bool)
        self.walk = world.holonomic[1:] & ~self.static
        self.brush = _brushing_pairs(world)
        """(M, M) pairs that pass each other without a contact (two pedestrians: :func:`scenario.brush_past`)."""
        self.state = np.array([r.init for r in refs], float).reshape(M, 4)
        self.steer = np.zeros(M)
        self.in_phys = np.zeros(M, dtype=bool)
        self.vel_phys = np.zeros((M, 2))
        self.omega_phys = np.zeros(M)
        self.follow = (
            Follower(world.agent_paths, np.arange(M), np.zeros((M, 2)), world.wheelbase[1:])
            if world.agent_paths is not None
            else None
        )
        self.phys: PhysicsWorld | None = None
        self.pres_prev = self.presence(0)
        if M > 1:
            gap = agent_gaps(self.state, self.half)
            self.ignore = (gap <= 0) & self.pres_prev[:, None] & self.pres_prev[None, :]
        else:
            self.ignore = np.zeros((M, M), bool)

    def presence(self, k: int) -> np.ndarray:
        """(M,) agents in the world at step ``k``."""
        return self.in_phys | ((self.start <= k) & (k <= self.end))

    def velocity(self) -> tuple[np.ndarray, np.ndarray]:
        """Current (M, 2) world velocities (m/s) and (M,) yaw rates (rad/s)."""
        v = velocity_xy(self.state[:, 2], self.state[:, 3], self.steer)
        w = yaw_rate(self.state[:, 3], self.steer, self.world.wheelbase[1:])
        return np.where(self.in_phys[:, None], self.vel_phys, v), np.where(self.in_phys, self.omega_phys, w)

    def new_velocity(self, new: np.ndarray, steer_new: np.ndarray) -> np.ndarray:
        """(M, 2) velocities of the candidate states ``new`` (physics bodies: their last velocity)."""
        return np.where(self.in_phys[:, None], self.vel_phys, velocity_xy(new[:, 2], new[:, 3], steer_new))

    def to_physics(self, idx: int, pose: np.ndarray, vel: np.ndarray, omega: float, t: float) -> None:
        """Vehicle ``idx`` (0 = ego) becomes a Box2D body (the world is created at time ``t``)."""
        w = self.world
        if self.phys is None:
            self.phys = PhysicsWorld()
            self.phys.time = t
        if idx in self.phys.bodies:
            return
        self.phys.add(idx, pose[:3], vel, omega, float(w.length[idx]), float(w.width[idx]), float(w.mass[idx]))

    def predict(self, k: int, dt: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Replay commands and kinematics: candidate states, steering at ``k + 1`` and presence at ``k + 1``."""
        assert self.follow is not None
        lim = self.lim
        a_acc, a_str = self.follow.command(self.state, k, dt)
        a_acc = np.where(self.static, -lim.max_brake, a_acc)
        moving = (self.start <= k) & (k < self.end) & ~self.in_phys
        a_acc_l, steer_new = limit_commands(a_acc, a_str, self.steer, dt, lim)
        new = np.where(
            moving[:, None], bicycle_step(self.state, a_acc_l, steer_new, self.world.wheelbase[1:], dt), self.state
        )
        steer_new = np.where(moving, steer_new, self.steer)
        walk = self.walk & moving
        if walk.any():  # pedestrians take their reference pose (see sim.vehicle.HOLONOMIC_CATEGORIES)
            assert self.world.agent_paths is not None
            new[walk] = self.world.agent_paths.pose_at(min(k + 1, len(self.world.times) - 1))[walk]
            steer_new[walk] = 0.0
        if self.phys is not None:
            for idx in self.phys.bodies:
                if idx > 0:
                    s, v, w = self.phys.state(idx)
                    new[idx - 1] = [s[0] + v[0] * dt, s[1] + v[1] * dt, s[2] + w * dt, s[3]]
        return new, steer_new, self.presence(k + 1)

    def join_contacts(self, k: int, new: np.ndarray, pres: np.ndarray) -> list[tuple[int, int, float, float]]:
        """Agents that touch during step ``k`` (not two pedestrians: ``brush``) continue under Box2D; returns (a, b,
        time, relative speed) each."""
        if self.M < 2:
            return []
        g_aa = agent_gaps(new, self.half)
        both = pres[:, None] & pres[None, :]
        newly = both & ~(self.pres_prev[:, None] & self.pres_prev[None, :])
        self.ignore |= newly & (g_aa <= 0)
        self.ignore &= ~(g_aa > 0)
        hit = both & (g_aa <= 0) & ~self.ignore & ~(self.in_phys[:, None] & self.in_phys[None, :]) & ~self.brush
        hit = np.triu(hit, 1)
        found = []
        for i, j in zip(*np.nonzero(hit), strict=True):
            found.append(self._join_pair(int(i), int(j), new, k))
            self.in_phys[[i, j]] = True
        return found

    def _join_pair(self, i: int, j: int, new: np.ndarray, k: int) -> tuple[int, int, float, float]:
        """Agents ``i`` and ``j`` (0-based) touch: both continue under Box2D from their pre-contact states."""
        w, s = self.world, self.state
        a, b = i + 1, j + 1
        half = w.half
        frac = contact_fraction(s[[i], :3], new[[i], :3], s[[j], :3], new[[j], :3], half[[a]], half[[b]])
        vel = velocity_xy(s[[i, j], 2], s[[i, j], 3], self.steer[[i, j]])
        om = yaw_rate(s[[i, j], 3], self.steer[[i, j]], w.wheelbase[[a, b]])
        t = float(w.times[k])
        self.to_physics(a, s[i], vel[0], float(om[0]), t)
        self.to_physics(b, s[j], vel[1], float(om[1]), t)
        return a, b, float(w.times[k] + frac[0] * w.dt), float(np.hypot(*(vel[0] - vel[1])))

    def from_physics(self, new: np.ndarray, steer_new: np.ndarray) -> None:
        """After a physics step: agents that are Box2D bodies take the bodies' states (in place)."""
        assert self.phys is not None
        for idx in self.phys.bodies:
            if idx > 0:
                s, v, w = self.phys.state(idx)
                new[idx - 1] = s
                self.vel_phys[idx - 1], self.omega_phys[idx - 1] = v, w
                steer_new[idx - 1] = 0.0

    def commit(self, new: np.ndarray, steer_new: np.ndarray) -> None:
        self.state, self.steer = new, steer_new


@dataclass
class _Segment:
    """Recorded agent quantities for steps ``k0 .. k0 + n - 1`` (first axis)."""

    k0: int
    state: np.ndarray  # (n, M, 4) at the step's start
    pres: np.ndarray  # (n, M) presence at the step's start
    vel: np.ndarray  # (n, M, 2) velocities at the step's start
    new: np.ndarray  # (n, M, 4) candidate states at k + 1 (before the physics step)
    pres_next: np.ndarray  # (n, M) presence at k + 1
    hit_vel: np.ndarray  # (n, M, 2) velocities after this step's agent-agent contacts
    hit_omega: np.ndarray  # (n, M)
    new_vel: np.ndarray  # (n, M, 2) velocities of the candidate states


class AgentTimeline:
    """The agents' whole run as seen by a batch of ego variants (independent of the ego), computed lazily.

    ``segment(k)`` returns the recorded segment holding step ``k``; steps must be asked in
    increasing order within one run (``rewind`` starts a new run). When the run is small
    (``steps x agents <= MAX_CACHED_ENTRIES``) every segment is kept and later runs reuse them.
    """

    def __init__(self, world: World, limits: VehicleLimits) -> None:
        self.world, self.limits = world, limits
        self.keep_all = len(world.times) * max(world.n_agents, 1) <= MAX_CACHED_ENTRIES
        self._segments: dict[int, _Segment] = {}
        self._live: AgentSet | None = None
        self._next = 0  # first step the live AgentSet has not recorded yet
        self._whole: _Segment | None = None
        self._contacts: list[tuple[int, int, float, float]] = []  # the live AgentSet's, in step order

    def rewind(self) -> None:
        if not self.keep_all:
            self._segments.clear()
            self._live, self._next = None, 0

    def record_all(self) -> None:
        """Record the whole run now (e.g. before forking workers, so that they share it); kept runs only."""
        if self.keep_all:
            for k in range(0, len(self.world.times) - 1, SEGMENT):
                self.segment(k)

    def whole(self) -> _Segment | None:
        """Every step's recorded quantities in one segment (``k0 = 0``), for kept runs only (else None)."""
        if not self.keep_all:
            return None
        n_seg = (len(self.world.times) - 2) // SEGMENT + 1
        if self._whole is None or len(self._segments) != n_seg:
            self.record_all()
            parts = [self._segments[i] for i in range(n_seg)]
            fields = [f for f in _Segment.__dataclass_fields__ if f != "k0"]
            self._whole = _Segment(0, *(np.concatenate([getattr(p, f) for p in parts]) for f in fields))
        return self._whole

    def agent_contacts(self) -> tuple[list[tuple[int, int, float, float]], PhysicsWorld | None] | None:
        """The agents' contacts of the whole recorded run, as :meth:`AgentSet.join_contacts` found them (vehicle
        indices, time in s, relative speed in m/s; in step order), and the Box2D world they continued in (None
        where no two agents touch); None for runs that are not kept (``keep_all`` False)."""
        if not self.keep_all:
            return None
        self.record_all()
        if self._live is None:  # recorded without stepping: no two agents ever touch
            return [], None
        return list(self._contacts), self._live.phys

    def segment(self, k: int) -> _Segment:
        s = self._segments.get(k // SEGMENT)
        if s is None and self.keep_all and not self._segments and self._live is None:
            whole = record_without_contacts(self.world, self.limits)
            if whole is not None:  # no agent-agent contact: every segment at once
                n = len(whole.state)
                fields = [f for f in _Segment.__dataclass_fields__ if f != "k0"]
                for i, k0 in enumerate(range(0, n, SEGMENT)):
                    part = [getattr(whole, f)[k0 : k0 + SEGMENT] for f in fields]
                    self._segments[i] = _Segment(k0, *part)
                self._next = n
                s = self._segments.get(k // SEGMENT)
        if s is None:
            s = self._record(k // SEGMENT)
        return s

    def _record(self, n_seg: int) -> _Segment:
        k0 = n_seg * SEGMENT
        if self._live is None or self._next != k0:
            if k0 != 0:
                raise RuntimeError("agent timeline asked out of order")
            self._live, self._next = AgentSet(self.world, self.limits), 0
            self._contacts = []
        ag, dt, M = self._live, self.world.dt, self._live.M
        n = min(SEGMENT, len(self.world.times) - 1 - k0)
        seg = _Segment(
            k0,
            np.empty((n, M, 4)),
            np.empty((n, M), bool),
            np.empty((n, M, 2)),
            np.empty((n, M, 4)),
            np.empty((n, M), bool),
            np.empty((n, M, 2)),
            np.empty((n, M)),
            np.empty((n, M, 2)),
        )
        for r in range(n):
            k = k0 + r
            seg.state[r] = ag.state
            seg.pres[r] = ag.presence(k)
            vel, omega = ag.velocity()
            seg.vel[r] = vel
            if M == 0:
                continue
            new, steer_new, pres = ag.predict(k, dt)
            found = ag.join_contacts(k, new, pres)
            if found:  # new Box2D bodies: their velocities from now on
                vel, omega = ag.velocity()
                self._contacts.extend(found)
            seg.hit_vel[r], seg.hit_omega[r] = vel, omega
            seg.new_vel[r] = ag.new_velocity(new, steer_new)
            seg.new[r], seg.pres_next[r] = new, pres
            ag.pres_prev = pres
            if ag.phys is not None:
                ag.phys.step(dt)
                ag.from_physics(new, steer_new)
            ag.commit(new, steer_new)
        self._next = k0 + n
        if not self.keep_all:
            self._segments.clear()
        self._segments[n_seg] = seg
        return seg


def agent_timeline(world: World, limits: VehicleLimits) -> AgentTimeline:
    """The agents' run (shared by every ego variant of a batch), recorded once per ``limits`` and cached
    on the world."""
    timeline = world.timelines.get(limits)
    if timeline is None:
        timeline = world.timelines[limits] = AgentTimeline(world, limits)
    return timeline


def record_without_contacts(world: World, limits: VehicleLimits) -> _Segment | None:
    """The agents' whole run as :meth:`AgentTimeline._record` records it, when no two agents ever touch
    (else None): the same values, computed without stepping every agent through Python per step.

    Only for agents that replay their references exactly (a processed scenario; otherwise None).
    Rows are independent until a contact: an agent that replays its reference exactly (``walk``) takes its
    reference pose at every step it moves (steering 0), so its states come from one
    :meth:`~deepcrashtest.sim.reference.PathSet.poses` call; the other agents (static, or driven by the
    vehicle model) step through the same follower and bicycle functions as :meth:`AgentSet.predict`, on their
    rows only. The agent-agent contact rule of :meth:`AgentSet.join_contacts` then runs on the gaps of all
    steps; a contact (Box2D from then on) returns None.
    """
    M, T = world.n_agents, len(world.times)
    if M == 0 or world.agent_paths is None or not world.holonomic[1:].all():
        return None  # agents driven by the vehicle model (raw tracks) gain little: they step as before
    ag = AgentSet(world, limits)
    states = np.empty((T, M, 4))
    steers = np.zeros((T, M))
    states[0] = ag.state
    ks = np.arange(T - 1)
    moving = (ag.start[None, :] <= ks[:, None]) & (ks[:, None] < ag.end[None, :])  # (T-1, M) at step k
    walk = np.flatnonzero(ag.walk)
    if len(walk):
        poses = world.agent_paths.poses(np.minimum(ks + 1, T - 1))[:, walk]  # pose at k + 1
        held = ag.state[walk].copy()
        for k in range(T - 1):  # hold the last pose where the agent does not move
            mv = moving[k, walk]
            held = np.where(mv[:, None], poses[k], held)
            states[k + 1, walk] = held
    rest = np.flatnonzero(~ag.walk)  # static agents (all agents replay exactly): they keep their pose
    states[1:, rest] = ag.state[rest]
    pres = (ag.start[None, :] <= np.arange(T)[:, None]) & (np.arange(T)[:, None] <= ag.end[None, :])
    if M > 1 and _agents_touch(ag, states, pres):
        return None
    if len(rest):  # their steering still follows the reference (it signs their zero velocities)
        _step_rows(world, limits, ag, rest, moving, states, steers)
    wb = world.wheelbase[1:]
    vel = velocity_xy(states[:-1, :, 2], states[:-1, :, 3], steers[:-1])
    omega = yaw_rate(states[:-1, :, 3], steers[:-1], wb)
    new_vel = velocity_xy(states[1:, :, 2], states[1:, :, 3], steers[1:])
    return _Segment(0, states[:-1], pres[:-1], vel, states[1:], pres[1:], vel, omega, new_vel)


def _step_rows(
    world: World,
    limits: VehicleLimits,
    ag: AgentSet,
    rows: np.ndarray,
    moving: np.ndarray,
    states: np.ndarray,
    steers: np.ndarray,
) -> None:
    """:meth:`AgentSet.predict` + commit for the agents ``rows`` (none of them replays its pose), every step."""
    assert world.agent_paths is not None
    lim, dt = limits, world.dt
    wb = world.wheelbase[1:][rows]
    static = ag.static[rows]
    follow = Follower(world.agent_paths, rows, np.zeros((len(rows), 2)), wb)
    state, steer = ag.state[rows].copy(), np.zeros(len(rows))
    for k in range(len(moving)):
        idx = follow.idx
        a_acc, a_str = follow.command(state, k, dt)
        a_acc = np.where(static, -lim.max_brake, a_acc)
        mv = moving[k, rows]
        a_acc_l, steer_new = limit_commands(a_acc, a_str, steer, dt, lim)
        stepped = bicycle_step(state, a_acc_l, steer_new, wb, dt)
        settled = static.all() and _same_bits(stepped, state) and _same_bits(steer_new, steer)
        state = np.where(mv[:, None], stepped, state)
        steer = np.where(mv, steer_new, steer)
        states[k + 1, rows], steers[k + 1, rows] = state, steer
        if settled and np.array_equal(follow.idx, idx):
            # a fixed point: every later step has the same inputs (the step number and the follower's integral
            # only change the acceleration command, which a static agent replaces by full braking), so the
            # same outputs, moving or not: the rest of the run is this state and steering, bit for bit
            states[k + 2 :, rows], steers[k + 2 :, rows] = state, steer
            return


def _same_bits(a: np.ndarray, b: np.ndarray) -> bool:
    """Whether two float arrays hold the same bits (``-0.0`` differs from ``0.0``, NaN equals itself)."""
    return bool(np.array_equal(np.ascontiguousarray(a).view(np.int64), np.ascontiguousarray(b).view(np.int64)))


def _agents_touch(ag: AgentSet, states: np.ndarray, pres: np.ndarray) -> bool:
    """Whether :meth:`AgentSet.join_contacts` would find a contact at any step (its ignore rule, in order).

    The rule per pair and step ``k``: a pair newly present together and touching (gap <= 0) is ignored (it
    started overlapping), until its gap is > 0 again; a touching pair not ignored is a contact. So a pair is
    ignored at ``k`` exactly when its last such start is later than its last step apart (the first start: the
    ignore mask at t = 0). Computed for blocks of steps at once (the last indices by a running maximum) instead
    of step by step: the same answer.
    """
    M = ag.M
    block = max(1, 65536 // (M * M))  # steps whose (M, M) gaps are computed together
    upper = np.triu(np.ones((M, M), bool), 1) & ~ag.brush
    prev_pres = np.concatenate([ag.pres_prev[None], pres[1:-1]])  # presence before step k's: (T - 1, M)
    ignored = ag.ignore.copy()  # the ignore mask before the block
    for k0 in range(0, len(states) - 1, block):
        gaps = agent_gaps_all(states[k0 + 1 : k0 + 1 + block], ag.half)  # (K, M, M) at steps k0 .. k0 + K - 1
        p, q = pres[k0 + 1 : k0 + 1 + len(gaps)], prev_pres[k0 : k0 + len(gaps)]
        both = p[:, :, None] & p[:, None, :]
        close = gaps <= 0
        start = both & ~(q[:, :, None] & q[:, None, :]) & close  # newly together and touching: ignore from here
        steps = np.arange(len(gaps))[:, None, None]
        last_start = np.maximum.accumulate(np.where(start, steps, np.where(ignored, -1, -2)[None]), axis=0)
        last_apart = np.maximum.accumulate(np.where(gaps > 0, steps, -2), axis=0)
        ignore = last_start > last_apart
        if (both & close & ~ignore & upper).any():
            return True
        ignored = ignore[-1]
    return False


def _brushing_pairs(world: World) -> np.ndarray:
    """(M, M) agent pairs that brush past each other (:func:`~deepcrashtest.scenario.brush_past`), but for the
    scenario's collision: two pedestrians a user says collided (``extract --crash FRAME:ID,ID``) do."""
    agents = world.scenario.vehicles()[1:]
    kinds, of = np.unique(np.array([v.category for v in agents], dtype=str), return_inverse=True)
    table = np.array([[brush_past(a, b) for b in kinds] for a in kinds], dtype=bool).reshape(len(kinds), len(kinds))
    brush = table[of[:, None], of[None, :]]  # the rule once per pair of categories, not per pair of agents
    crash = world.scenario.collision
    if crash is not None:
        idx = [k for k, v in enumerate(agents) if v.id in crash.participants]
        if len(idx) == 2:
            brush[idx[0], idx[1]] = brush[idx[1], idx[0]] = False
    return brush


def agent_gaps_all(ag: np.ndarray, ah: np.ndarray) -> np.ndarray:
    """(K, M, M) :func:`agent_gaps` of K sets of agent boxes ``ag`` (K, M, >=3)."""
    return sat_gap(
        ag[:, :, None, 0], ag[:, :, None, 1], ag[:, :, None, 2], ah[None, :, None, 0], ah[None, :, None, 1],
        ag[:, None, :, 0], ag[:, None, :, 1], ag[:, None, :, 2], ah[None, None, :, 0], ah[None, None, :, 1],
    )  # fmt: skip
