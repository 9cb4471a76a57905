"""The time-stepping loop, vectorised over ego variants, shared by ``simulate`` and ``simulate_batch``.

Rows: ``B`` ego variants and the ``M`` agents. Agents do not depend on the ego (they replay), so
they are stepped once and shared by all variants. Each step (k -> k+1):

1. replay commands (Stanley + PID) for ego variants and agents; the ego controller (with sensor
   observations when it needs them) may override the ego's;
2. actuator limits and the kinematic bicycle step give candidate states at k+1;
3. collision test (vectorised separating axes) of every ego variant against every present agent,
   and between agents; the first contact time inside the step is found by bisection;
4. vehicles that touch leave the kinematic model for Box2D, starting from their pre-contact state
   (``physics`` mode, one variant) - or, in ``batch`` mode, the variant ends at its first collision
   and a two-body Box2D impact gives its delta-v;
5. metrics (distance, time to collision) for the variants still driving.

Contacts between boxes that already overlap when the pair first co-exists (label noise of parked
cars, a vehicle appearing in another) are ignored until the pair has separated once.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import numpy as np

from deepcrashtest.sim.agents import AgentSet, agent_timeline
from deepcrashtest.sim.boxes import contact_fraction, sat_gap, signed_distance, time_to_collision
from deepcrashtest.sim.controllers import call_controller
from deepcrashtest.sim.follow import Follower
from deepcrashtest.sim.physics import PhysicsWorld, impact_delta_v, pair_key
from deepcrashtest.sim.reference import PathSet
from deepcrashtest.sim.sensors import SensorConfig, sense
from deepcrashtest.sim.vehicle import VehicleLimits, bicycle_step, limit_commands, velocity_xy, yaw_rate
from deepcrashtest.sim.world import World

NEAR_M = 10.0  # exact box distances are computed below this separating-axis gap
CONTROL_PERIOD_S = 0.04  # the ego controller (and its sensors) run at 25 Hz; commands are held between
TTC_EVERY = 5  # steps between time-to-collision evaluations (0.1 s at dt = 0.02 s)
INTERVENTION_MPS2 = 1.0  # a user controller "brakes" when it asks 1 m/s^2 more than the driver


@dataclass
class Contact:
    """A collision found by the loop."""

    time: float
    a: int  # vehicle index (0 = ego)
    b: int
    relative_speed: float
    point: tuple[float, float] | None = None
    delta_v: dict[int, float] = field(default_factory=dict)


@dataclass
class LoopOutput:
    collided: np.ndarray
    collision_time: np.ndarray
    collision_agent: np.ndarray  # vehicle index, -1 none
    relative_speed: np.ndarray
    delta_v_ego: np.ndarray
    delta_v_other: np.ndarray
    min_distance: np.ndarray
    min_ttc: np.ndarray
    aeb_time: np.ndarray
    warning_time: np.ndarray
    states: np.ndarray | None = None  # (T, N, 4) in physics mode
    present: np.ndarray | None = None  # (T, N)
    contacts: list[Contact] = field(default_factory=list)

    @classmethod
    def empty(cls, batch: int) -> LoopOutput:
        """Outcomes of ``batch`` variants before any step: no collision, no AEB, infinite distance and TTC."""
        B = batch
        return cls(
            collided=np.zeros(B, bool),
            collision_time=np.full(B, np.nan),
            collision_agent=np.full(B, -1),
            relative_speed=np.full(B, np.nan),
            delta_v_ego=np.full(B, np.nan),
            delta_v_other=np.full(B, np.nan),
            min_distance=np.full(B, np.inf),
            min_ttc=np.full(B, np.inf),
            aeb_time=np.full(B, np.nan),
            warning_time=np.full(B, np.nan),
        )


def run_loop(
    world: World,
    ego_paths: PathSet,
    ego_q: np.ndarray,
    ego_offset: np.ndarray,
    ego_init: np.ndarray,
    controller: Any,
    rng: np.random.Generator,
    physics_mode: bool,
    seed: int = 0,
    limits: VehicleLimits | None = None,
    sensors: SensorConfig | None = None,
) -> LoopOutput:
    """Run one batch of ``B = len(ego_init)`` ego variants through the whole time grid.

    In batch mode (``physics_mode=False``) the agents come from the world's recorded
    :class:`~deepcrashtest.sim.agents.AgentTimeline`; in physics mode they are stepped live.
    """
    loop = _Loop(world, ego_paths, ego_q, ego_offset, ego_init, controller, rng, physics_mode, seed, limits, sensors)
    loop.start()
    for k in range(len(world.times) - 1):
        if not loop.step(k):
            break
    return loop.finish()


class _Loop:
    """The state of one run of :func:`run_loop` and its phases (one method each)."""

    def __init__(
        self,
        world: World,
        ego_paths: PathSet,
        ego_q: np.ndarray,
        ego_offset: np.ndarray,
        ego_init: np.ndarray,
        controller: Any,
        rng: np.random.Generator,
        physics_mode: bool,
        seed: int,
        limits: VehicleLimits | None,
        sensors: SensorConfig | None,
    ) -> None:
        self.world, self.rng, self.physics_mode, self.controller = world, rng, physics_mode, controller
        self.lim = limits or VehicleLimits()
        self.cfg = sensors or SensorConfig()
        self.dt, self.times = world.dt, world.times
        T, B, M = len(self.times), len(ego_init), world.n_agents
        self.M = M
        self.eh, self.ah = world.half[0], world.half[1:]
        self.ego_size = (float(world.length[0]), float(world.width[0]))
        self.wb_e = np.full(B, world.wheelbase[0])
        self.ego = np.array(ego_init, float)
        self.e_steer, self.e_accel = np.zeros(B), np.zeros(B)
        self.ego_follow = Follower(ego_paths, ego_q, ego_offset, self.wb_e)
        self.active = np.ones(B, dtype=bool)
        self.orig = np.arange(B)  # variant index of each row (rows of finished variants are dropped)
        self.live = AgentSet(world, self.lim) if physics_mode else None
        self.timeline = None if physics_mode else agent_timeline(world, self.lim)
        if self.timeline is not None:
            self.timeline.rewind()
        self.ego_in_phys = False
        self.needs_sensors = bool(getattr(controller, "needs_sensors", True))
        if hasattr(controller, "reset"):
            controller.reset(B, self.dt, seed)
        self.is_replay = is_replay_controller(controller)
        self.compactable = not physics_mode and (self.is_replay or hasattr(controller, "select"))
        self.period = max(1, int(round(CONTROL_PERIOD_S / self.dt)))
        self.held: tuple[np.ndarray, np.ndarray] | None = None
        self.out = LoopOutput.empty(B)
        if physics_mode:
            self.out.states = np.full((T, M + 1, 4), np.nan)
            self.out.present = np.zeros((T, M + 1), dtype=bool)
        self.pre_contact: dict[int, PreContact] = {}
        self.pres_prev = np.zeros(M, dtype=bool)
        self.ignore_e = np.zeros((B, M), dtype=bool)

    # ------------------------------------------------------------------ helpers
    def at_start(self, k: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Agents' states, presence and velocities at the start of step ``k``."""
        if self.live is not None:
            return self.live.state, self.live.presence(k), self.live.velocity()[0]
        assert self.timeline is not None
        seg = self.timeline.segment(k)
        r = k - seg.k0
        return seg.state[r], seg.pres[r], seg.vel[r]

    def gaps(self, e: np.ndarray, ag: np.ndarray, pres: np.ndarray) -> np.ndarray:
        """(B, M) separating-axis gaps ego-agent; +inf for absent agents."""
        out_g = np.full((len(e), self.M), np.inf)
        cols = np.nonzero(pres)[0]
        if len(cols):
            eh, a, h = self.eh, ag[cols], self.ah[cols]
            out_g[:, cols] = sat_gap(
                e[:, None, 0], e[:, None, 1], e[:, None, 2], eh[0], eh[1],
                a[None, :, 0], a[None, :, 1], a[None, :, 2], h[None, :, 0], h[None, :, 1],
            )  # fmt: skip
        return out_g

    def update_metrics(
        self,
        gap: np.ndarray,
        pres: np.ndarray,
        e_all: np.ndarray,
        es_all: np.ndarray,
        ag: np.ndarray,
        av: np.ndarray,
        with_ttc: bool,
    ) -> None:
        """Distance (every step) and TTC (when ``with_ttc``) of the active ego rows against present agents."""
        out, rows, eh = self.out, self.active, self.eh
        cols = np.nonzero(pres)[0]
        if len(cols) == 0 or not rows.any():
            return
        ridx = np.nonzero(rows)[0]
        g = gap[np.ix_(ridx, cols)]
        e = e_all[ridx]
        ag, av, ahc = ag[cols], av[cols], self.ah[cols]
        o = self.orig[ridx]
        # the separating-axis gap is a lower bound of the distance: refine only where it may lower the minimum
        near = (g > 0) & (g < NEAR_M) & (g < out.min_distance[o][:, None])
        if near.any():
            bi, mi = np.nonzero(near)
            g[bi, mi] = signed_distance(e[bi, :3], ag[mi, :3], eh[None, :], ahc[mi])
        out.min_distance[o] = np.minimum(out.min_distance[o], g.min(axis=1))
        if not with_ttc:
            return
        ev = velocity_xy(e[:, 2], e[:, 3], es_all[ridx])
        ttc = time_to_collision(
            ag[None, :, 0] - e[:, None, 0], ag[None, :, 1] - e[:, None, 1],
            av[None, :, 0] - ev[:, None, 0], av[None, :, 1] - ev[:, None, 1],
            e[:, None, 2], eh[0], eh[1], ag[None, :, 2], ahc[None, :, 0], ahc[None, :, 1],
        )  # fmt: skip
        ttc = np.where(g > 0, ttc, np.inf)
        out.min_ttc[o] = np.minimum(out.min_ttc[o], ttc.min(axis=1))

    def record(self, k: int) -> None:
        """Physics mode: store the states and presence at step ``k``."""
        out, live = self.out, self.live
        if out.states is None or out.present is None or live is None:
            return
        out.states[k, 0] = self.ego[0]
        out.present[k, 0] = True
        pres = live.presence(k)
        out.states[k, 1:][pres] = live.state[pres]
        out.present[k, 1:] = pres

    # ------------------------------------------------------------------ phases
    def start(self) -> None:
        """Step 0: initial overlaps are ignored; metrics of the initial state."""
        agents, self.pres_prev, av0 = self.at_start(0)
        gap0 = self.gaps(self.ego, agents, self.pres_prev)
        self.ignore_e = (gap0 <= 0) & self.pres_prev[None, :]
        self.update_metrics(gap0, self.pres_prev, self.ego, self.e_steer, agents, av0, True)
        self.record(0)

    def step(self, k: int) -> bool:
        """Advance every variant from step ``k`` to ``k + 1``; False when no variant is left to drive."""
        agents, pres_k, av_k = self.at_start(k)
        e_acc_c, e_str_c = self.commands(k, agents, pres_k, av_k)
        # ---- 2. kinematics -> candidate states at k+1
        acc, e_steer_new = limit_commands(e_acc_c, e_str_c, self.e_steer, self.dt, self.lim)
        ego_new = bicycle_step(self.ego, acc, e_steer_new, self.wb_e, self.dt)
        ego_new = np.where(self.active[:, None], ego_new, self.ego)
        agents_new: Any = None
        a_steer_new: Any = None
        if self.M:
            agents_new, a_steer_new = self.interact(k, agents, ego_new, e_steer_new)
        self.physics_step(agents_new, a_steer_new, ego_new, e_steer_new)
        # ego physics contacts with other agents are detected in the next step via predicted states
        self.ego, self.e_steer, self.e_accel = ego_new, e_steer_new, acc
        if self.M and self.live is not None:
            self.live.commit(agents_new, a_steer_new)
        self.record(k + 1)
        if not self.physics_mode and not self.active.any():
            return False
        if self.compactable and self.active.sum() <= 0.5 * len(self.active):
            self.compact()
        return True

    def commands(
        self, k: int, agents: np.ndarray, pres_k: np.ndarray, av_k: np.ndarray
    ) -> tuple[np.ndarray, np.ndarray]:
        """Phase 1: replay commands (Stanley + PID); the ego controller (at its period) may override them."""
        ego, out = self.ego, self.out
        e_acc_r, e_str_r = self.ego_follow.command(ego, k, self.dt)
        if self.is_replay:
            return e_acc_r, e_str_r
        if not (self.active.any() and (k % self.period == 0 or self.held is None)):
            return self.held if self.held is not None else (e_acc_r, e_str_r)
        obs = self.observe(k, agents, pres_k, av_k, (e_acc_r, e_str_r))
        e_acc_c, e_str_c = call_controller(self.controller, obs, len(ego))
        level = getattr(self.controller, "brake_level", None)
        if level is not None and len(level) == len(ego):
            lv = np.asarray(level)
            warn, brake = lv >= 1, lv >= 2
        else:
            brake = (e_acc_c < e_acc_r - INTERVENTION_MPS2) & (e_acc_c < -INTERVENTION_MPS2)
            warn = brake
        orig, t = self.orig, self.times[k]
        wt, at = out.warning_time[orig], out.aeb_time[orig]
        out.warning_time[orig] = np.where(np.isnan(wt) & warn & self.active, t, wt)
        out.aeb_time[orig] = np.where(np.isnan(at) & brake & self.active, t, at)
        self.held = (e_acc_c, e_str_c)
        return self.held

    def observe(
        self,
        k: int,
        agents: np.ndarray,
        pres_k: np.ndarray,
        av_k: np.ndarray,
        replay: tuple[np.ndarray, np.ndarray],
    ) -> Any:
        """The ego controller's sensor observation at step ``k`` (no agents when it needs no sensors)."""
        ego, e_steer, ah, wb_e = self.ego, self.e_steer, self.ah, self.wb_e
        t = float(self.times[k])
        if self.needs_sensors:
            return sense(
                self.cfg, self.rng, t, self.dt, ego,
                velocity_xy(ego[:, 2], ego[:, 3], e_steer), yaw_rate(ego[:, 3], e_steer, wb_e), self.e_accel,
                self.ego_size, agents, av_k, ah, pres_k, replay, self.world.ids[1:],
            )  # fmt: skip
        return sense(
            self.cfg, self.rng, t, self.dt, ego, np.zeros((len(ego), 2)), np.zeros(len(ego)), self.e_accel,
            self.ego_size, agents[:0], np.zeros((0, 2)), ah[:0], np.zeros(0, bool), replay, [],
        )  # fmt: skip

    def interact(
        self, k: int, agents: np.ndarray, ego_new: np.ndarray, e_steer_new: np.ndarray
    ) -> tuple[np.ndarray, Any]:
        """Phase 3: agents' candidate states, contacts (agent-agent, ego-agent), metrics; physics hand-over."""
        live, out = self.live, self.out
        a_steer_new: Any = None
        if live is not None:
            agents_new, a_steer_new, pres = live.predict(k, self.dt)
            for va, vb, t_c, rel in live.join_contacts(k, agents_new, pres):
                out.contacts.append(Contact(t_c, va, vb, rel))
            hit_vel = None
        else:
            assert self.timeline is not None
            seg = self.timeline.segment(k)
            r = k - seg.k0
            agents_new, pres = seg.new[r], seg.pres_next[r]
            hit_vel = (seg.hit_vel[r], seg.hit_omega[r])
        g_e = self.gaps(ego_new, agents_new, pres)
        newly_e = pres[None, :] & ~self.pres_prev[None, :]
        self.ignore_e |= newly_e & (g_e <= 0)
        self.ignore_e &= ~(g_e > 0)
        rows_hit = self.ego_contacts(k, agents, agents_new, ego_new, g_e, pres, hit_vel)
        av_new = live.new_velocity(agents_new, a_steer_new) if live is not None else seg.new_vel[r]
        ttc_now = (k + 1) % TTC_EVERY == 0
        self.update_metrics(g_e, pres, ego_new, e_steer_new, agents_new, av_new, ttc_now)
        if live is not None and self.ego_in_phys:
            self.push_touched(k, g_e, pres)
        if not self.physics_mode:
            self.active[rows_hit] = False
        elif self.ego_in_phys:
            self.active[:] = False
        self.pres_prev = pres
        if live is not None:
            live.pres_prev = pres
        return agents_new, a_steer_new

    def ego_contacts(
        self,
        k: int,
        agents: np.ndarray,
        agents_new: np.ndarray,
        ego_new: np.ndarray,
        g_e: np.ndarray,
        pres: np.ndarray,
        hit_vel: tuple[np.ndarray, np.ndarray] | None,
    ) -> np.ndarray:
        """Ego-agent contacts inside step ``k``: record them (first contact time by bisection); returns the rows."""
        ego, out, eh, ah = self.ego, self.out, self.eh, self.ah
        hit_e = self.active[:, None] & pres[None, :] & (g_e <= 0) & ~self.ignore_e
        rows_hit = np.nonzero(hit_e.any(axis=1))[0]
        if not len(rows_hit):
            return rows_hit
        j = np.argmin(np.where(hit_e[rows_hit], g_e[rows_hit], np.inf), axis=1)
        e0, e1 = ego[rows_hit, :3], ego_new[rows_hit, :3]
        frac = contact_fraction(e0, e1, agents[j, :3], agents_new[j, :3], np.tile(eh, (len(j), 1)), ah[j])
        ev = velocity_xy(ego[rows_hit, 2], ego[rows_hit, 3], self.e_steer[rows_hit])
        av, aw = self.live.velocity() if self.live is not None else hit_vel  # type: ignore[misc]
        o_hit = self.orig[rows_hit]
        out.collided[o_hit] = True
        out.collision_time[o_hit] = self.times[k] + frac * self.dt
        out.collision_agent[o_hit] = j + 1
        out.relative_speed[o_hit] = np.hypot(*(ev - av[j]).T)
        for n, (b, jj) in enumerate(zip(rows_hit, j, strict=True)):
            ew = float(yaw_rate(ego[b : b + 1, 3], self.e_steer[b : b + 1], self.wb_e[b : b + 1])[0])
            self.pre_contact[int(self.orig[b])] = (
                ego[b].copy(), ev[n], ew, int(jj), agents[jj].copy(), av[jj].copy(), float(aw[jj]),
            )  # fmt: skip
        if self.live is not None:
            self.ego_to_physics(k, int(rows_hit[0]), int(j[0]))
        return rows_hit

    def ego_to_physics(self, k: int, b0: int, j0: int) -> None:
        """Physics mode: the ego and the agent it hit leave the kinematic model for Box2D."""
        live, out = self.live, self.out
        assert live is not None
        _, ev0, ew0, _, ap, av0, aw0 = self.pre_contact[b0]
        live.to_physics(0, self.ego[0], ev0, ew0, float(self.times[k]))
        live.to_physics(j0 + 1, ap, av0, aw0, float(self.times[k]))
        live.in_phys[j0] = True
        self.ego_in_phys = True
        out.contacts.append(Contact(float(out.collision_time[b0]), 0, j0 + 1, float(out.relative_speed[b0])))

    def push_touched(self, k: int, g_e: np.ndarray, pres: np.ndarray) -> None:
        """The sliding ego pushes kinematic agents it touches into the physics world."""
        live = self.live
        assert live is not None
        touch = pres & ~live.in_phys & (g_e[0] <= 0) & ~self.ignore_e[0]
        for jj in np.nonzero(touch)[0]:
            s_jj, st_jj = live.state[jj : jj + 1], live.steer[jj : jj + 1]
            vel = velocity_xy(s_jj[:, 2], s_jj[:, 3], st_jj)[0]
            om = float(yaw_rate(s_jj[:, 3], st_jj, self.world.wheelbase[jj + 1 : jj + 2])[0])
            live.to_physics(int(jj) + 1, live.state[jj], vel, om, float(self.times[k]))
            live.in_phys[jj] = True

    def physics_step(self, agents_new: Any, a_steer_new: Any, ego_new: np.ndarray, e_steer_new: np.ndarray) -> None:
        """Phase 4 (physics mode): one Box2D step; bodies in it overwrite the candidate states."""
        live = self.live
        if live is None or live.phys is None:
            return
        live.phys.step(self.dt)
        if 0 in live.phys.bodies:
            ego_new[0] = live.phys.state(0)[0]
            e_steer_new[0] = 0.0
        if self.M:
            live.from_physics(agents_new, a_steer_new)

    def compact(self) -> None:
        """Drop the rows of finished variants (batch mode) so later steps cost less."""
        keep = np.nonzero(self.active)[0]
        self.ego, self.e_steer, self.e_accel, self.wb_e = (
            self.ego[keep], self.e_steer[keep], self.e_accel[keep], self.wb_e[keep],
        )  # fmt: skip
        self.ego_follow.select(keep)
        self.ignore_e, self.orig, self.active = self.ignore_e[keep], self.orig[keep], self.active[keep]
        if self.held is not None:
            self.held = (self.held[0][keep], self.held[1][keep])
        if hasattr(self.controller, "select"):
            self.controller.select(keep)

    def finish(self) -> LoopOutput:
        """Delta-v: from Box2D (physics mode) or a two-body impact per colliding variant (batch mode)."""
        out, world = self.out, self.world
        if self.physics_mode:
            finish_contacts(out.contacts, self.live.phys if self.live is not None else None)
            first = next((c for c in out.contacts if 0 in (c.a, c.b)), None)  # the ego's first, after any third-party
            if first is not None:
                other = first.b if first.a == 0 else first.a
                out.delta_v_ego[0] = first.delta_v.get(0, np.nan)
                out.delta_v_other[0] = first.delta_v.get(other, np.nan)
            return out
        batch_delta_v(world, self.pre_contact, out)
        return out


