"""Prepared worlds (``sim.prepare``) and the agents' recorded run give the same results as before.

The batch loop reads the agents from a timeline recorded once per world; ``simulate`` steps them
live. These tests compare both paths on real KITTI 0008 scenarios, including an agent-agent crash.
"""

from __future__ import annotations

import numpy as np
import pytest

from deepcrashtest.errors import UserError
from deepcrashtest.scenario import Trajectory
from deepcrashtest.sim import agents as agents_mod
from deepcrashtest.sim import prepare, simulate, simulate_batch
from deepcrashtest.sim.testcases import meet_ego
from deepcrashtest.sim.vehicle import VehicleLimits


@pytest.fixture(scope="module")
def head_on(kitti8_raw):
    return meet_ego(kitti8_raw, 11, 10.0)


@pytest.fixture(scope="module")
def agents_crash(head_on):
    """A copy of the ego's real drive becomes agent 99 (hit by oncoming agent 11 at 10 s); the ego moves 40 m left."""
    sc = head_on.model_copy(deep=True)
    sc.agents.append(sc.ego.model_copy(update={"id": 99}, deep=True))
    a = sc.ego.trajectory.arrays()
    sc.ego.trajectory = Trajectory.from_arrays(a["t"], a["x"], a["y"] + 40.0, a["yaw"], a["speed"])
    sc.collision = None
    return sc


def _same(a, b) -> None:
    for name in a.__dataclass_fields__:
        assert np.array_equal(getattr(a, name), getattr(b, name), equal_nan=True), name


def test_prepared_world_gives_identical_batches_and_runs(head_on):
    rng = np.random.default_rng(1)
    off = np.column_stack([rng.uniform(-15, 15, 24), rng.uniform(-2, 2, 24)])
    world = prepare(head_on, duration=12.0)
    for ctrl in ("aeb", "replay", "aeb"):  # the world (and its recorded agents) is reused across calls
        _same(
            simulate_batch(world, off, controller=ctrl, seed=2, chunk_size=8),
            simulate_batch(head_on, off, controller=ctrl, seed=2, duration=12.0, chunk_size=8),
        )
    r1, r2 = simulate(world, controller="aeb"), simulate(head_on, controller="aeb", duration=12.0)
    assert np.array_equal(r1.states, r2.states, equal_nan=True) and r1.collisions == r2.collisions
    assert r1.metrics == r2.metrics and r1.metrics["collided"]
    with pytest.raises(UserError):
        simulate_batch(world, off, duration=5.0)
    with pytest.raises(UserError):
        simulate_batch(world, off, dt=0.01)


def test_streamed_timeline_equals_cached(head_on, monkeypatch):
    rng = np.random.default_rng(2)
    off = np.column_stack([rng.uniform(-15, 15, 12), rng.uniform(-2, 2, 12)])
    ref = simulate_batch(head_on, off, controller="aeb", duration=12.0)
    monkeypatch.setattr(agents_mod, "SEGMENT", 37)
    monkeypatch.setattr(agents_mod, "MAX_CACHED_ENTRIES", 0)  # keep one segment, re-record every run
    world = prepare(head_on, duration=12.0)
    assert not agents_mod.agent_timeline(world, VehicleLimits()).keep_all
    _same(simulate_batch(world, off, controller="aeb"), ref)
    _same(simulate_batch(world, off, controller="aeb"), ref)


def test_recorded_agents_equal_live_agents_through_an_agent_crash(agents_crash):
    """Agents 11 and 99 collide (Box2D from then on): the timeline matches ``simulate``'s live agents."""
    run = simulate(agents_crash, duration=12.0)
    assert any(set(c["vehicles"]) == {11, 99} for c in run.collisions)
    assert not any(0 in c["vehicles"] for c in run.collisions)
    world = prepare(agents_crash, duration=12.0)
    batch = simulate_batch(world, np.zeros((1, 2)))
    assert not batch.collided[0]
    tl = agents_mod.agent_timeline(world, VehicleLimits())
    for k in range(len(world.times) - 1):
        seg = tl.segment(k)
        pres = seg.pres[k - seg.k0]
        assert np.array_equal(pres, run.present[k, 1:])
        assert np.array_equal(seg.state[k - seg.k0][pres], run.states[k, 1:][pres])


