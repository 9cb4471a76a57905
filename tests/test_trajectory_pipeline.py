"""Stage 2 end to end: real KITTI sequences, spline consistency, road, collisions, bad input, CLI, plot."""

from __future__ import annotations

import json
import subprocess
import sys
from collections import Counter

import numpy as np
import pytest
import shapely
from scipy.interpolate import BSpline

from deepcrashtest.datasets.kitti.scenario import scenario_from_kitti
from deepcrashtest.errors import UserError
from deepcrashtest.scenario import Collision, LaneTimeline, Scenario, wrap_angle
from deepcrashtest.trajectory.agentheading import BLEND_S
from deepcrashtest.trajectory.params import Stage2Params
from deepcrashtest.trajectory.pipeline import process_scenario
from deepcrashtest.trajectory.roadframe import RoadFrame
from trajectory_cases import EGO_SPEED, raw_scenario, track, vehicle


@pytest.fixture(scope="module")
def kitti(kitti_root):
    out = {}
    for s in (3, 8, 10):
        raw = scenario_from_kitti(kitti_root, s)
        out[s] = (raw, process_scenario(raw))
    return out


def test_kitti_processed_scenarios_are_valid(kitti):
    for _raw, sc in kitti.values():
        assert sc.stage == "processed"
        again = Scenario.from_dict(json.loads(sc.to_json()))  # passes validation incl. |accel| <= 15 m/s^2
        assert again == sc
        assert sc.collision is None  # no crash in these drives
        assert all(a.trajectory_class is not None for a in sc.agents)
        assert sc.provenance.parameters["t_max_s"] > 0


def test_kitti_known_classes(kitti):
    """Classes checked against what the labels show (first/last frame, direction of travel)."""
    _, sc8 = kitti[8]
    cls = {a.id: a.trajectory_class for a in sc8.agents}
    assert cls[9] == "D0T1"  # same direction, labelled in every frame 0..389
    assert all(cls[i] == "D1T1" for i in (1, 2, 5, 6, 7))  # oncoming from frame 0, pass the ego
    assert cls[15] == "D0T2"  # same direction, first labelled at frame 320 beside the ego, faster
    assert cls[28] == "D1T4"  # oncoming truck labelled in the last 6 frames only
    assert cls[3] == "D0T1"  # parked van beside the road at the start (static, box facing forward)
    _, sc10 = kitti[10]
    cls10 = {a.id: a.trajectory_class for a in sc10.agents}
    assert cls10[1] == "D0T1" and cls10[2] == "D1T1" and cls10[10] == "D1T3"
    assert 26 not in cls10  # a 1-sample track: dropped, with a warning
    assert any("agent 26: 1-sample track" in w for w in sc10.warnings)
    counts = {s: Counter(a.trajectory_class for a in sc.agents) for s, (_, sc) in kitti.items()}
    assert sum(counts[8].values()) == 27 and sum(counts[3].values()) == 9 and sum(counts[10].values()) == 16


def test_samples_are_the_spline_and_its_derivative(kitti):
    raw, sc = kitti[8]
    raw_by_id = {a.id: a.trajectory.arrays() for a in raw.agents}
    shift = sc.provenance.parameters["video_time_offset_s"]
    for v in sc.vehicles():
        sp = v.spline
        assert sp is not None
        a = v.trajectory.arrays()
        bx = BSpline(np.asarray(sp.knots), np.asarray(sp.cx), sp.degree)
        by = BSpline(np.asarray(sp.knots), np.asarray(sp.cy), sp.degree)
        assert np.allclose(bx(a["t"]), a["x"], atol=1e-6) and np.allclose(by(a["t"]), a["y"], atol=1e-6)
        vx, vy = bx.derivative()(a["t"]), by.derivative()(a["t"])
        moving = np.hypot(vx, vy) > 0.3
        if np.any(a["speed"] > 0):
            assert np.allclose(a["speed"], np.hypot(vx, vy), atol=1e-6)
        assert np.all(a["speed"] >= 0)
        # agents: the direction of their spline, but over their observed span (plus BLEND_S) the raw heading (fitted
        # to the boxes; here KITTI's labels); the ego: the camera's measured yaw (as the agents were placed with),
        # which agrees with its path's direction on KITTI's ORB-SLAM poses
        if v.id == sc.ego.id:
            assert np.allclose(wrap_angle(a["yaw"][moving] - np.arctan2(vy, vx)[moving]), 0, atol=0.03)
            continue
        r = raw_by_id[v.id]
        seen = (a["t"] >= r["t"][0] + shift - BLEND_S) & (a["t"] <= r["t"][-1] + shift + BLEND_S)
        assert np.allclose(wrap_angle(a["yaw"][moving & ~seen] - np.arctan2(vy, vx)[moving & ~seen]), 0, atol=1e-6)
        inside = (a["t"] >= r["t"][0] + shift) & (a["t"] <= r["t"][-1] + shift) & moving
        label = np.interp(a["t"][inside] - shift, r["t"], np.unwrap(r["yaw"]))
        assert np.allclose(np.sin(a["yaw"][inside] - label), 0, atol=1e-6)  # the label's heading (or a half turn)


