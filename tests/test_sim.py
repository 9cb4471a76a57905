"""The built-in simulator: physics known answers, geometry against shapely, replay on real KITTI
trajectories, crashes made from real trajectories, AEB, plug-in controllers, determinism, CLI."""

from __future__ import annotations

import json
import subprocess
import sys
import textwrap

import numpy as np
import pytest
import shapely
from shapely.geometry import Polygon

from deepcrashtest.errors import UserError
from deepcrashtest.sim import replay_error, simulate, simulate_batch
from deepcrashtest.sim.boxes import (
    axis_gaps,
    contact_fraction,
    corners,
    distance_lower_bound,
    sat_gap,
    signed_distance,
    time_to_collision,
)
from deepcrashtest.sim.controllers import resolve_controller
from deepcrashtest.sim.physics import PhysicsWorld, impact_delta_v
from deepcrashtest.sim.testcases import meet_ego
from deepcrashtest.sim.vehicle import VehicleLimits, bicycle_step, limit_commands


# --------------------------------------------------------------------------- fixtures (real data)
@pytest.fixture(scope="module")
def kitti3(kitti_root):
    from deepcrashtest.datasets.kitti.scenario import scenario_from_kitti

    return scenario_from_kitti(kitti_root, 3)


@pytest.fixture(scope="module")
def head_on(kitti8_raw):
    """KITTI 0008 with real oncoming agent 11 moved to meet the ego at t = 10 s."""
    return meet_ego(kitti8_raw, 11, 10.0)


@pytest.fixture(scope="module")
def parked(kitti8_raw):
    """KITTI 0008 with the real parked van 8 moved onto the ego's path at t = 5 s."""
    return meet_ego(kitti8_raw, 8, 5.0)


# --------------------------------------------------------------------------- vehicle model
def test_braking_distance_matches_v2_over_2a_and_no_reverse_roll():
    lim = VehicleLimits()
    for v0 in (5.0, 13.9, 27.8):
        state = np.array([[0.0, 0.0, 0.3, v0]])
        steer = np.zeros(1)
        xs, vs = [], []
        for _ in range(int(2 * v0 / lim.max_brake / 0.02) + 50):  # well past the stop
            acc, steer = limit_commands(np.array([-50.0]), np.zeros(1), steer, 0.02, lim)
            state = bicycle_step(state, acc, steer, np.array([2.7]), 0.02)
            xs.append(np.hypot(state[0, 0], state[0, 1]))
            vs.append(state[0, 3])
        expected = v0**2 / (2 * lim.max_brake)
        assert abs(xs[-1] - expected) / expected < 0.02
        assert min(vs) == 0.0 and all(v >= 0 for v in vs)
        assert np.all(np.diff(xs) >= -1e-12)  # never rolls backwards
        assert xs[-1] == xs[-40]  # stays put once stopped


def test_actuator_limits_are_enforced():
    lim = VehicleLimits()
    acc, steer = limit_commands(np.array([99.0, -99.0, np.nan]), np.array([2.0, -2.0, 0.0]), np.zeros(3), 0.02, lim)
    assert list(acc) == [lim.max_accel, -lim.max_brake, 0.0]
    assert np.allclose(np.abs(steer[:2]), lim.max_steer_rate * 0.02)  # rate limit first


# --------------------------------------------------------------------------- geometry vs shapely
def _poly(x, y, yaw, hl, hw):
    return Polygon(corners(np.array(x), np.array(y), np.array(yaw), np.array(hl), np.array(hw)))


def test_collision_detection_and_distance_agree_with_shapely():
    rng = np.random.default_rng(7)
    n = 600
    a = np.column_stack([rng.uniform(-3, 3, n), rng.uniform(-3, 3, n), rng.uniform(-np.pi, np.pi, n)])
    b = np.column_stack([rng.uniform(-3, 3, n), rng.uniform(-3, 3, n), rng.uniform(-np.pi, np.pi, n)])
    ha = np.column_stack([rng.uniform(0.5, 3, n), rng.uniform(0.3, 1.2, n)])
    hb = np.column_stack([rng.uniform(0.5, 3, n), rng.uniform(0.3, 1.2, n)])
    gap = sat_gap(a[:, 0], a[:, 1], a[:, 2], ha[:, 0], ha[:, 1], b[:, 0], b[:, 1], b[:, 2], hb[:, 0], hb[:, 1])
    dist = signed_distance(a, b, ha, hb)
    hits = 0
    for i in range(n):
        pa, pb = _poly(*a[i], *ha[i]), _poly(*b[i], *hb[i])
        ref = pa.intersects(pb)
        hits += ref
        assert (gap[i] <= 0) == ref, i
        if not ref:
            assert dist[i] == pytest.approx(pa.distance(pb), abs=1e-9)
            assert gap[i] <= dist[i] + 1e-12  # the separating-axis gap is a lower bound
    assert 100 < hits < n - 100  # both outcomes well represented


