"""Waypoint edits on real KITTI trajectories: positions, derived speed/yaw, spline refit, validation."""

from __future__ import annotations

import math
import re

import numpy as np
import pytest
from scipy.interpolate import BSpline, make_lsq_spline

from deepcrashtest.scenario import Scenario, wrap_angle
from deepcrashtest.viz.edit import (
    MOVING_MPS,
    EditError,
    apply_edit,
    falloff_weights,
    motion,
    move_waypoint,
    shift_trajectory,
)

AGENT = 9  # KITTI 0008 track 8: a car seen in all 390 frames


def _unchanged_except(a: Scenario, b: Scenario, vid: int) -> None:
    for v in a.vehicles():
        if v.id != vid:
            assert b.vehicle(v.id) == v


def test_move_waypoint_moves_it_and_keeps_speed_derived_from_positions(kitti8_raw):
    sc = kitti8_raw
    old = sc.vehicle(AGENT).trajectory.arrays()
    i = 120
    new_sc = move_waypoint(sc, AGENT, i, old["x"][i] + 1.5, old["y"][i] - 0.8, falloff_s=0.6)
    new = new_sc.vehicle(AGENT).trajectory.arrays()
    assert new["x"][i] == pytest.approx(old["x"][i] + 1.5, abs=1e-12)
    assert new["y"][i] == pytest.approx(old["y"][i] - 0.8, abs=1e-12)
    # neighbours follow with the raised-cosine weights, nothing beyond the falloff moves
    w = falloff_weights(old["t"], i, 0.6)
    np.testing.assert_allclose(new["x"] - old["x"], 1.5 * w, atol=1e-12)
    np.testing.assert_allclose(new["y"] - old["y"], -0.8 * w, atol=1e-12)
    far = np.abs(old["t"] - old["t"][i]) >= 0.6 + 0.15  # + one sample: central differences reach one further
    assert far.sum() > 300
    for k in ("x", "y", "yaw", "speed"):
        np.testing.assert_array_equal(new[k][far], old[k][far])
    # from_kitti derives speed by central differences: after the edit it still is exactly that
    v_new, h_new = motion(new["t"], new["x"], new["y"])
    np.testing.assert_allclose(new["speed"], v_new, atol=1e-9)
    # yaw turned by the change of the direction of motion where the car moves
    v_old, h_old = motion(old["t"], old["x"], old["y"])
    moving = (v_old >= MOVING_MPS) & (v_new >= MOVING_MPS)
    np.testing.assert_allclose(new["yaw"][moving] - old["yaw"][moving], wrap_angle(h_new - h_old)[moving], atol=1e-9)
    assert np.abs(new["yaw"] - old["yaw"]).max() > 0.01
    assert new_sc.provenance.history[-1].startswith(f"move_waypoint vehicle={AGENT} index={i}")
    _unchanged_except(sc, new_sc, AGENT)
    assert sc.vehicle(AGENT).trajectory.arrays()["x"][i] == old["x"][i]  # the input is not modified


def test_zero_falloff_moves_a_single_waypoint(kitti8_raw):
    tr = kitti8_raw.vehicle(AGENT).trajectory
    new = move_waypoint(kitti8_raw, AGENT, 10, tr.x[10], tr.y[10] + 0.3, falloff_s=0).vehicle(AGENT).trajectory
    dy = np.asarray(new.y) - np.asarray(tr.y)
    assert np.count_nonzero(dy) == 1 and dy[10] == pytest.approx(0.3)


def test_shift_moves_every_sample_in_its_own_frame(kitti8_raw):
    old = kitti8_raw.vehicle(AGENT).trajectory.arrays()
    new_sc = shift_trajectory(kitti8_raw, AGENT, d_lon=2.0, d_lat=-1.0)
    new = new_sc.vehicle(AGENT).trajectory.arrays()
    c, s = np.cos(old["yaw"]), np.sin(old["yaw"])
    np.testing.assert_allclose(new["x"], old["x"] + 2.0 * c + 1.0 * s, atol=1e-12)
    np.testing.assert_allclose(new["y"], old["y"] + 2.0 * s - 1.0 * c, atol=1e-12)
    assert np.hypot(new["x"] - old["x"], new["y"] - old["y"]) == pytest.approx(np.full(len(c), math.sqrt(5)))
    np.testing.assert_allclose(new["speed"], motion(new["t"], new["x"], new["y"])[0], atol=1e-9)
    assert new_sc.provenance.history == ["shift vehicle=9 d_lon=+2.000 m d_lat=-1.000 m (vehicle frame)"]


def _with_spline(sc: Scenario, vid: int, spacing_s: float = 2.0) -> Scenario:
    """The scenario with a least-squares cubic B-spline (knots every ``spacing_s``) fitted to one vehicle."""
    tr = sc.vehicle(vid).trajectory.arrays()
    t = tr["t"]
    inner = np.arange(t[0] + spacing_s, t[-1] - spacing_s / 2, spacing_s)
    knots = np.r_[[t[0]] * 4, inner, [t[-1]] * 4]
    sx, sy = make_lsq_spline(t, tr["x"], knots, k=3), make_lsq_spline(t, tr["y"], knots, k=3)
    data = sc.model_dump(mode="json")
    veh = next(a for a in data["agents"] if a["id"] == vid)
    veh["spline"] = {"knots": knots.tolist(), "cx": sx.c.tolist(), "cy": sy.c.tolist(), "degree": 3}
    return Scenario.from_dict(data)