def test_references_of_many_paths_equal_one_by_one(head_on):
    """One interpolation for many paths (a cached inverse, matrix products) equals one spline per path to rounding
    (the products' summation order differs); flags and grid spans exactly."""
    from deepcrashtest.sim.reference import build_reference, build_references

    tr = head_on.ego.trajectory
    t = np.linspace(tr.t[0], tr.t[-1], 30)
    xy = np.column_stack([np.interp(t, tr.t, tr.x), np.interp(t, tr.t, tr.y)])
    paths = xy + np.random.default_rng(3).normal(0.0, 0.5, (6, 30, 2))
    times = np.arange(0, 20.0, 0.02)
    yaw = np.interp(t, tr.t, tr.yaw)
    for one, many in zip(
        [build_reference(t, p, yaw, times, 0.02, smooth=False) for p in paths],
        build_references(t, paths, yaw, times, 0.02),
        strict=True,
    ):
        for name in ("path", "s_ref", "v_ref", "init"):
            np.testing.assert_allclose(getattr(many, name), getattr(one, name), rtol=0, atol=1e-9, err_msg=name)
        assert (one.start, one.end, one.static) == (many.start, many.end, many.static)


@pytest.mark.parametrize("name", ["head_on", "agents_crash"])
def test_agents_run_without_contacts_equals_the_step_by_step_recording(name, request, monkeypatch):
    """Agents replaying their references exactly (processed scenario): the whole-run recording gives every
    recorded array bit for bit (zero signs included); with an agent-agent crash it steps aside (None)."""
    # real (raw, noisy) tracks replayed exactly; a processed scenario's validation would refuse their noise
    sc = request.getfixturevalue(name).model_copy(update={"stage": "processed"})
    world = prepare(sc, duration=12.0)
    fast = agents_mod.record_without_contacts(world, VehicleLimits())
    assert (fast is None) == (name == "agents_crash")
    tl = agents_mod.AgentTimeline(world, VehicleLimits())
    monkeypatch.setattr(agents_mod, "record_without_contacts", lambda *a: None)
    slow = tl.whole()
    assert slow is not None
    if fast is not None:
        for f in agents_mod._Segment.__dataclass_fields__:
            assert (
                getattr(fast, f) is getattr(slow, f)
                or np.asarray(getattr(fast, f)).tobytes() == np.asarray(getattr(slow, f)).tobytes()
            ), f


def test_settled_static_agents_are_not_stepped_kitti3(kitti_root, monkeypatch):
    """KITTI 0003 processed (parked cars: static agents whose steering follows the reference): the whole-run
    recording stops stepping them at their fixed point and still gives every array bit for bit."""
    from deepcrashtest.pipeline.kitti import kitti_scenarios

    world = prepare(kitti_scenarios(kitti_root, 3)[1], duration=6.0)
    settled = []
    same_bits = agents_mod._same_bits
    monkeypatch.setattr(agents_mod, "_same_bits", lambda a, b: settled.append(same_bits(a, b)) or settled[-1])
    fast = agents_mod.record_without_contacts(world, VehicleLimits())
    assert fast is not None and any(settled)  # the shortcut was taken
    monkeypatch.setattr(agents_mod, "record_without_contacts", lambda *a: None)
    slow = agents_mod.AgentTimeline(world, VehicleLimits()).whole()
    assert slow is not None
    for f in agents_mod._Segment.__dataclass_fields__:
        assert np.asarray(getattr(fast, f)).tobytes() == np.asarray(getattr(slow, f)).tobytes(), f


