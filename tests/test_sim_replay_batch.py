"""The replay controller's batch mode (``sim.replay_batch``) gives the per-step loop's outcomes.

``simulate_batch`` runs replay variants through whole-run arrays; ``stepwise=True`` runs the
reference loop (``sim.loop``). Both are compared on real KITTI scenes: search variants of 0003
(the search benchmark's scene, parked cars along the road) and start offsets on 0008 with an
oncoming agent moved to meet the ego (collisions, Box2D delta-v).
"""

from __future__ import annotations

import numpy as np
import pytest

from deepcrashtest.search.space import SearchSpace
from deepcrashtest.sim import prepare, simulate_batch
from deepcrashtest.sim.reference import PathSet, build_pathset, build_references
from deepcrashtest.sim.testcases import meet_ego

EXACT = ("collided", "collision_agent")


@pytest.fixture(scope="module")
def kitti3_raw(kitti_root):
    from deepcrashtest.datasets.kitti.scenario import scenario_from_kitti

    return scenario_from_kitti(kitti_root, 3)


def _equivalent(fast, loop) -> None:
    """Flags and pairs identical; times, distances, TTC, speeds and delta-v equal to rounding."""
    for name in fast.__dataclass_fields__:
        a, b = getattr(fast, name), getattr(loop, name)
        if name in EXACT:
            assert np.array_equal(a, b), name
        else:
            assert np.array_equal(np.isfinite(a), np.isfinite(b)), name
            ok = np.isfinite(a)
            assert np.allclose(a[ok], b[ok], rtol=0.0, atol=1e-9), name


def test_search_variants_of_kitti3(kitti3_raw):
    space = SearchSpace.for_scenario(kitti3_raw)
    theta = space.reference_grid(np.random.default_rng([0, 1]), 24, 4)
    world = prepare(kitti3_raw)
    paths, zero = space.paths(theta), np.zeros((len(theta), 2))
    fast = simulate_batch(world, zero, ego_paths=paths)
    loop = simulate_batch(world, zero, ego_paths=paths, stepwise=True)
    _equivalent(fast, loop)
    assert 0 < fast.collided.sum() < len(theta)  # both kinds of outcome are compared
    assert np.isfinite(fast.min_ttc).any() and np.isfinite(fast.delta_v_ego[fast.collided]).all()


def test_start_offsets_with_a_head_on_agent_kitti8(kitti8_raw):
    sc = meet_ego(kitti8_raw, 11, 10.0)
    off = np.column_stack([np.linspace(-12, 12, 25), np.tile([-1.5, 0.0, 1.5, 0.7, -0.7], 5)])
    world = prepare(sc, duration=14.0)
    fast = simulate_batch(world, off)
    loop = simulate_batch(world, off, stepwise=True)
    _equivalent(fast, loop)
    assert fast.collided.any() and (fast.collision_agent[fast.collided] > 0).all()


def test_pathset_of_many_paths_equals_stacked_references(kitti3_raw):
    space = SearchSpace.for_scenario(kitti3_raw)
    theta = space.reference_grid(np.random.default_rng([0, 2]), 8, 2)
    world = prepare(kitti3_raw)
    tr = kitti3_raw.ego.trajectory
    paths = space.paths(theta)
    t = np.linspace(tr.t[0], tr.t[-1], paths.shape[1])
    yaw = np.interp(t, tr.t, tr.yaw)
    refs = build_references(t, paths, yaw, world.times, world.dt)
    stacked = PathSet.stack(refs, world.dt)
    fast, init = build_pathset(t, paths, yaw, world.times, world.dt)
    for name in stacked.__dataclass_fields__:
        assert np.array_equal(getattr(stacked, name), getattr(fast, name)), name
    assert np.array_equal(init, np.stack([r.init for r in refs]))


def test_packed_paths_serve_every_chunk_and_roll_out_as_the_path_set(kitti3_raw):
    """The batch packs the ego paths once for all its chunks (released after the only one): several chunks give the
    one chunk's outcomes, and a roll-out over packed paths is the path set's, bit for bit."""
    from deepcrashtest.sim.rollout import PackedPaths, rollout
    from deepcrashtest.sim.vehicle import VehicleLimits

    space = SearchSpace.for_scenario(kitti3_raw)
    theta = space.reference_grid(np.random.default_rng([0, 4]), 6, 3)
    world = prepare(kitti3_raw)
    paths, zero = space.paths(theta), np.zeros((len(theta), 2))
    one = simulate_batch(world, zero, ego_paths=paths)
    several = simulate_batch(world, zero, ego_paths=paths, chunk_size=5)  # 4 chunks share the packed paths
    for name in one.__dataclass_fields__:
        a, b = getattr(one, name), getattr(several, name)
        assert np.array_equal(a, b, equal_nan=a.dtype.kind == "f") if isinstance(a, np.ndarray) else a == b, name
    tr = kitti3_raw.ego.trajectory
    t = np.linspace(tr.t[0], tr.t[-1], paths.shape[1])
    pathset, init = build_pathset(t, paths, np.interp(t, tr.t, tr.yaw), world.times, world.dt)
    wb, steps, lim = float(world.wheelbase[0]), len(world.times) - 1, VehicleLimits()
    q, off = np.arange(len(theta)), np.zeros((len(theta), 2))
    packed = PackedPaths.pack(pathset, wb)
    a = rollout(pathset, q, off, init, wb, world.dt, steps, lim)
    b = rollout(packed, q, off, init, wb, world.dt, steps, lim)
    for name in a.__dataclass_fields__:
        assert np.array_equal(getattr(a, name), getattr(b, name)), name
    with pytest.raises(ValueError, match="wheelbase"):
        rollout(packed, q, off, init, wb + 0.1, world.dt, steps, lim)
    packed.release()
    assert packed.table.size == 0 and packed.s_ref.size == 0


