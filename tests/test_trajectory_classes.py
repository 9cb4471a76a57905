"""Trajectory classes, delays and extrapolation on hand-built tracks with a known answer."""

from __future__ import annotations

import numpy as np
import pytest

from deepcrashtest.trajectory.classify import ClassFeatures, trajectory_class
from deepcrashtest.trajectory.pipeline import process_scenario
from trajectory_cases import CLASS_CASES, EGO_SPEED, FPS, raw_scenario, track, vehicle

DELAYED = {"D0T3", "D1T3", "D1T4"}


@pytest.fixture(scope="module")
def processed():
    raw = raw_scenario([v for v in CLASS_CASES.values()])
    return raw, process_scenario(raw)


@pytest.mark.parametrize("cls", sorted(CLASS_CASES))
def test_each_class_alone(cls):
    sc = process_scenario(raw_scenario([CLASS_CASES[cls]]))
    assert sc.agents[0].trajectory_class == cls
    assert sc.collision is None


def test_all_classes_together(processed):
    _, sc = processed
    assert {a.trajectory_class for a in sc.agents} == set(CLASS_CASES)
    for cls, v in CLASS_CASES.items():
        assert sc.vehicle(v.id).trajectory_class == cls


def test_start_delays_follow_frame_of_appearance(processed):
    raw, sc = processed
    t_max = sc.provenance.parameters["t_max_s"]
    present = [v for v in sc.vehicles() if v.trajectory.t[0] == 0]
    first_speeds = [v.trajectory.state_at(t_max)["speed"] for v in present]
    assert t_max == pytest.approx(max(first_speeds) / 3.0, abs=0.05)  # fastest present at start, a = 3 m/s^2
    assert EGO_SPEED / 3.0 <= t_max < 10.5 / 3.0
    for cls, v in CLASS_CASES.items():
        a = sc.vehicle(v.id)
        if cls == "D0T2":  # invented behind the ego for at most max_invented_s before it is seen
            # (less where its invented path would meet an oncoming car's extrapolated one: trimmed)
            assert v.first_frame / FPS - 2.0 + t_max - 1e-6 <= a.start_delay_s <= v.first_frame / FPS + t_max
        elif cls in DELAYED:
            assert a.start_delay_s == pytest.approx(v.first_frame / FPS + t_max, abs=1e-9)
            assert a.trajectory.t[0] == pytest.approx(a.start_delay_s, abs=1e-9)
            assert a.trajectory.observed[0] is True
        else:
            assert a.start_delay_s == 0.0 and a.trajectory.t[0] == 0.0


def test_observed_flags_mark_extrapolation(processed):
    _, sc = processed
    t_max = sc.provenance.parameters["t_max_s"]
    for v in CLASS_CASES.values():
        a = sc.vehicle(v.id).trajectory
        t, obs = np.asarray(a.t), np.asarray(a.observed)
        seen = (t >= v.trajectory.t[0] + t_max - 1e-6) & (t <= v.trajectory.t[-1] + t_max + 1e-6)
        assert np.array_equal(obs, seen), v.id
    assert not any(sc.ego.trajectory.observed[: int(t_max * FPS)])  # step-back part of the ego


def test_every_vehicle_runs_to_the_end(processed):
    _, sc = processed
    end = sc.ego.trajectory.t[-1]
    assert end == pytest.approx(10.0 + sc.provenance.parameters["t_max_s"])
    for a in sc.agents:
        assert a.trajectory.t[-1] == pytest.approx(end)


def test_oncoming_extrapolated_at_constant_speed(processed):
    _, sc = processed
    for vid in (4, 5, 6, 7):
        a = sc.vehicle(vid).trajectory.arrays()
        after = ~np.asarray(sc.vehicle(vid).trajectory.observed) & (a["t"] > sc.vehicle(vid).start_delay_s + 1)
        after &= a["t"] > sc.provenance.parameters["t_max_s"]
        assert after.any()
        assert np.allclose(a["speed"][after], 10.0, atol=0.15)
        assert np.allclose(np.cos(a["yaw"][after]), -1.0, atol=1e-3)  # against the road direction
        assert np.allclose(a["y"][after], 3.5, atol=0.05)  # keeps its lane