def _agents_touch_loop(ag, states, pres) -> bool:
    """:meth:`AgentSet.join_contacts`' ignore rule step by step (the reference ``agents._agents_touch`` replaced)."""
    ignore, prev = ag.ignore.copy(), ag.pres_prev
    for k in range(len(states) - 1):
        g = agents_mod.agent_gaps_all(states[k + 1 : k + 2], ag.half)[0]
        p = pres[k + 1]
        both = p[:, None] & p[None, :]
        newly = both & ~(prev[:, None] & prev[None, :])
        ignore |= newly & (g <= 0)
        ignore &= ~(g > 0)
        if np.triu(both & (g <= 0) & ~ignore, 1).any():
            return True
        prev = p
    return False


def test_agents_touch_blocks_equal_the_step_loop(head_on):
    """The blockwise contact test gives the step loop's answer on KITTI 0008's agents moved at random: starts
    already overlapping (ignored), agents entering and leaving, unknown (NaN) gaps; with and without contacts."""
    world = prepare(head_on.model_copy(update={"stage": "processed"}), duration=8.0)
    M, T = world.n_agents, len(world.times)
    base = agents_mod.AgentSet(world, VehicleLimits())
    states = np.repeat(base.state[None], T, axis=0)
    walk = np.flatnonzero(base.walk)
    states[1:, walk] = world.agent_paths.poses(np.arange(1, T))[:, walk]
    pres0 = (base.start[None, :] <= np.arange(T)[:, None]) & (np.arange(T)[:, None] <= base.end[None, :])
    rng = np.random.default_rng(5)
    answers = []
    for trial in range(16):
        st, pres = states.copy(), pres0.copy()
        if trial:
            st[..., :2] += rng.normal(0.0, 0.6 * trial, (1, M, 2)) + rng.normal(0.0, 0.3, (T, M, 2))
        if trial % 3 == 2:
            pres &= rng.random((T, M)) > 0.05
        if trial % 4 == 3:
            st[rng.integers(0, T, 20), rng.integers(0, M, 20), 0] = np.nan
        a, b = agents_mod.AgentSet(world, VehicleLimits()), agents_mod.AgentSet(world, VehicleLimits())
        if trial % 2:
            a.ignore[:] = b.ignore[:] = rng.random((M, M)) > 0.6
        answers.append(agents_mod._agents_touch(a, st, pres))
        assert answers[-1] == _agents_touch_loop(b, st, pres), trial
    assert not answers[0] and any(answers)  # the real run has no contact; moved agents do
    # agent 1 on agent 0 (0.5 m aside) from the start, only the two present. (apart in the middle third, agent 1
    # present only from the middle, ignored at t = 0, agent 1 present before the first step) -> a contact:
    # overlapping from the start: ignored if so at t = 0 or newly together, else a contact; apart, then
    # overlapping again: a contact; entering overlapping in the middle: newly together, ignored
    pres = np.zeros((T, M), bool)
    pres[:, :2] = True
    cases = [
        ((False, False, True, True), False),
        ((False, False, False, True), True),
        ((False, False, False, False), False),
        ((True, False, True, True), True),
        ((False, True, False, True), False),
    ]
    for (apart, enter, ignored, before), touch in cases:
        st = states.copy()
        st[:, 1] = st[:, 0] + [0.5, 0.0, 0.0, 0.0]
        if apart:
            st[T // 3 : 2 * T // 3, 1, 1] += 20.0
        p = pres.copy()
        if enter:
            p[: T // 2, 1] = False
        a, b = agents_mod.AgentSet(world, VehicleLimits()), agents_mod.AgentSet(world, VehicleLimits())
        for ag in (a, b):
            ag.pres_prev = p[0].copy()
            ag.pres_prev[1] = before and not enter
            ag.ignore[:] = False
            ag.ignore[0, 1] = ag.ignore[1, 0] = ignored
        assert agents_mod._agents_touch(a, st, p) == _agents_touch_loop(b, st, p) == touch, (apart, enter, ignored)
