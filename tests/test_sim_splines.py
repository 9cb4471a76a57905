"""``sim.splines`` (SciPy's splines in NumPy, without its import time) against SciPy itself, on a real ego track."""

from __future__ import annotations

import subprocess
import sys

import numpy as np
import pytest
from scipy.interpolate import BSpline, make_interp_spline, make_lsq_spline, make_smoothing_spline

from deepcrashtest.sim import splines
from deepcrashtest.sim.reference import SMOOTH_CUTOFF_HZ


@pytest.fixture(scope="module")
def kitti3(kitti_root):
    from deepcrashtest.datasets.kitti.scenario import scenario_from_kitti

    return scenario_from_kitti(kitti_root, 3)


@pytest.fixture(scope="module")
def track(kitti3):
    """The real KITTI 0003 ego track: times (s) and x, y (m), label noise included."""
    a = kitti3.ego.trajectory.arrays()
    return a["t"], np.column_stack([a["x"], a["y"]])


def _grid(t: np.ndarray) -> np.ndarray:
    return np.linspace(t[0], t[-1], 2001)


@pytest.mark.parametrize("k", [1, 3])
def test_interpolating_spline_is_scipys(track, k):
    t, xy = track
    ref, got = make_interp_spline(t, xy, k=k), splines.interp_spline(t, xy, k)
    tq = _grid(t)
    np.testing.assert_allclose(got(tq), ref(tq), rtol=0, atol=1e-9)
    np.testing.assert_allclose(got.derivative()(tq), ref.derivative()(tq), rtol=0, atol=1e-8)
    np.testing.assert_allclose(got(t), xy, rtol=0, atol=1e-9)  # through the samples


def test_smoothing_spline_is_scipys(track):
    t, xy = track
    lam = float(np.median(np.diff(t))) / (2.0 * np.pi * SMOOTH_CUTOFF_HZ) ** 4
    tq = _grid(t)
    for d in range(2):
        ref, got = make_smoothing_spline(t, xy[:, d], lam=lam), splines.smoothing_spline(t, xy[:, d], lam)
        np.testing.assert_allclose(got(tq), ref(tq), rtol=0, atol=1e-9)
        np.testing.assert_allclose(got.derivative()(tq), ref.derivative()(tq), rtol=0, atol=1e-8)
    assert np.abs(got(t) - xy[:, 1]).max() > 1e-3  # it smooths: not through the noisy samples


def test_least_squares_spline_and_basis_are_scipys(track):
    t, xy = track
    knots = np.r_[[t[0]] * 4, np.linspace(t[0], t[-1], 14)[1:-1], [t[-1]] * 4]
    ref, got = make_lsq_spline(t, xy, knots, k=3), splines.lsq_spline(t, xy, knots, 3)
    np.testing.assert_allclose(got.c, ref.c, rtol=0, atol=1e-8)
    tq = _grid(t)
    eye = np.eye(len(knots) - 4)
    for nu in range(3):
        want = BSpline(knots, eye, 3).derivative(nu)(tq) if nu else BSpline(knots, eye, 3)(tq)
        np.testing.assert_allclose(splines.BSpline(knots, eye, 3).derivative(nu)(tq), want, rtol=0, atol=1e-9)
    np.testing.assert_allclose(splines.basis_matrix(knots, 3, tq).sum(axis=1), 1.0, atol=1e-12)  # partition of unity


def test_bad_sample_counts_are_refused():
    with pytest.raises(ValueError, match="samples"):
        splines.interp_spline(np.arange(3.0), np.zeros(3), 3)
    with pytest.raises(ValueError, match=">= 5"):
        splines.smoothing_spline(np.arange(4.0), np.zeros(4), 1.0)


def test_a_search_process_imports_neither_scipy_nor_pandas(kitti3, tmp_path):
    """Their imports cost ~1.5 s of CPU per search process (more than 2,000 variants' simulation took): a whole
    search (the CLI, simulation, results written) runs without them."""
    scen = kitti3.save(tmp_path / "k3.json")
    code = (
        "import sys; from deepcrashtest.cli import main\n"
        "try:\n    main()\nexcept SystemExit as e:\n    assert not e.code, e.code\n"
        "print(sorted(m for m in ('scipy', 'pandas', 'matplotlib') if m in sys.modules))"
    )
    args = ["search", str(scen), "-o", str(tmp_path / "s"), "--method", "random", "--starts", "2", "--no-video"]
    out = subprocess.run([sys.executable, "-c", code, *args, "--json"], capture_output=True, text=True, timeout=300)
    assert out.returncode == 0, out.stderr
    assert out.stdout.strip().splitlines()[-1] == "[]"
    assert (tmp_path / "s" / "results.csv").exists() and (tmp_path / "s" / "starts.png").exists()


def test_reference_median_equals_numpy_bit_for_bit(kitti_root):
    """``sim.reference._median`` (no numpy.ma import) gives ``np.median``'s value, bits included: the real
    KITTI 0008 sample intervals and headings, and odd and even random lengths."""
    from deepcrashtest.datasets.kitti.scenario import scenario_from_kitti
    from deepcrashtest.sim.reference import _median

    sc = scenario_from_kitti(kitti_root, 8)
    arrays = [np.diff(v.trajectory.t) for v in sc.vehicles() if len(v.trajectory) > 1]
    arrays += [np.asarray(v.trajectory.yaw) for v in sc.vehicles()]
    rng = np.random.default_rng(2)
    arrays += [rng.normal(0.0, 10.0 ** rng.uniform(-3, 3), n) for n in (*range(1, 30), 100, 101, 915)]
    for a in arrays:
        assert _median(a).hex() == float(np.median(a)).hex()