def test_corner_distance_bound_is_a_tight_lower_bound_of_shapely_distance():
    """The bound the batch mode prunes exact distances with: never above the true distance (shapely), never below the
    separating-axis gap, and exact where the boxes face each other corner to corner along both axes."""
    rng = np.random.default_rng(11)
    n = 2000
    a = np.column_stack([np.zeros(n), np.zeros(n), rng.uniform(-np.pi, np.pi, n)])
    b = np.column_stack([rng.uniform(-12, 12, n), rng.uniform(-12, 12, n), rng.uniform(-np.pi, np.pi, n)])
    ha = np.column_stack([rng.uniform(0.5, 3, n), rng.uniform(0.3, 1.2, n)])
    hb = np.column_stack([rng.uniform(0.2, 3, n), rng.uniform(0.2, 1.2, n)])
    args = (a[:, 0], a[:, 1], a[:, 2], ha[:, 0], ha[:, 1], b[:, 0], b[:, 1], b[:, 2], hb[:, 0], hb[:, 1])
    gaps = axis_gaps(*args)
    gap = sat_gap(*args)
    np.testing.assert_array_equal(gap, np.maximum(np.maximum(gaps[0], gaps[1]), np.maximum(gaps[2], gaps[3])))
    bound = distance_lower_bound(*gaps)
    ref = np.array([_poly(*a[i], *ha[i]).distance(_poly(*b[i], *hb[i])) for i in range(n)])
    apart = ref > 0
    assert 1500 < apart.sum() < n
    assert (bound[apart] <= ref[apart] + 1e-9).all()
    assert (bound[apart] >= gap[apart]).all()
    assert (bound[apart] > gap[apart] + 0.1).sum() > 300  # tighter than the gap for many pairs
    # axis-aligned boxes offset diagonally: the closest points are two corners, the bound is the distance
    aligned = distance_lower_bound(*axis_gaps(0.0, 0.0, 0.0, 2.0, 1.0, 7.0, 5.0, 0.0, 2.0, 1.0))
    assert aligned == pytest.approx(np.hypot(3.0, 3.0), abs=1e-12)


def _polys(xy, yaw, hl, hw):
    """Vectorised shapely boxes for centres ``xy`` (n, 2)."""
    c = corners(xy[:, 0], xy[:, 1], np.full(len(xy), yaw), np.full(len(xy), hl), np.full(len(xy), hw))
    return shapely.polygons(c)


def test_time_to_collision_and_contact_fraction_against_shapely_sweep():
    rng = np.random.default_rng(3)
    ts = np.arange(0, 6, 0.001)
    checked = finite = 0
    for _ in range(40):
        a = np.array([0.0, 0.0, rng.uniform(-0.5, 0.5)])
        b = np.array([rng.uniform(8, 20), rng.uniform(-3, 3), rng.uniform(-np.pi, np.pi)])
        wa = np.array([rng.uniform(5, 15), rng.uniform(-1, 1)])
        wb = np.array([rng.uniform(-10, 5), rng.uniform(-2, 2)])
        ttc = time_to_collision(b[0] - a[0], b[1] - a[1], *(wb - wa), a[2], 2.25, 0.9, b[2], 2.25, 0.9)
        pa = _polys(a[:2] + wa * ts[:, None], a[2], 2.25, 0.9)
        pb = _polys(b[:2] + wb * ts[:, None], b[2], 2.25, 0.9)
        hit = np.nonzero(shapely.intersects(pa, pb))[0]
        first = ts[hit[0]] if len(hit) else np.inf
        assert (np.isinf(ttc) and np.isinf(first)) or abs(float(ttc) - first) < 0.002
        finite += np.isfinite(first)
        if np.isfinite(first) and first > 0.1:
            t0, t1 = first - 0.05, first + 0.01  # one "step" containing the first contact
            f = contact_fraction(
                np.array([[*(a[:2] + wa * t0), a[2]]]), np.array([[*(a[:2] + wa * t1), a[2]]]),
                np.array([[*(b[:2] + wb * t0), b[2]]]), np.array([[*(b[:2] + wb * t1), b[2]]]),
                np.array([[2.25, 0.9]]), np.array([[2.25, 0.9]]),
            )  # fmt: skip
            assert abs(t0 + f[0] * (t1 - t0) - first) < 0.002
            checked += 1
    assert checked >= 5 and finite < 40


