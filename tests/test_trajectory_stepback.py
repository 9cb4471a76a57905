"""Step-back initialisation: the synchronisation equations, checked numerically."""

from __future__ import annotations

import numpy as np
import pytest

from deepcrashtest.errors import UserError
from deepcrashtest.trajectory.params import Stage2Params
from deepcrashtest.trajectory.pipeline import process_scenario
from deepcrashtest.trajectory.stepback import distance_from_rest, plan_step_back, step_back_prefix
from trajectory_cases import CLASS_CASES, raw_scenario, track, vehicle


def _simulate(v_target: float, a: float, t_end: float, dt: float = 1e-4) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Explicit time-stepping of 'accelerate at a until v_target, then hold' (independent of the formulas)."""
    n = int(round(t_end / dt))
    t = np.arange(n + 1) * dt
    v = np.minimum(a * t, v_target)
    x = np.concatenate([[0.0], np.cumsum(0.5 * (v[1:] + v[:-1]) * dt)])
    return t, v, x


def test_synchronisation_equations():
    a = 3.0
    speeds = np.array([10.0, 15.0, 0.0, 5.0, 12.5])
    plan = plan_step_back(speeds, a)
    assert plan.t_max == pytest.approx(5.0)
    assert np.allclose(plan.t_i, speeds / a) and np.allclose(plan.d_i, speeds**2 / (2 * a))
    assert np.allclose(plan.D_i, plan.d_i + (plan.t_max - plan.t_i) * speeds)
    for v, D in zip(speeds, plan.D_i, strict=True):
        t, vel, x = _simulate(v, a, plan.t_max)
        # every vehicle is at its observed speed at t_max (the same instant for all) ...
        assert vel[-1] == pytest.approx(v)
        # ... reached at t_i = v / a, not before
        if v > 0:
            assert t[np.argmax(vel >= v - 1e-9)] == pytest.approx(v / a, abs=2e-4)
        # ... having covered exactly D_i from rest
        assert x[-1] == pytest.approx(D, abs=1e-6)
        assert distance_from_rest(np.array([plan.t_max]), v, a)[0] == pytest.approx(D)


def test_prefix_reaches_the_first_observed_positions_together():
    a = 3.0
    first = {1: (np.array([0.0, 0.0]), 0.0, 10.0), 2: (np.array([25.0, -3.5]), 0.0, 14.0),
             3: (np.array([60.0, 3.5]), np.pi, 8.0)}  # fmt: skip
    plan = plan_step_back(np.array([v for _, _, v in first.values()]), a)
    t = np.linspace(0, plan.t_max, 2001)
    paths = {k: step_back_prefix(p, h, v, plan, t) for k, (p, h, v) in first.items()}
    for k, (p, h, v) in first.items():
        q = paths[k]
        assert np.allclose(q[-1], p, atol=1e-9)  # at t_max: the first observed position
        speed = np.hypot(*np.gradient(q, t, axis=0).T)
        assert speed[0] == pytest.approx(0.0, abs=0.02)  # starts at rest
        assert speed[-1] == pytest.approx(v, abs=0.02)  # reaches its observed speed
        back = np.hypot(*(p - q[0]))
        assert back == pytest.approx(plan.D_i[list(first).index(k)])
        along = (q[-1] - q[0]) @ [np.cos(h), np.sin(h)]
        assert along == pytest.approx(back)  # straight along the initial heading
    # relative positions at t_max are the first observed ones
    assert np.allclose(paths[2][-1] - paths[1][-1], first[2][0] - first[1][0])


def test_processed_scenario_starts_at_rest_and_reproduces_the_first_frame():
    agents = [CLASS_CASES[c] for c in ("D0T1", "D1T1", "D1T2")]
    # faster car ahead, in the right lane (in the left one it would drive through the oncoming D1T1,
    # a contact stage 2 now removes)
    agents.append(vehicle(9, track(lambda t: (35 + 14 * t, -3.5 + 0 * t), 0, 100)))
    raw = raw_scenario(agents)
    sc = process_scenario(raw, params=Stage2Params(stepback_max_s=10.0))  # uncapped: all from rest
    t_max = sc.provenance.parameters["t_max_s"]
    assert t_max == pytest.approx(14.0 / 3.0, abs=0.02)
    for v in sc.vehicles():
        r = raw.vehicle(v.id).trajectory
        a = v.trajectory.arrays()
        assert a["t"][0] == 0 and a["speed"][0] < 0.1  # at rest at t = 0
        s = v.trajectory.state_at(t_max)
        assert s["x"] == pytest.approx(r.x[0], abs=0.02) and s["y"] == pytest.approx(r.y[0], abs=0.02)
        # the final C2 spline rounds the corner of the speed profile at t_i (here t_i = t_max for the
        # fastest vehicle) by up to ~0.2 m/s; the plan itself is exact (tests above)
        assert s["speed"] == pytest.approx(r.speed[0], abs=0.25)
        # distance travelled from rest to t_max is D_i = d_i + (t_max - t_i) v_i
        pre = a["t"] <= t_max + 1e-9
        travelled = np.hypot(np.diff(a["x"][pre]), np.diff(a["y"][pre])).sum()
        vi = r.speed[0]
        assert travelled == pytest.approx(vi**2 / 6 + (t_max - vi / 3) * vi, abs=0.05)
        # after t_max the video is reproduced, shifted by t_max
        obs = np.asarray(v.trajectory.observed)
        assert obs.sum() == len(r.t) and a["t"][obs][0] == pytest.approx(t_max)
        assert np.allclose(a["x"][obs], r.x, atol=0.05) and np.allclose(a["y"][obs], r.y, atol=0.05)


def test_bad_acceleration():
    with pytest.raises(UserError, match="acceleration"):
        plan_step_back(np.array([10.0]), 0.0)