def test_spline_control_points_equal_a_scipy_refit_of_the_edited_path(kitti8_raw):
    sc = _with_spline(kitti8_raw, AGENT)
    tr = sc.vehicle(AGENT).trajectory
    new_sc = move_waypoint(sc, AGENT, 200, tr.x[200] - 2.0, tr.y[200] + 1.0, falloff_s=1.5)
    veh = new_sc.vehicle(AGENT)
    assert veh.spline is not None
    a = veh.trajectory.arrays()
    knots = np.asarray(veh.spline.knots)
    # least squares is linear: old fit + fit of the displacement == fit of the new path (scipy as reference)
    ref_x, ref_y = make_lsq_spline(a["t"], a["x"], knots, k=3), make_lsq_spline(a["t"], a["y"], knots, k=3)
    np.testing.assert_allclose(veh.spline.cx, ref_x.c, atol=1e-6)
    np.testing.assert_allclose(veh.spline.cy, ref_y.c, atol=1e-6)
    # and the spline follows the edited waypoint
    at = BSpline(knots, np.asarray(veh.spline.cx), 3)(a["t"][200])
    assert abs(at - a["x"][200]) < abs(at - tr.x[200])


def test_shift_translates_a_spline_of_a_straight_path(kitti8_raw):
    sc = _with_spline(kitti8_raw, AGENT)
    before = sc.vehicle(AGENT).spline
    after = shift_trajectory(sc, AGENT, 0.0, 1.0).vehicle(AGENT).spline
    assert before is not None and after is not None
    d = np.hypot(np.subtract(after.cx, before.cx), np.subtract(after.cy, before.cy))
    assert d == pytest.approx(np.ones(len(d)), abs=0.05)  # this car drives nearly straight
    assert after.knots == before.knots and after.degree == before.degree


def test_processed_scenario_refuses_an_edit_no_car_could_drive(kitti8_raw):
    ego_only = Scenario.from_dict({**kitti8_raw.model_dump(mode="json"), "agents": [], "stage": "processed"})
    tr = ego_only.ego.trajectory
    with pytest.raises(EditError, match="acceleration") as err:
        move_waypoint(ego_only, 0, 100, tr.x[100] + 3.0, tr.y[100], falloff_s=0)
    # the refusal says what would work, and it does
    found = re.search(r"a drag falloff of ([0-9.]+) s or a move of at most ([0-9.]+) m", str(err.value))
    assert found, str(err.value)
    falloff, most = float(found[1]), float(found[2])
    ok = move_waypoint(ego_only, 0, 100, tr.x[100] + 3.0, tr.y[100], falloff_s=falloff)
    assert ok.ego.trajectory.x[100] == pytest.approx(tr.x[100] + 3.0)
    assert ok.ego.trajectory.max_abs_accel()[0] <= 15.0
    move_waypoint(ego_only, 0, 100, tr.x[100] + most, tr.y[100], falloff_s=0)
    with pytest.raises(EditError):
        move_waypoint(ego_only, 0, 100, tr.x[100] + most + 0.05, tr.y[100], falloff_s=0)
    # the default falloff takes a 3 m drag sideways (bench/viewer_drag.py: 100% of KITTI 0008's drags)
    ok = move_waypoint(ego_only, 0, 100, tr.x[100], tr.y[100] + 3.0)
    assert ok.ego.trajectory.y[100] == pytest.approx(tr.y[100] + 3.0)


@pytest.mark.parametrize(
    ("edit", "message"),
    [
        ({"kind": "teleport", "vehicle_id": 9}, "edit.kind"),
        ({"kind": "shift", "vehicle_id": 999, "d_lon": 1.0}, "999 is not a vehicle"),
        ({"kind": "shift", "vehicle_id": True, "d_lon": 1.0}, "vehicle_id must be an integer"),
        ({"kind": "shift", "vehicle_id": 9, "d_lon": "1"}, "d_lon must be a number"),
        ({"kind": "shift", "vehicle_id": 9, "d_lon": float("nan")}, "finite"),
        ({"kind": "shift", "vehicle_id": 9, "d_lon": 1e6}, "more than"),
        ({"kind": "shift", "vehicle_id": 9, "dlon": 1.0}, "unknown field"),
        ({"kind": "move_waypoint", "vehicle_id": 9, "index": 390, "x": 0, "y": 0}, "outside"),
        ({"kind": "move_waypoint", "vehicle_id": 9, "index": 1, "x": 0, "y": 0, "falloff_s": -1}, "falloff_s"),
        ({"kind": "move_waypoint", "vehicle_id": 9, "index": 1, "x": float("inf"), "y": 0}, "finite"),
    ],
)
def test_bad_edits_are_refused_with_the_reason(kitti8_raw, edit, message):
    with pytest.raises(EditError, match=message):
        apply_edit(kitti8_raw, edit)


def test_a_shift_no_car_could_drive_is_refused_with_the_shift_that_works(kitti8_raw):
    from deepcrashtest.trajectory.pipeline import process_scenario

    sc = process_scenario(kitti8_raw)
    vid = 20  # an oncoming car on the curve: 20 m to its left its parallel path needs 21.5 m/s^2
    sc = sc.evolve(agents=[a for a in sc.agents if a.id == vid])
    with pytest.raises(EditError, match="at most") as err:
        shift_trajectory(sc, vid, 0.0, 20.0)
    found = re.search(r"at most ([-+0-9.]+) m along and ([-+0-9.]+) m across would work", str(err.value))
    assert found, str(err.value)
    ok = shift_trajectory(sc, vid, float(found[1]), float(found[2]))
    assert ok.vehicle(vid).trajectory.max_abs_accel()[0] <= 15.0
    assert 10.0 < float(found[2]) < 20.0