# --------------------------------------------------------------------------- Box2D impacts
def test_head_on_equal_masses_equal_and_opposite_delta_v():
    dv_a, dv_b, point = impact_delta_v(
        np.array([0.0, 0.0, 0.0]), np.array([15.0, 0.0]), 0.0, (4.5, 1.8, 1500.0),
        np.array([4.55, 0.0, np.pi]), np.array([-15.0, 0.0]), 0.0, (4.5, 1.8, 1500.0),
    )  # fmt: skip
    assert dv_a == pytest.approx(dv_b, rel=1e-6)
    # central plastic-ish impact: each car's delta-v is (1 + e) * 15 m/s with restitution e ~ 0.15
    assert 15.0 < dv_a < 15.0 * 1.2
    assert point[0] == pytest.approx(2.275, abs=0.1)


def test_box2d_conserves_momentum_and_impulse_delta_v_matches_velocity_change():
    w = PhysicsWorld(mu=0.0)  # no tyre friction: only the impact acts
    w.add(0, np.array([0.0, 0.0, 0.0]), np.array([16.0, 0.0]), 0.0, 4.5, 1.8, 1500.0)
    w.add(1, np.array([3.6, 2.2, np.pi / 2]), np.array([0.0, -9.0]), 0.3, 4.9, 1.9, 2200.0)  # side impact
    v0 = {k: w.state(k)[1] for k in (0, 1)}
    p0 = sum(w.mass[k] * v0[k] for k in (0, 1))
    while w.episode_open(0, 1) and w.time < 2.0:  # until the first contact episode ends
        w.step(0.005)
    v1 = {k: w.state(k)[1] for k in (0, 1)}
    p1 = sum(w.mass[k] * v1[k] for k in (0, 1))
    assert w.time < 1.0
    assert np.linalg.norm(p1 - p0) / np.linalg.norm(p0) < 0.01
    dv = w.delta_v(0, 1)
    for k in (0, 1):
        assert dv[k] > 1.0
        assert dv[k] == pytest.approx(np.linalg.norm(v1[k] - v0[k]), rel=0.01)
    assert dv[0] * w.mass[0] == pytest.approx(dv[1] * w.mass[1], rel=0.01)  # equal and opposite impulses


def test_tyre_friction_brings_vehicles_to_rest():
    w = PhysicsWorld()
    w.add(0, np.array([0.0, 0.0, 0.0]), np.array([10.0, 3.0]), 1.5, 4.5, 1.8, 1500.0)
    for _ in range(200):
        w.step(0.02)
    s, v, om = w.state(0)
    assert np.hypot(*v) < 0.05 and abs(om) < 0.05
    # sliding distance ~ v^2 / (2 mu g)
    assert np.hypot(s[0], s[1]) == pytest.approx(109.0 / (2 * 0.8 * 9.81), rel=0.15)


# --------------------------------------------------------------------------- replay on real data
def test_replay_reproduces_kitti_trajectories(kitti3):
    res = simulate(kitti3)
    err = replay_error(kitti3, res)
    assert err["ego"] < 0.1
    assert err["all"] < 0.3
    assert not res.metrics["collided"]
    assert res.states.shape == (len(res.times), 1 + len(kitti3.agents), 4)
    # existence convention: agents exist exactly from their first to their last sample; the ego always
    for i, v in enumerate(kitti3.vehicles()):
        k = np.nonzero(res.present[:, i])[0]
        if i == 0:
            assert len(k) == len(res.times)
        else:
            assert res.times[k[0]] == pytest.approx(v.trajectory.t[0], abs=0.011)
            assert res.times[k[-1]] == pytest.approx(v.trajectory.t[-1], abs=0.011)
            assert np.isnan(res.states[~res.present[:, i], i]).all()
    assert (res.states[:, :, 3][res.present] >= 0).all()
    m = res.metrics
    assert all(isinstance(v, bool | int | float) or v is None for v in m.values())
    assert m["robustness"] == pytest.approx(m["min_distance"]) and m["min_distance"] > 0