def test_delayed_vehicles_start_at_their_delay(kitti):
    for _, sc in kitti.values():
        t_max = sc.provenance.parameters["t_max_s"]
        for a in sc.agents:
            if a.start_delay_s > 0:
                assert a.trajectory_class in ("D0T2", "D0T3", "D1T3", "D1T4")
                assert a.start_delay_s == pytest.approx(a.trajectory.t[0])
                invented = 2.0 if a.trajectory_class == "D0T2" else 0.0  # an overtaker: 2 s before it is seen
                assert a.start_delay_s == pytest.approx(a.first_frame / sc.source.fps - invented + t_max, abs=1e-6)


@pytest.mark.parametrize("sequence", [8, 10])
def test_curved_road_follows_the_ego(kitti, sequence):
    _, sc = kitti[sequence]
    frame = RoadFrame.from_polyline(sc.road.centerline())
    e = sc.ego.trajectory.arrays()
    s, d = frame.project(np.column_stack([e["x"], e["y"]]))
    assert np.abs(d).max() < 1.0  # the ego stays in its lane, on the centre line (RMS = road_sigma_m)
    assert np.sqrt((d**2).mean()) == pytest.approx(Stage2Params().road_sigma_m, abs=0.05)
    heading = frame.tangent(np.linspace(0, frame.length, 200))
    assert np.ptp(np.unwrap(heading)) > 0.15  # the road really curves (KITTI 0008/0010 bend)
    assert s.min() > 0 and s.max() < frame.length  # the road covers the whole drive incl. the step-back
    # KITTI labels carry no lane lines: the lanes are inferred from the road users' paths, and said so
    assert 3.0 <= sc.road.lane_width <= 3.75 and sc.road.source == "road_users"


def test_deterministic(kitti_root):
    raw = scenario_from_kitti(kitti_root, 3)
    assert process_scenario(raw, seed=3).to_json() == process_scenario(raw, seed=3).to_json()


# ---------------------------------------------------------------- collisions
def head_on_raw(**kw):  # type: ignore[no-untyped-def]
    oncoming = vehicle(1, track(lambda t: (100 - 10 * t, 0 * t), 0, 60))
    return raw_scenario([oncoming, vehicle(2, track(lambda t: (30 + 10 * t, -3.5 + 0 * t), 0, 100))], **kw)


def test_collision_detected_and_trajectories_end_there():
    sc = process_scenario(head_on_raw())
    t_max = sc.provenance.parameters["t_max_s"]
    c = sc.collision
    assert c is not None and c.agent_id == 1 and c.other_id == 0
    # boxes 4.5 m long meet when the centres are 4.5 m apart: 100 - 20 t = 4.5
    assert c.time_s == pytest.approx(95.5 / 20 + t_max, abs=0.01)
    assert c.x == pytest.approx(50.0, abs=0.05) and c.y == pytest.approx(0.0, abs=0.05)  # front meets front
    assert c.relative_speed == pytest.approx(20.0, abs=0.5)
    for v in sc.vehicles():
        assert v.trajectory.t[-1] == pytest.approx(c.time_s)
    assert sc.vehicle(1).trajectory_class == "D1T2"  # hit, not passed
    # shapely agrees: the boxes just touch at the end and were apart 0.1 s before
    from deepcrashtest.trajectory.collision import boxes

    def poly(v, t):  # type: ignore[no-untyped-def]
        s = v.trajectory.state_at(t)
        return boxes(np.array([s["x"]]), np.array([s["y"]]), np.array([s["yaw"]]), v.length, v.width)[0]

    assert shapely.intersects(poly(sc.ego, c.time_s + 1e-3), poly(sc.vehicle(1), c.time_s + 1e-3))
    assert not shapely.intersects(poly(sc.ego, c.time_s - 0.1), poly(sc.vehicle(1), c.time_s - 0.1))