PreContact = tuple[np.ndarray, np.ndarray, float, int, np.ndarray, np.ndarray, float]


def is_replay_controller(controller: Any) -> bool:
    """True for the built-in replay controller (the ego follows its reference, blind to the agents)."""
    return type(controller).__name__ == "ReplayController"


def batch_delta_v(world: World, pre_contact: dict[int, PreContact], out: LoopOutput) -> None:
    """Batch mode: delta-v (m/s) of the ego and the agent it hit, from a two-body Box2D impact per variant.

    ``pre_contact[row]`` = ego state, velocity, yaw rate; agent index; agent state, velocity, yaw rate,
    all at the start of the step of the first contact.
    """
    size_e = (float(world.length[0]), float(world.width[0]), float(world.mass[0]))
    for row, (e_pose, e_vel, e_om, agent, a_pose, a_vel, a_om) in pre_contact.items():
        size_a = (float(world.length[agent + 1]), float(world.width[agent + 1]), float(world.mass[agent + 1]))
        dv_e, dv_o, _ = impact_delta_v(e_pose[:3], e_vel, e_om, size_e, a_pose[:3], a_vel, a_om, size_a)
        out.delta_v_ego[row], out.delta_v_other[row] = dv_e, dv_o


def finish_contacts(contacts: list[Contact], phys: PhysicsWorld | None) -> None:
    """Add delta-v and impact points from Box2D; add contacts only Box2D saw (between sliding bodies); in place."""
    if phys is None:
        return
    seen = {pair_key(c.a, c.b) for c in contacts}
    for pair, ep in phys.episodes.items():
        if pair not in seen:
            contacts.append(Contact(ep.begin_time, int(pair[0]), int(pair[1]), ep.relative_speed))
    for c in contacts:
        found = phys.episodes.get(pair_key(c.a, c.b))
        if found is not None:
            c.point = found.point
            c.delta_v = {int(k): v for k, v in phys.delta_v(c.a, c.b).items()}
    contacts.sort(key=lambda c: c.time)