def test_a_replayed_vehicle_is_posed_on_its_path_while_it_exists_and_nowhere_else(kitti3):
    """``SimResult.pose_at``: KITTI 0003's agents at their own sample times sit near their recorded positions (the
    replay's error), and are absent before their first sample, after their last and outside the run."""
    res = simulate(kitti3)
    for i, v in enumerate(kitti3.vehicles()):
        if i == 0:
            continue
        tr = v.trajectory
        poses = [res.pose_at(float(t), i) for t in tr.t]
        assert all(p is not None for p in poses)
        err = np.hypot(
            [p[0] - x for p, x in zip(poses, tr.x, strict=True)], [p[1] - y for p, y in zip(poses, tr.y, strict=True)]
        )  # type: ignore[index]
        assert float(np.median(err)) < 0.3
        assert res.pose_at(float(tr.t[0]) - 0.5, i) is None
        assert res.pose_at(float(tr.t[-1]) + 0.5, i) is None
    assert res.pose_at(-1.0, 0) is None and res.pose_at(float(res.times[-1]) + 1.0, 0) is None
    assert res.pose_at(0.0, 0) is not None


def test_replayed_ego_drives_its_path_through_bends(kitti_root):
    """KITTI training sequences 0004, 0006 and 0014 (the ego takes bends): the replayed ego stays near its path.
    The follower once asked for a curvature feed-forward on top of Stanley's heading error (which holds a
    bend's road-wheel angle already): twice the angle, RMS 0.180 / 0.167 / 0.381 m."""
    from deepcrashtest.datasets.kitti.scenario import scenario_from_kitti

    for seq, most in ((4, 0.1), (6, 0.1), (14, 0.2)):  # now 0.070 / 0.061 / 0.180
        sc = scenario_from_kitti(kitti_root, seq)
        assert replay_error(sc, simulate(sc))["ego"] < most