def test_head_on_road_continues_along_the_oncoming_path():
    sc = process_scenario(head_on_raw())
    assert sc.road.source == "ego_path+oncoming"
    c = sc.road.centerline()
    assert c[:, 0].max() > 95  # reaches past the collision (x = 50) to where the oncoming car came from
    assert np.abs(c[:, 1]).max() < 0.2


def test_raw_collision_is_kept():
    sc = process_scenario(head_on_raw(collision=Collision(time_s=4.0, agent_id=2, x=40.0, y=-1.0)))
    t_max = sc.provenance.parameters["t_max_s"]
    assert sc.collision is not None and sc.collision.agent_id == 2
    assert sc.collision.time_s == pytest.approx(4.0 + t_max)
    # every path ends at the collision; the pair's 0.1 s later, overlapping (the first touch is the collision)
    ends = {v.id: v.trajectory.t[-1] for v in sc.vehicles()}
    pair = set(sc.collision.participants)
    assert all(t == pytest.approx(4.0 + t_max + (0.1 if i in pair else 0.0)) for i, t in ends.items()), ends


def test_lane_timeline_sets_the_lanes():
    raw = raw_scenario([vehicle(1, track(lambda t: (20 + EGO_SPEED * t, -3.5 + 0 * t), 0, 100))])
    lt = LaneTimeline(t=[0.0, 5.0], lane_index=[1, 1], lateral_offset=[0.0, 0.1])
    raw = raw.model_copy(update={"road": raw.road.model_copy(update={"lane_timeline": lt, "lane_width": 3.2,
                                                                      "lane_count": 3, "ego_lane": 1})})  # fmt: skip
    sc = process_scenario(raw)
    # the seen lines give the width; the lanes are the ones the road users need: the car 3.5 m right of the ego
    # (the lane stage's own lane count and index are relative to where the ego started, not counted lanes)
    assert (sc.road.lane_width, sc.road.lane_count, sc.road.ego_lane, sc.road.oncoming_lane_count) == (3.2, 2, 1, 0)
    t_max = sc.provenance.parameters["t_max_s"]
    assert sc.road.lane_timeline is not None and sc.road.lane_timeline.t == pytest.approx([t_max, 5 + t_max])
    plain = process_scenario(raw_scenario([vehicle(1, track(lambda t: (20 + EGO_SPEED * t, -3.5 + 0 * t), 0, 100))]))
    assert (plain.road.lane_width, plain.road.lane_count, plain.road.ego_lane) == (3.5, 2, 1)


# ---------------------------------------------------------------- bad input
def test_bad_input_raises_user_error():
    ok = raw_scenario([])
    with pytest.raises(UserError, match="already processed"):
        process_scenario(ok.model_copy(update={"stage": "processed"}))
    one = raw_scenario([], ego=track(lambda t: (0 * t, 0 * t), 0, 0))
    with pytest.raises(UserError, match="ego trajectory has 1 sample"):
        process_scenario(one)
    with pytest.raises(UserError, match="fps"):
        process_scenario(ok.model_copy(update={"source": ok.source.model_copy(update={"fps": 0.0})}))
    nan_ego = ok.ego.trajectory.model_copy(update={"x": [float("nan")] + ok.ego.trajectory.x[1:]})
    with pytest.raises(UserError, match="non-finite"):
        process_scenario(ok.model_copy(update={"ego": ok.ego.model_copy(update={"trajectory": nan_ego})}))
    with pytest.raises(UserError, match="outside"):
        process_scenario(head_on_raw(collision=Collision(time_s=50.0, agent_id=1)))
    with pytest.raises(UserError, match="must be > 0"):
        Stage2Params(stepback_accel_mps2=0.0)


def test_short_tracks_dropped_and_static_ego_ok():
    one = vehicle(1, track(lambda t: (30 + 0 * t, 3.5 + 0 * t), 10, 10))
    two = vehicle(2, track(lambda t: (50 + 0 * t, 3.5 + 0 * t), 10, 11))
    sc = process_scenario(raw_scenario([one, two]))
    assert sc.agents == [] and sum("dropped" in w for w in sc.warnings) == 2
    # an ego that never moves: no step-back, a straight default road along its heading
    still = raw_scenario([], ego=track(lambda t: (0 * t, 0 * t), 0, 50, yaw=0.0))
    sc2 = process_scenario(still)
    assert sc2.provenance.parameters["t_max_s"] == 0 and np.all(np.asarray(sc2.ego.trajectory.speed) == 0)


