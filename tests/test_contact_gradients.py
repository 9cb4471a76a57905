"""The crash correction's analytic derivatives agree with finite differences on a real problem.

The problem is the one stage 2 solves for a crash declared between two real KITTI road users (sequence
0002: a pedestrian beside a passing car, as in ``test_crash_replay``): every function SLSQP sees
(the least-squares cost, the pair's separation at the crash and before it, the per-axis acceleration
bound, each mover's kinematic rows) is checked against ``scipy.optimize.approx_fprime`` at the
uncorrected paths and at corrections of a few decimetres.
"""

from __future__ import annotations

from dataclasses import replace
from typing import Any

import numpy as np
import pytest
from scipy.optimize import approx_fprime, check_grad

import deepcrashtest.trajectory.contact as contact
from deepcrashtest.scenario import PEDESTRIAN_KINEMATICS, Collision
from deepcrashtest.trajectory import crash as crash_phase
from deepcrashtest.trajectory.pipeline import process_scenario


class _Recorded(Exception):
    pass


@pytest.fixture(scope="module")
def kitti_crash_problem(kitti_root) -> tuple[Any, ...]:
    """The arguments of the ``make_contact`` call stage 2 makes for the declared crash."""
    from deepcrashtest.datasets.kitti.scenario import scenario_from_kitti

    raw = scenario_from_kitti(kitti_root, 2, road_users=True)
    raw = raw.evolve(collision=Collision(time_s=13.0, other_id=4, agent_id=6, source="user"))
    seen: list[tuple[Any, ...]] = []

    def record(*args: Any) -> Any:
        seen.append(args)
        raise _Recorded

    mp = pytest.MonkeyPatch()
    mp.setattr(crash_phase, "make_contact", record)
    try:
        with pytest.raises(_Recorded):
            process_scenario(raw)
    finally:
        mp.undo()
    return seen[0]


def _window_problem(args: tuple[Any, ...], window_s: float) -> contact._Problem:
    """The SLSQP problem of ``make_contact``'s try with ``window_s``."""
    a, b, t_crash, cp = args
    lo = max(t_crash - window_s, a.t[0], b.t[0])
    bases = [
        contact._rigid(m) if m.rigid else contact._basis(lo, t_crash, cp.knot_step_s, lo > m.t[0] + 1e-6)
        for m in (a, b)
    ]
    t_free = a.t[(a.t >= lo) & (a.t <= t_crash - 0.08)]
    eq = [(0, 1, t_crash, -0.2)]
    return contact._problem([a, b], [], bases, eq, [(0, 1, t_free, 0.0)], cp)


def _points(pb: contact._Problem) -> list[np.ndarray]:
    n = int(pb.paths.offs[-1])
    rng = np.random.default_rng(7)
    return [np.zeros(n), 0.3 * rng.standard_normal(n), 0.6 * rng.standard_normal(n)]


@pytest.mark.parametrize(("window_s", "walking"), [(2.0, False), (4.5, True)])
def test_analytic_derivatives_match_finite_differences_on_a_real_crash(kitti_crash_problem, window_s, walking):
    """As stage 2 poses it (the pedestrian stands: one rigid shift; the car's last seconds move) and
    with the pedestrian's last seconds free to move too (the holonomic rows)."""
    a, b, t_crash, cp = kitti_crash_problem
    assert a.rigid and not b.rigid and b.kin is not None and not b.kin.holonomic
    if walking:
        a = replace(a, rigid=False, kin=PEDESTRIAN_KINEMATICS, weight=1.0)
    pb = _window_problem((a, b, t_crash, cp), window_s)
    assert len(pb.kins) == 1 + walking
    for z in _points(pb):
        err = check_grad(pb.cost, pb.cost_jac, z, epsilon=1e-6)
        assert err <= 1e-5 * (1.0 + np.linalg.norm(pb.cost_jac(z))), err
        for con in pb.cons:
            analytic = np.atleast_2d(con["jac"](z))
            numeric = np.atleast_2d(approx_fprime(z, con["fun"], 1e-7))
            rows = len(numeric)
            scale = 1.0 + np.abs(numeric).max()
            # a finite difference may straddle a kink (the active separating axis, a heading source):
            # all but a few rows agree to 1e-4 of the largest derivative
            bad = np.abs(analytic - numeric).max(axis=1) > 1e-4 * scale
            assert bad.sum() <= max(1, rows // 50), (con["type"], bad.sum(), rows)