def test_replay_holds_a_steady_bend():
    """A 2.7 m-wheelbase vehicle replaying a 12 m-radius circle at 8 m/s: the follower holds its front axle on
    the circle, so its centre runs on the radius that puts it there, ``sqrt(R^2 - 3 L^2 / 4)`` (kinematic
    bicycle, centre mid-wheelbase), 0.23 m inside; with the doubled steering of a curvature feed-forward
    on top of the heading error it ran 0.72 m inside."""
    from deepcrashtest.sim.follow import Follower
    from deepcrashtest.sim.reference import PathSet, build_references

    radius, speed, dt, wheelbase = 12.0, 8.0, 0.05, 2.7
    t = np.arange(0.0, 8.01, 0.1)
    ang = speed * t / radius
    xy = np.column_stack([radius * np.sin(ang), radius * (1 - np.cos(ang))])
    times = np.arange(0.0, 8.0 + 1e-9, dt)
    refs = build_references(t, xy[None], np.zeros_like(t), times, dt)
    wb = np.array([wheelbase])
    follow = Follower(PathSet.stack(refs, dt), np.array([0]), np.zeros((1, 2)), wb)
    state, steer, lim = refs[0].init[None].copy(), np.zeros(1), VehicleLimits()
    dist = []
    for k in range(len(times) - 1):
        accel, cmd = follow.command(state, k, dt)
        accel, steer = limit_commands(accel, cmd, steer, dt, lim)
        state = bicycle_step(state, accel, steer, wb, dt)
        dist.append(np.hypot(state[0, 0], state[0, 1] - radius))
    steady = np.array(dist[len(dist) // 4 : -len(dist) // 4])  # away from the start and the path's straight end
    assert np.abs(steady - np.sqrt(radius**2 - 0.75 * wheelbase**2)).max() < 0.02


def _shapely_first_contact(sc, agent_id, t_lo, t_hi):
    """Reference contact time from the scenario's raw trajectories (linear interpolation, shapely)."""
    ego, ag = sc.ego, sc.vehicle(agent_id)
    for t in np.arange(t_lo, t_hi, 0.001):
        e, a = ego.trajectory.state_at(t), ag.trajectory.state_at(t)
        pe = _poly(e["x"], e["y"], e["yaw"], ego.length / 2, ego.width / 2)
        pa = _poly(a["x"], a["y"], a["yaw"], ag.length / 2, ag.width / 2)
        if pe.intersects(pa):
            return t
    return None


def test_crash_built_from_real_trajectories_happens_in_the_simulation(head_on):
    ref = _shapely_first_contact(head_on, 11, 9.0, 10.5)
    assert ref is not None and abs(ref - 10.0) < 0.05
    res = simulate(head_on, duration=12.0)
    m = res.metrics
    assert m["collided"] and m["collision_vehicle"] == 11
    assert abs(m["collision_time"] - ref) < 0.05
    assert m["relative_speed"] > 25.0
    assert m["delta_v_ego"] == pytest.approx(m["delta_v_other"], rel=0.01)  # same masses (two cars)
    assert m["robustness"] < 0 and m["min_distance"] == 0.0
    c = res.collision
    assert c is not None and c["vehicles"] == [0, 11] and c["point"] is not None
    # after the impact both slide to rest under Box2D and stay in the world past agent 11's last sample
    k_end = len(res.times) - 1
    assert res.present[k_end, res.vehicle_ids.index(11)]
    assert res.states[k_end, 0, 3] < 0.1 and res.states[k_end, res.vehicle_ids.index(11), 3] < 0.1


def test_aeb_avoids_parked_van_and_mitigates_head_on(parked, head_on):
    rep = simulate(parked, duration=8.0)
    assert rep.metrics["collided"] and rep.metrics["collision_vehicle"] == 8
    aeb = simulate(parked, controller="aeb", duration=8.0)
    assert not aeb.metrics["collided"]
    assert aeb.metrics["warning_time"] <= aeb.metrics["aeb_time"] < rep.metrics["collision_time"]
    assert aeb.metrics["min_distance"] > 0.5
    rep2 = simulate(head_on, duration=11.0)
    aeb2 = simulate(head_on, controller="aeb", duration=11.0)
    assert aeb2.metrics["collided"]  # an oncoming car cannot be avoided by braking alone
    assert aeb2.metrics["relative_speed"] < rep2.metrics["relative_speed"] - 3.0
    assert aeb2.metrics["delta_v_ego"] < rep2.metrics["delta_v_ego"]


# --------------------------------------------------------------------------- plug-ins and determinism
class _Recorder:
    """A user controller: full braking from t = 1 s, records what it saw."""

    def __init__(self):
        self.ranges = []

    def reset(self, n, dt, seed):
        self.n = n

    def __call__(self, obs):
        self.ranges.append(np.nan_to_num(obs.radar_range).copy())
        accel = np.where(obs.t >= 1.0, -20.0, obs.replay_accel)
        return accel, obs.replay_steer


def test_user_controller_plugin_brakes_to_a_stop(kitti3):
    ctrl = _Recorder()
    res = simulate(kitti3, controller=ctrl, duration=6.0)
    assert ctrl.n == 1 and len(ctrl.ranges) > 10
    v = res.states[:, 0, 3]
    k1 = int(round(1.0 / res.dt))
    assert v[-1] == 0.0 and np.all(v >= 0)
    path = np.hypot(*np.diff(res.states[k1:, 0, :2], axis=0).T).sum()
    assert path == pytest.approx(v[k1] ** 2 / (2 * 9.0), rel=0.03)
    assert res.metrics["aeb_time"] == pytest.approx(1.0, abs=0.05)  # a harder-than-driver brake counts


def test_module_and_file_specs(tmp_path):
    f = tmp_path / "myctrl.py"
    f.write_text(
        textwrap.dedent(
            """
            import numpy as np
            class Coast:
                needs_sensors = False
                def __call__(self, obs):
                    return np.zeros(obs.n), obs.replay_steer
            def brake(obs):
                return np.full(obs.n, -9.0), obs.replay_steer
            """
        )
    )
    assert callable(resolve_controller(f"{f}:brake"))
    assert type(resolve_controller(f"{f}:Coast")).__name__ == "Coast"
    assert type(resolve_controller("deepcrashtest.sim.controllers:AebController")).__name__ == "AebController"
    for bad in ("nope", "no.such.module:f", f"{f}:missing", f"{tmp_path}/absent.py:f"):
        with pytest.raises(UserError):
            resolve_controller(bad)


def test_determinism_with_a_seed(parked):
    a = _Recorder()
    b = _Recorder()
    c = _Recorder()
    simulate(parked, controller=a, seed=5, duration=3.0)
    simulate(parked, controller=b, seed=5, duration=3.0)
    simulate(parked, controller=c, seed=6, duration=3.0)
    assert all(np.array_equal(x, y) for x, y in zip(a.ranges, b.ranges, strict=True))
    assert any(not np.array_equal(x, y) for x, y in zip(a.ranges, c.ranges, strict=True))
    r1 = simulate(parked, controller="aeb", seed=1, duration=6.0)
    r2 = simulate(parked, controller="aeb", seed=1, duration=6.0)
    assert np.array_equal(r1.states, r2.states, equal_nan=True) and r1.metrics == r2.metrics


# --------------------------------------------------------------------------- batch
def test_batch_matches_single_run_and_offsets_change_outcome(head_on):
    off = np.array([[0.0, 0.0], [0.0, 4.0], [20.0, 0.0], [-30.0, 0.0]])
    br = simulate_batch(head_on, off, duration=12.0)
    single = simulate(head_on, duration=12.0).metrics
    v0 = br.variant(0)
    assert v0["collided"] and v0["collision_agent"] == 11
    assert v0["collision_time"] == pytest.approx(single["collision_time"], abs=1e-9)
    assert v0["delta_v_ego"] == pytest.approx(single["delta_v_ego"], rel=0.02)
    assert v0["robustness"] == pytest.approx(single["robustness"], abs=1e-9)
    assert not br.collided[1] and br.robustness[1] > 0  # one lane to the left: passes the oncoming car
    # starting 20 m further ahead, the ego meets the oncoming car 20 / ~35 m/s = ~0.57 s earlier
    assert br.collided[2] and br.collision_time[2] == pytest.approx(br.collision_time[0] - 0.57, abs=0.1)
    # starting 30 m back it would meet it ~0.86 s later, but agent 11's last sample is at 10.3 s: it has left
    assert not br.collided[3] and head_on.vehicle(11).trajectory.t[-1] < br.collision_time[0] + 0.86
    for name in ("collided", "collision_time", "min_distance", "min_ttc", "robustness", "aeb_time", "delta_v_ego"):
        assert getattr(br, name).shape == (4,)


def test_batch_is_deterministic_and_independent_of_workers(parked):
    rng = np.random.default_rng(0)
    off = np.column_stack([rng.uniform(-20, 20, 10), rng.uniform(-2, 2, 10)])
    kw = dict(controller="aeb", seed=3, duration=7.0, chunk_size=4)
    a = simulate_batch(parked, off, **kw, workers=1)
    b = simulate_batch(parked, off, **kw, workers=2)
    for name in a.__dataclass_fields__:
        assert np.array_equal(getattr(a, name), getattr(b, name), equal_nan=True), name
    assert np.isfinite(a.aeb_time).any()


def test_batch_with_perturbed_paths(head_on):
    t = np.linspace(head_on.ego.trajectory.t[0], head_on.ego.trajectory.t[-1], 40)
    xy = np.column_stack([np.interp(t, head_on.ego.trajectory.t, head_on.ego.trajectory.x),
                          np.interp(t, head_on.ego.trajectory.t, head_on.ego.trajectory.y)])  # fmt: skip
    paths = np.stack([xy, xy + [0.0, 4.0]])
    br = simulate_batch(head_on, np.zeros((2, 2)), ego_paths=paths, duration=12.0)
    assert br.collided[0] and not br.collided[1]
    with pytest.raises(UserError):
        simulate_batch(head_on, np.zeros((2, 2)), ego_paths=paths[:, :, :1])
    with pytest.raises(UserError):
        simulate_batch(head_on, np.zeros((3,)))


# --------------------------------------------------------------------------- CLI and video
def test_cli_simulate_json_and_video(tmp_path, parked):
    import av

    path = parked.save(tmp_path / "scenario.json")
    video = tmp_path / "bev.mp4"
    cmd = [sys.executable, "-m", "deepcrashtest.cli", "simulate", str(path), "--controller", "aeb",
           "--duration", "6", "--video", str(video), "--json"]  # fmt: skip
    proc = subprocess.run(cmd, capture_output=True, text=True, timeout=300)
    assert proc.returncode == 0, proc.stderr
    out = json.loads(proc.stdout)
    assert out["metrics"]["collided"] is False and out["metrics"]["aeb_time"] is not None
    with av.open(str(video)) as c:
        s = c.streams.video[0]
        assert s.codec_context.name == "h264"
        frames = sum(1 for _ in c.decode(s))
    assert frames == pytest.approx(6.0 * 25, abs=2)
    again = subprocess.run(cmd, capture_output=True, text=True, timeout=300)
    assert again.returncode == 2 and "already exists" in again.stderr and len(again.stderr.strip().splitlines()) == 1
    bad = subprocess.run(cmd[:5] + ["--controller", "nosuch:thing"], capture_output=True, text=True, timeout=300)
    assert bad.returncode == 2 and "nosuch" in bad.stderr