# ---------------------------------------------------------------- CLI and plot
def run(*args: str) -> subprocess.CompletedProcess[str]:
    return subprocess.run([sys.executable, "-m", "deepcrashtest.cli", *args], capture_output=True, text=True,
                          timeout=300)  # fmt: skip


def test_cli_build(tmp_path):
    raw = head_on_raw()
    (tmp_path / "raw.json").write_text(raw.to_json())
    out = tmp_path / "out.json"
    proc = run("scenario", "build", str(tmp_path / "raw.json"), "-o", str(out), "--json")
    assert proc.returncode == 0, proc.stderr
    res = json.loads(proc.stdout)
    assert res["stage"] == "processed" and res["collision"]["agent_id"] == 1 and res["classes"]["D1T2"] == 1
    assert Scenario.load(out).stage == "processed"
    again = run("scenario", "build", str(tmp_path / "raw.json"), "-o", str(out))
    assert again.returncode == 2 and "already exists" in again.stderr and len(again.stderr.strip().splitlines()) == 1
    assert run("scenario", "build", str(tmp_path / "raw.json"), "-o", str(out), "--force").returncode == 0
    # a processed file is refused, NaN / zero fps in the JSON are refused with one line
    proc = run("scenario", "build", str(out), "-o", str(tmp_path / "x.json"))
    assert proc.returncode == 2 and "already processed" in proc.stderr
    data = json.loads(raw.to_json())
    data["source"]["fps"] = 0
    (tmp_path / "fps.json").write_text(json.dumps(data))
    proc = run("scenario", "build", str(tmp_path / "fps.json"), "-o", str(tmp_path / "y.json"))
    assert proc.returncode == 2 and "source.fps" in proc.stderr and len(proc.stderr.strip().splitlines()) == 1
    data = json.loads(raw.to_json())
    data["agents"][0]["trajectory"]["x"][3] = float("nan")
    (tmp_path / "nan.json").write_text(json.dumps(data))
    proc = run("scenario", "build", str(tmp_path / "nan.json"), "-o", str(tmp_path / "z.json"))
    assert proc.returncode == 2 and "NaN" in proc.stderr and len(proc.stderr.strip().splitlines()) == 1


def test_cli_from_kitti_processes_by_default(kitti_root, tmp_path):
    proc = run("scenario", "from-kitti", "--data", str(kitti_root), "--sequence", "3", "-o", str(tmp_path), "--json")
    assert proc.returncode == 0, proc.stderr
    res = json.loads(proc.stdout)
    assert res["stage"] == "processed" and sum(res["classes"].values()) == 9 and "unclassified" not in res["classes"]


def test_plot_birdseye(kitti, tmp_path):
    from deepcrashtest.viz.plots import plot_birdseye

    raw, sc = kitti[3]
    path = plot_birdseye(sc, raw, tmp_path / "b.png")
    data = path.read_bytes()
    assert data[:8] == b"\x89PNG\r\n\x1a\n" and len(data) > 20_000
    with pytest.raises(UserError, match="already exists"):
        plot_birdseye(sc, raw, tmp_path / "b.png")
    assert plot_birdseye(sc, None, tmp_path / "b.png", force=True).exists()


def test_gappy_off_grid_track():
    """A perception track with a 2 s gap and times off the frame grid is bridged and classified."""
    base = track(lambda t: (20 + EGO_SPEED * t, -3.5 + 0 * t), 0, 80)
    keep = [i for i in range(len(base.t)) if not 20 < i < 40]
    a = base.arrays()
    from deepcrashtest.scenario import Trajectory

    gappy = Trajectory.from_arrays(*(a[k][keep] + (0.013 if k == "t" else 0) for k in ("t", "x", "y", "yaw", "speed")))
    sc = process_scenario(raw_scenario([vehicle(1, gappy)]))
    v = sc.vehicle(1)
    assert v.trajectory_class == "D0T1" and sc.collision is None
    t_max = sc.provenance.parameters["t_max_s"]
    assert v.trajectory.state_at(3.013 + t_max)["x"] == pytest.approx(20 + EGO_SPEED * 3.0, abs=0.1)