def test_ongoing_extrapolated_slower_than_ego():
    # same direction, 12 m/s, ahead in the right lane, leaves the view at 4 s
    fast = vehicle(1, track(lambda t: (15 + 12 * t, -3.5 + 0 * t), 0, 40))
    sc = process_scenario(raw_scenario([fast]))
    a, e = sc.vehicle(1).trajectory.arrays(), sc.ego.trajectory.arrays()
    t_leave = 4.0 + sc.provenance.parameters["t_max_s"]
    late = a["t"] > t_leave + 2.0  # after settling at <= 2 m/s^2 from 12 to 9 m/s
    assert late.any()
    assert np.all(a["speed"][late] <= 0.9 * EGO_SPEED + 0.05)
    # rate-limited to 2 m/s^2 (the final C2 spline rounds the corners of the ramp: < 3 m/s^2), no jump
    assert np.all(np.diff(a["speed"]) / np.diff(a["t"]) >= -3.0)
    assert np.allclose(a["y"][late], -3.5, atol=0.05)
    assert sc.collision is None and e["t"][-1] == pytest.approx(a["t"][-1])


def test_overtaker_before_it_appears_is_behind_and_never_collides(processed):
    _, sc = processed
    t_max = sc.provenance.parameters["t_max_s"]
    a, e = sc.vehicle(2).trajectory.arrays(), sc.ego.trajectory.arrays()
    t_first = 8.0 + t_max
    before = a["t"] < t_first - 1e-6
    ego_x = np.interp(a["t"], e["t"], e["x"])
    rel = a["x"] - ego_x
    r0 = rel[np.argmin(np.abs(a["t"] - t_first))]
    assert r0 == pytest.approx(5.0, abs=0.1)
    assert np.all(rel[before] <= r0 + 1e-6)  # never further ahead than where it is first seen
    assert np.all(np.diff(rel[a["t"] >= t_max - 1e-6]) >= -1e-3)  # only closes in (after the step-back)
    # invented for at most 2 s before it is seen (it starts late), behind the ego, never past the safe gap
    assert t_first - 2.0 - 1e-6 <= a["t"][0] < t_first
    assert -20.0 - 0.1 <= rel[0] < r0
    assert np.allclose(a["y"], 3.5, atol=0.05)  # in its own lane: boxes 3.5 m apart never touch
    assert not any(np.asarray(sc.vehicle(2).trajectory.observed)[before])


def test_parked_car_is_static_for_the_whole_scenario():
    parked = vehicle(1, track(lambda t: (80.0 + 0 * t, -6.0 + 0 * t), 40, 70, yaw=0.0, noise=0.05))
    facing = vehicle(2, track(lambda t: (30.0 + 0 * t, 6.0 + 0 * t), 0, 25, yaw=np.pi, noise=0.05, seed=1))
    sc = process_scenario(raw_scenario([parked, facing]))
    p, f = sc.vehicle(1), sc.vehicle(2)
    assert p.trajectory_class == "D0T3"  # seen later, ahead: a parked car never counts as an overtaker
    assert f.trajectory_class == "D1T1"  # faces the ego, in view at start, the ego drives past it
    for v in (p, f):
        a = v.trajectory.arrays()
        assert v.start_delay_s == 0 and a["t"][0] == 0  # it was there all along
        assert a["t"][-1] == pytest.approx(sc.ego.trajectory.t[-1])
        assert np.all(a["speed"] == 0)
        assert np.ptp(a["x"]) < 1e-6 and np.ptp(a["y"]) < 1e-6
    assert p.trajectory.x[0] == pytest.approx(80.0, abs=0.05)
    assert np.cos(f.trajectory.yaw[0]) == pytest.approx(-1.0, abs=1e-3)


def test_rules_table():
    f = ClassFeatures(oncoming=False, in_view_at_start=False, static=False, entry_gap_m=30.0,
                      entry_rel_speed_mps=2.0, passed=False)  # fmt: skip
    assert trajectory_class(f, overtake_entry_gap_m=20.0) == "D0T3"  # appears far ahead
    assert trajectory_class(f, overtake_entry_gap_m=40.0) == "D0T2"
    g = ClassFeatures(True, True, False, 50.0, -20.0, passed=True)
    assert trajectory_class(g, 20.0) == "D1T1"
