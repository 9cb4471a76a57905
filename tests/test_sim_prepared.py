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
