"""The search space on a real KITTI drive: spline fit, variant sampling, paths."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.interpolate import BSpline

from deepcrashtest.errors import UserError
from deepcrashtest.search.space import SearchSpace
from deepcrashtest.search.spline import evaluate_paths, fit_spline


@pytest.fixture(scope="module")
def space(kitti8_raw):
    return SearchSpace.for_scenario(kitti8_raw, box_lateral=4.0, box_longitudinal=8.0, noise_sigma=0.3)


def test_fitted_spline_follows_the_real_ego_path(kitti8_raw, space):
    a = kitti8_raw.ego.trajectory.arrays()
    p = space.paths(np.zeros((1, space.dim)))[0]
    err = np.hypot(p[:, 0] - a["x"], p[:, 1] - a["y"])
    assert err.max() < 0.2, err.max()  # 39 s, 591 m of real (ORB-SLAM3) ego motion, 1 s knots
    # the basis-matrix evaluation is SciPy's BSpline, control points and all
    sp = space.spline
    ref = BSpline(np.array(sp.knots), np.column_stack([sp.cx, sp.cy]), sp.degree)(a["t"])
    np.testing.assert_allclose(p, ref, atol=1e-9)
    tr = space.variant_trajectory(np.zeros(space.dim))
    assert np.abs(np.array(tr.speed) - a["speed"]).mean() < 0.2


def test_reference_grid_is_seeded_inside_the_box_and_start_major(space):
    g1 = space.reference_grid(np.random.default_rng(5), 32, 4)
    g2 = space.reference_grid(np.random.default_rng(5), 32, 4)
    g3 = space.reference_grid(np.random.default_rng(6), 32, 4)
    assert g1.shape == (128, space.dim)
    np.testing.assert_array_equal(g1, g2)
    assert not np.allclose(g1, g3)
    assert np.all(np.abs(g1[:, 0]) <= 4.0) and np.all(np.abs(g1[:, 1]) <= 2.0)
    starts = g1[:, :2].reshape(32, 4, 2)
    assert np.all(starts == starts[:, :1])  # 4 noisy paths share each start
    assert abs(g1[:, 2:].std() - 0.3) < 0.03
    with pytest.raises(UserError):
        space.reference_grid(np.random.default_rng(0), 0, 4)


def test_offset_moves_the_whole_path_in_the_ego_frame(space):
    th = np.zeros((2, space.dim))
    th[1, :2] = [3.0, -1.5]  # 3 m forward, 1.5 m right of the original start
    p = space.paths(th)
    d = p[1] - p[0]
    c, s = np.cos(space.yaw0), np.sin(space.yaw0)
    np.testing.assert_allclose(d, np.broadcast_to([3 * c + 1.5 * s, 3 * s - 1.5 * c], d.shape), atol=1e-9)
    np.testing.assert_allclose(space.change(th), [0.0, np.hypot(3.0, 1.5)])


def test_noise_keeps_the_start_and_bends_the_path(space):
    th = np.zeros((1, space.dim))
    th[0, 2:] = np.random.default_rng(1).normal(0, 0.3, space.dim - 2)
    p0 = space.paths(np.zeros((1, space.dim)))[0]
    p1 = space.paths(th)[0]
    assert np.allclose(p1[0], p0[0])  # clamped spline: the start is the first control point
    assert 0.05 < np.abs(p1 - p0).max() < 1.5


def test_fit_spline_refuses_too_few_samples():
    with pytest.raises(UserError, match="needs >= 4"):
        fit_spline(np.array([0.0, 0.1, 0.2]), np.zeros((3, 2)))
    sp = fit_spline(np.linspace(0, 3, 31), np.column_stack([np.linspace(0, 30, 31), np.zeros(31)]))
    np.testing.assert_allclose(evaluate_paths(sp, np.column_stack([sp.cx, sp.cy]), np.array([1.5]))[0], [15, 0])


def test_variant_kinematics_of_many_are_each_variants_trajectory(space):
    """The variant files' trajectories computed a block at a time are each variant's own, bit for bit."""
    from deepcrashtest.scenario import Trajectory

    theta = space.reference_grid(np.random.default_rng(7), 6, 3)
    kin = space.variant_kinematics(theta)
    assert len(kin) == len(theta)
    for b, arrays in enumerate(kin):
        assert Trajectory.from_arrays(*arrays) == space.variant_trajectory(theta[b]), b
