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
    lim = limits or VehicleLimits()
    cfg = sensors or SensorConfig()
    dt, times = world.dt, world.times
    T, B, M = len(times), len(ego_init), world.n_agents
    half = world.half
    eh, ah = half[0], half[1:]
    ego_size = (float(world.length[0]), float(world.width[0]))
    wb_e = np.full(B, world.wheelbase[0])
    ego = np.array(ego_init, float)
    e_steer, e_accel = np.zeros(B), np.zeros(B)
    ego_follow = Follower(ego_paths, ego_q, ego_offset, wb_e)
    active = np.ones(B, dtype=bool)
    orig = np.arange(B)  # variant index of each row (rows of finished variants are dropped)

    live = AgentSet(world, lim) if physics_mode else None
    timeline = None if physics_mode else agent_timeline(world, lim)
    if timeline is not None:
        timeline.rewind()
    ego_in_phys = False
    ids = world.ids

    needs_sensors = bool(getattr(controller, "needs_sensors", True))
    if hasattr(controller, "reset"):
        controller.reset(B, dt, seed)
    is_replay = type(controller).__name__ == "ReplayController"
    compactable = not physics_mode and (is_replay or hasattr(controller, "select"))
    period = max(1, int(round(CONTROL_PERIOD_S / dt)))
    held: tuple[np.ndarray, np.ndarray] | None = None

    out = LoopOutput(
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
    if physics_mode:
        out.states = np.full((T, M + 1, 4), np.nan)
        out.present = np.zeros((T, M + 1), dtype=bool)
    pre_contact: dict[int, tuple[np.ndarray, np.ndarray, float, int, np.ndarray, np.ndarray, float]] = {}

    def at_start(k: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Agents' states, presence and velocities at the start of step ``k``."""
        if live is not None:
            return live.state, live.presence(k), live.velocity()[0]
        assert timeline is not None
        seg = timeline.segment(k)
        r = k - seg.k0
        return seg.state[r], seg.pres[r], seg.vel[r]

    def gaps(e: np.ndarray, ag: np.ndarray, pres: np.ndarray) -> np.ndarray:
        """(B, M) separating-axis gaps ego-agent; +inf for absent agents."""
        out_g = np.full((len(e), M), np.inf)
        cols = np.nonzero(pres)[0]
        if len(cols):
            a, h = ag[cols], ah[cols]
            out_g[:, cols] = sat_gap(
                e[:, None, 0], e[:, None, 1], e[:, None, 2], eh[0], eh[1],
                a[None, :, 0], a[None, :, 1], a[None, :, 2], h[None, :, 0], h[None, :, 1],
            )  # fmt: skip
        return out_g

    def update_metrics(
        gap: np.ndarray,
        pres: np.ndarray,
        rows: np.ndarray,
        e_all: np.ndarray,
        es_all: np.ndarray,
        ag: np.ndarray,
        av: np.ndarray,
        with_ttc: bool,
    ) -> None:
        """Distance (every step) and TTC (when ``with_ttc``) of ego rows ``rows`` against present agents."""
        cols = np.nonzero(pres)[0]
        if len(cols) == 0 or not rows.any():
            return
        ridx = np.nonzero(rows)[0]
        g = gap[np.ix_(ridx, cols)]
        e = e_all[ridx]
        ag, av, ahc = ag[cols], av[cols], ah[cols]
        o = orig[ridx]
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

    def record(k: int) -> None:
        if out.states is None or out.present is None or live is None:
            return
        out.states[k, 0] = ego[0]
        out.present[k, 0] = True
        pres = live.presence(k)
        out.states[k, 1:][pres] = live.state[pres]
        out.present[k, 1:] = pres

    # ---- step 0: initial overlaps are ignored; metrics of the initial state
    agents, pres_prev, av0 = at_start(0)
    gap0 = gaps(ego, agents, pres_prev)
    ignore_e = (gap0 <= 0) & pres_prev[None, :]
    update_metrics(gap0, pres_prev, active, ego, e_steer, agents, av0, True)
    record(0)

    for k in range(T - 1):
        agents, pres_k, av_k = at_start(k)
        # ---- 1. commands
        e_acc_r, e_str_r = ego_follow.command(ego, k, dt)
        if active.any() and not is_replay and (k % period == 0 or held is None):
            if needs_sensors:
                obs = sense(
                    cfg, rng, float(times[k]), dt, ego,
                    velocity_xy(ego[:, 2], ego[:, 3], e_steer), yaw_rate(ego[:, 3], e_steer, wb_e), e_accel,
                    ego_size, agents, av_k, ah, pres_k, (e_acc_r, e_str_r), ids[1:],
                )  # fmt: skip
            else:
                obs = sense(
                    cfg, rng, float(times[k]), dt, ego, np.zeros((len(ego), 2)), np.zeros(len(ego)), e_accel, ego_size,
                    agents[:0], np.zeros((0, 2)), ah[:0], np.zeros(0, bool), (e_acc_r, e_str_r), [],
                )  # fmt: skip
            res = controller(obs)
            e_acc_c, e_str_c = (np.broadcast_to(np.asarray(r, float), (len(ego),)) for r in res)
            level = getattr(controller, "brake_level", None)
            if level is not None and len(level) == len(ego):
                lv = np.asarray(level)
                warn, brake = lv >= 1, lv >= 2
            else:
                brake = (e_acc_c < e_acc_r - INTERVENTION_MPS2) & (e_acc_c < -INTERVENTION_MPS2)
                warn = brake
            wt, at = out.warning_time[orig], out.aeb_time[orig]
            out.warning_time[orig] = np.where(np.isnan(wt) & warn & active, times[k], wt)
            out.aeb_time[orig] = np.where(np.isnan(at) & brake & active, times[k], at)
            held = (e_acc_c, e_str_c)
        elif held is not None and not is_replay:
            e_acc_c, e_str_c = held
        else:
            e_acc_c, e_str_c = e_acc_r, e_str_r
        # ---- 2. kinematics -> candidate states at k+1
        acc, e_steer_new = limit_commands(e_acc_c, e_str_c, e_steer, dt, lim)
        ego_new = bicycle_step(ego, acc, e_steer_new, wb_e, dt)
        ego_new = np.where(active[:, None], ego_new, ego)
        if M:
            # ---- 3. agents: candidate states and contacts between agents (shared by all variants)
            if live is not None:
                agents_new, a_steer_new, pres = live.predict(k, dt)
                for va, vb, t_c, rel in live.join_contacts(k, agents_new, pres):
                    out.contacts.append(Contact(t_c, va, vb, rel))
            else:
                assert timeline is not None
                seg = timeline.segment(k)
                r = k - seg.k0
                agents_new, pres = seg.new[r], seg.pres_next[r]
            # ---- ego contacts
            g_e = gaps(ego_new, agents_new, pres)
            newly_e = pres[None, :] & ~pres_prev[None, :]
            ignore_e |= newly_e & (g_e <= 0)
            ignore_e &= ~(g_e > 0)
            hit_e = active[:, None] & pres[None, :] & (g_e <= 0) & ~ignore_e
            rows_hit = np.nonzero(hit_e.any(axis=1))[0]
            if len(rows_hit):
                j = np.argmin(np.where(hit_e[rows_hit], g_e[rows_hit], np.inf), axis=1)
                e0, e1 = ego[rows_hit, :3], ego_new[rows_hit, :3]
                frac = contact_fraction(e0, e1, agents[j, :3], agents_new[j, :3], np.tile(eh, (len(j), 1)), ah[j])
                ev = velocity_xy(ego[rows_hit, 2], ego[rows_hit, 3], e_steer[rows_hit])
                av, aw = live.velocity() if live is not None else (seg.hit_vel[r], seg.hit_omega[r])
                o_hit = orig[rows_hit]
                out.collided[o_hit] = True
                out.collision_time[o_hit] = times[k] + frac * dt
                out.collision_agent[o_hit] = j + 1
                out.relative_speed[o_hit] = np.hypot(*(ev - av[j]).T)
                for n, (b, jj) in enumerate(zip(rows_hit, j, strict=True)):
                    ew = float(yaw_rate(ego[b : b + 1, 3], e_steer[b : b + 1], wb_e[b : b + 1])[0])
                    pre_contact[int(orig[b])] = (
                        ego[b].copy(),
                        ev[n],
                        ew,
                        int(jj),
                        agents[jj].copy(),
                        av[jj].copy(),
                        float(aw[jj]),
                    )
                if live is not None:
                    b0, j0 = int(rows_hit[0]), int(j[0])
                    _, ev0, ew0, _, ap, av0, aw0 = pre_contact[b0]
                    live.to_physics(0, ego[0], ev0, ew0, float(times[k]))
                    live.to_physics(j0 + 1, ap, av0, aw0, float(times[k]))
                    live.in_phys[j0] = True
                    ego_in_phys = True
                    out.contacts.append(
                        Contact(float(out.collision_time[b0]), 0, j0 + 1, float(out.relative_speed[b0]))
                    )
            av_new = live.new_velocity(agents_new, a_steer_new) if live is not None else seg.new_vel[r]
            update_metrics(g_e, pres, active, ego_new, e_steer_new, agents_new, av_new, (k + 1) % TTC_EVERY == 0)
            if live is not None and ego_in_phys:
                # the sliding ego pushes kinematic agents it touches into the physics world
                touch = pres & ~live.in_phys & (g_e[0] <= 0) & ~ignore_e[0]
                for jj in np.nonzero(touch)[0]:
                    s_jj, st_jj = live.state[jj : jj + 1], live.steer[jj : jj + 1]
                    vel = velocity_xy(s_jj[:, 2], s_jj[:, 3], st_jj)[0]
                    om = float(yaw_rate(s_jj[:, 3], st_jj, world.wheelbase[jj + 1 : jj + 2])[0])
                    live.to_physics(int(jj) + 1, live.state[jj], vel, om, float(times[k]))
                    live.in_phys[jj] = True
            if not physics_mode:
                active[rows_hit] = False
            elif ego_in_phys:
                active[:] = False
            pres_prev = pres
            if live is not None:
                live.pres_prev = pres
        # ---- 4. physics step and commit (batch mode: the agents' physics is in the timeline)
        if live is not None and live.phys is not None:
            live.phys.step(dt)
            if 0 in live.phys.bodies:
                ego_new[0] = live.phys.state(0)[0]
                e_steer_new[0] = 0.0
            if M:
                live.from_physics(agents_new, a_steer_new)
        # ego physics contacts with other agents are detected in the next step via predicted states
        ego, e_steer, e_accel = ego_new, e_steer_new, acc
        if M and live is not None:
            live.commit(agents_new, a_steer_new)
        record(k + 1)
        if not physics_mode and not active.any():
            break
        if compactable and active.sum() <= 0.5 * len(active):
            keep = np.nonzero(active)[0]
            ego, e_steer, e_accel, wb_e = ego[keep], e_steer[keep], e_accel[keep], wb_e[keep]
            ego_follow.select(keep)
            ignore_e, orig, active = ignore_e[keep], orig[keep], active[keep]
            if held is not None:
                held = (held[0][keep], held[1][keep])
            if hasattr(controller, "select"):
                controller.select(keep)

    if physics_mode:
        _finish_contacts(out, live.phys if live is not None else None)
        first = next((c for c in out.contacts if 0 in (c.a, c.b)), None)  # the ego's first, after any third-party one
        if first is not None:
            other = first.b if first.a == 0 else first.a
            out.delta_v_ego[0] = first.delta_v.get(0, np.nan)
            out.delta_v_other[0] = first.delta_v.get(other, np.nan)
    else:
        for row, (e_pose, e_vel, e_om, agent, a_pose, a_vel, a_om) in pre_contact.items():
            size_a = (float(world.length[agent + 1]), float(world.width[agent + 1]), float(world.mass[agent + 1]))
            size_e = (ego_size[0], ego_size[1], float(world.mass[0]))
            dv_e, dv_o, _ = impact_delta_v(e_pose[:3], e_vel, e_om, size_e, a_pose[:3], a_vel, a_om, size_a)
            out.delta_v_ego[row], out.delta_v_other[row] = dv_e, dv_o
    return out


def _finish_contacts(out: LoopOutput, phys: PhysicsWorld | None) -> None:
    """Add delta-v and impact points from Box2D; add contacts only Box2D saw (between sliding bodies)."""
    if phys is None:
        return
    seen = {pair_key(c.a, c.b) for c in out.contacts}
    for pair, ep in phys.episodes.items():
        if pair not in seen:
            out.contacts.append(Contact(ep.begin_time, int(pair[0]), int(pair[1]), ep.relative_speed))
    for c in out.contacts:
        found = phys.episodes.get(pair_key(c.a, c.b))
        if found is not None:
            c.point = found.point
            c.delta_v = {int(k): v for k, v in phys.delta_v(c.a, c.b).items()}
    out.contacts.sort(key=lambda c: c.time)