def test_search_variants_of_kitti8_with_a_head_on_agent(kitti8_raw):
    """Perturbed ego paths (the search's variants) on the 28-vehicle scene, with collisions."""
    sc = meet_ego(kitti8_raw, 10, 8.8)
    space = SearchSpace.for_scenario(sc)
    theta = space.reference_grid(np.random.default_rng([0, 3]), 8, 2)
    world = prepare(sc, duration=10.0)
    paths, zero = space.paths(theta), np.zeros((len(theta), 2))
    fast = simulate_batch(world, zero, ego_paths=paths)
    loop = simulate_batch(world, zero, ego_paths=paths, stepwise=True)
    _equivalent(fast, loop)
    assert fast.collided.any()


def test_unwrap_shortcut_is_numpy_unwrap():
    from deepcrashtest.sim.reference import _unwrap

    rng = np.random.default_rng(0)
    smooth = np.cumsum(rng.normal(0, 0.1, (3, 50)), axis=1)
    wrapped = np.angle(np.exp(1j * np.cumsum(rng.normal(0, 0.8, (3, 50)), axis=1)))  # steps across +-pi
    for p in (smooth, wrapped, np.array([[-0.0, -0.0, 0.1]]), np.zeros((2, 1))):
        got, want = _unwrap(p), np.unwrap(p, axis=-1)
        assert np.array_equal(got, want) and np.array_equal(np.signbit(got), np.signbit(want))


def test_remainder_shortcut_gives_the_loops_heading_error():
    """The roll-out's heading error (``remainder(e + pi, 2 pi) - pi``, the remainder skipped when every element
    is in range) equals the follower's, bit for bit, in range (with -0.0), across the wrap, and with NaN."""
    from deepcrashtest.sim.rollout import _remainder_two_pi

    two_pi = 2 * np.pi
    rng = np.random.default_rng(1)
    cases = (
        rng.uniform(-1.0, 1.0, 1000) + np.pi,  # the usual case: small errors, the remainder skipped
        np.array([-0.0, 0.0, np.nextafter(two_pi, 0.0), 1e-300]),
        rng.uniform(-20.0, 20.0, 1000),  # out of range: the full remainder
        np.array([np.nan, 1.0, np.inf]),
    )
    for t in cases:
        got = t.copy()
        with np.errstate(invalid="ignore"):  # inf: NaN, as numpy's remainder gives
            _remainder_two_pi(got, two_pi)
            want = np.remainder(t, two_pi) - np.pi
        assert np.array_equal(got - np.pi, want, equal_nan=True)


def test_stopped_ego_beside_parked_cars_kitti3(kitti3_raw):
    """A stopped ego beside parked cars (the same pair of boxes step after step): the loop's outcomes."""
    space = SearchSpace.for_scenario(kitti3_raw)
    theta = space.reference_grid(np.random.default_rng([0, 1]), 6, 2)
    paths = space.paths(theta)
    # every other variant stands for the whole run 4 m beside the car parked at (52, 21) for the first 2.5 s
    park = next(a.trajectory.arrays() for a in kitti3_raw.agents if a.id == 3)
    paths[::2] = [float(np.mean(park["x"])), float(np.mean(park["y"])) - 4.0]
    world = prepare(kitti3_raw)
    zero = np.zeros((len(theta), 2))
    fast = simulate_batch(world, zero, ego_paths=paths)
    _equivalent(fast, simulate_batch(world, zero, ego_paths=paths, stepwise=True))
    assert np.ptp(fast.min_distance[::2]) == 0.0 and 0.0 < fast.min_distance[0] < 4.0


def test_repeated_box_pairs_give_signed_distances(kitti3_raw):
    """Runs of identical box pairs (a stopped ego, a parked car) computed once give signed_distance's bits."""
    from deepcrashtest.sim.boxes import signed_distance
    from deepcrashtest.sim.replay_batch import apart_distances

    world = prepare(kitti3_raw)
    rng = np.random.default_rng(0)
    ag = np.array([[52.8, 21.5, -3.09], [56.7, 21.6, -3.1], [50.0, 27.0, 1.2]])
    ego = np.column_stack([rng.uniform(40, 60, 40), rng.uniform(14, 17, 40), rng.uniform(-3.3, -2.9, 40)])
    pick = np.repeat(rng.integers(0, 40, 60), rng.integers(1, 6, 60))  # runs of repeated pairs
    e, a = ego[pick], ag[pick % 3]
    ah = world.half[1:][pick % 3]
    signed = signed_distance(e, a, world.half[0][None, :], ah)
    apart = signed > 0
    assert apart.sum() > 100
    got = apart_distances(np.column_stack([e, a, ah])[apart], world.half[0])
    assert np.array_equal(got, signed[apart])
    assert len(np.unique(got)) < apart.sum()  # repeats were there


def test_new_boxes_compares_bits():
    from deepcrashtest.sim.replay_batch import _new_boxes

    boxes = np.array([[1.0, 0.0], [1.0, 0.0], [1.0, -0.0], [np.nan, 2.0], [np.nan, 2.0], [1.0, 2.0]])
    assert _new_boxes(boxes).tolist() == [True, False, True, True, False, True]
    assert _new_boxes(np.zeros((0, 8))).tolist() == []
