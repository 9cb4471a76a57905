"""CommonRoad and CSV exports of real KITTI scenarios, and the ``export`` command.

The crash check. KITTI ground truth has no crash (Scenario.collision is None), so
``crash_scenario`` makes one from real trajectories: in KITTI 0008 the oncoming car (track 17,
agent id 18, seen 21.0-23.3 s) is shifted, as a whole, so that at MEET_T_S = 22.5 s its centre
is straight ahead of the ego's centre by half their lengths minus 0.3 m: a head-on crash. The
first contact time is computed independently with shapely (box polygons every 5 ms) and stored
as Scenario.collision; the CommonRoad drivability checker must find the ego colliding from the
same time step (within one step), and never without that agent.
"""

from __future__ import annotations

import copy
import json
import math

import numpy as np
import pandas as pd
import pytest
import shapely

from conftest import KITTI_TRACKING, need
from deepcrashtest.cli import main
from deepcrashtest.export import export_scenario
from deepcrashtest.export.commonroad import (
    COMMONROAD_DT_S,
    GOAL_AHEAD_M,
    OBSTACLE_ID_BASE,
    crash_point,
    ego_collision_steps,
    resample,
)
from deepcrashtest.export.csv import COLUMNS
from deepcrashtest.scenario import Collision, Scenario, Trajectory, Vehicle

pytestmark = pytest.mark.filterwarnings("ignore::DeprecationWarning")  # commonroad's protobuf modules

MEET_AGENT_ID = 18
MEET_T_S = 22.5


def _read_cr(path):
    from commonroad.common.file_reader import CommonRoadFileReader

    return CommonRoadFileReader(str(path)).open()


def _box(v: Vehicle, t: float) -> shapely.Polygon:
    s = v.trajectory.state_at(t)
    c, sn = math.cos(s["yaw"]), math.sin(s["yaw"])
    hl, hw = v.length / 2, v.width / 2
    pts = [
        (s["x"] + c * dx - sn * dy, s["y"] + sn * dx + c * dy)
        for dx, dy in ((hl, hw), (-hl, hw), (-hl, -hw), (hl, -hw))
    ]
    return shapely.Polygon(pts)


def first_contact_s(ego: Vehicle, agent: Vehicle, step: float = 0.005) -> float | None:
    """First time (s) the two boxes intersect, on a ``step`` grid over their common span."""
    t0 = max(ego.trajectory.t[0], agent.trajectory.t[0])
    t1 = min(ego.trajectory.t[-1], agent.trajectory.t[-1])
    for t in np.arange(t0, t1 + 1e-9, step):
        if _box(ego, t).intersects(_box(agent, t)):
            return float(t)
    return None


def make_crash_scenario(kitti8: Scenario) -> Scenario:
    """KITTI 0008 with agent MEET_AGENT_ID shifted into a head-on crash (see the module doc)."""
    sc = copy.deepcopy(kitti8)
    agent = sc.vehicle(MEET_AGENT_ID)
    e = sc.ego.trajectory.state_at(MEET_T_S)
    a = agent.trajectory.state_at(MEET_T_S)
    gap = (sc.ego.length + agent.length) / 2 - 0.3
    target = np.array([e["x"], e["y"]]) + gap * np.array([math.cos(e["yaw"]), math.sin(e["yaw"])])
    d = target - np.array([a["x"], a["y"]])
    arr = agent.trajectory.arrays()
    agent.trajectory = Trajectory.from_arrays(
        arr["t"], arr["x"] + d[0], arr["y"] + d[1], arr["yaw"], arr["speed"], agent.trajectory.observed
    )
    t_hit = first_contact_s(sc.ego, agent)
    assert t_hit is not None and MEET_T_S - 0.5 < t_hit <= MEET_T_S
    others = [first_contact_s(sc.ego, v) for v in sc.agents if v.id != MEET_AGENT_ID]
    assert all(t is None for t in others), "real KITTI agents must not touch the ego"
    sc.collision = Collision(time_s=t_hit, agent_id=MEET_AGENT_ID, other_id=sc.ego.id)
    return sc


@pytest.fixture(scope="module")
def crash_scenario(kitti8_raw) -> Scenario:
    return make_crash_scenario(kitti8_raw)


@pytest.mark.parametrize("seq", [3, 8, 10])
def test_commonroad_reloads_with_resampled_agents(seq, tmp_path):
    from deepcrashtest.datasets.kitti.scenario import scenario_from_kitti

    sc = scenario_from_kitti(need(KITTI_TRACKING), seq)
    res = export_scenario(sc, "commonroad", tmp_path)
    cr, pps = _read_cr(tmp_path / "commonroad.xml")
    assert cr.dt == pytest.approx(COMMONROAD_DT_S)
    assert len(cr.lanelet_network.lanelets) == sc.road.lane_count + sc.road.oncoming_lane_count
    kept = [a for a in sc.agents if a.id not in res["agents_left_out"]]
    assert {o.obstacle_id for o in cr.dynamic_obstacles} == {OBSTACLE_ID_BASE + a.id for a in kept}
    assert all(len(resample(sc.vehicle(i))["step"]) < 2 for i in res["agents_left_out"])
    worst = 0.0
    for agent in kept:
        obs = cr.obstacle_by_id(OBSTACLE_ID_BASE + agent.id)
        states = [obs.initial_state, *obs.prediction.trajectory.state_list]
        for st in states:
            ref = agent.trajectory.state_at(st.time_step * cr.dt)
            worst = max(worst, math.hypot(st.position[0] - ref["x"], st.position[1] - ref["y"]))
        assert obs.obstacle_shape.length == pytest.approx(agent.length, abs=1e-3)
    assert worst < 1e-3, f"obstacle position error {worst:.5f} m"
    (pp,) = pps.planning_problem_dict.values()
    assert pp.initial_state.time_step == 0
    assert np.allclose(pp.initial_state.position, [sc.ego.trajectory.x[0], sc.ego.trajectory.y[0]], atol=1e-3)
    # the ego's own recorded path never touches a real KITTI agent
    assert ego_collision_steps(cr, sc.ego) == []


def test_commonroad_crash_found_by_drivability_checker(crash_scenario, tmp_path):
    sc = crash_scenario
    export_scenario(sc, "commonroad", tmp_path)
    cr, pps = _read_cr(tmp_path / "commonroad.xml")
    hits = ego_collision_steps(cr, sc.ego)
    assert hits, "the drivability checker finds no collision"
    assert abs(hits[0] * cr.dt - sc.collision.time_s) <= cr.dt + 1e-9, (hits[0], sc.collision.time_s)
    cr.remove_obstacle(cr.obstacle_by_id(OBSTACLE_ID_BASE + MEET_AGENT_ID))
    assert ego_collision_steps(cr, sc.ego) == []  # the crash is with that agent only
    # goal region: past the crash point along the ego's heading, not at the crash itself
    (pp,) = pps.planning_problem_dict.values()
    xy, hdg, _ = crash_point(sc)
    goal_shape = pp.goal.state_list[0].position
    ahead = xy + GOAL_AHEAD_M * np.array([math.cos(hdg), math.sin(hdg)])
    assert goal_shape.contains_point(ahead) and not goal_shape.contains_point(xy)
    assert pp.goal.state_list[0].time_step.start * cr.dt > sc.collision.time_s


# --------------------------------------------------------------------------- CSV
def test_csv_rows_columns_values(kitti8_raw, tmp_path):
    sc = kitti8_raw
    res = export_scenario(sc, "csv", tmp_path)
    df = pd.read_csv(tmp_path / "trajectories.csv")
    assert tuple(df.columns) == COLUMNS
    assert len(df) == res["rows"] == sum(len(v.trajectory) for v in sc.vehicles())
    assert (df["role"] == "ego").sum() == len(sc.ego.trajectory)
    assert df["t_s"].is_monotonic_increasing
    for veh in (sc.ego, sc.vehicle(MEET_AGENT_ID)):
        rows = df[df["vehicle_id"] == veh.id]
        a = veh.trajectory.arrays()
        for col, key in (("t_s", "t"), ("x_m", "x"), ("y_m", "y"), ("yaw_rad", "yaw"), ("speed_mps", "speed")):
            assert np.allclose(rows[col].to_numpy(), a[key], atol=1e-5), col
        assert (rows["category"] == veh.category).all() and (rows["length_m"] == veh.length).all()


# --------------------------------------------------------------------------- command line
def test_cli_export_all_formats(kitti8_raw, tmp_path, capsys):
    path = kitti8_raw.save(tmp_path / "scenario.json")
    out = tmp_path / "out"
    for fmt in ("openscenario", "commonroad", "csv"):
        assert main(["export", str(path), "--format", fmt, "-o", str(out), "--json"]) == 0
        res = json.loads(capsys.readouterr().out)
        assert res["format"] == fmt and all((out / p).exists() for p in map(str, res["files"]))
    assert sorted(p.name for p in out.iterdir()) == ["commonroad.xml", "road.xodr", "scenario.xosc", "trajectories.csv"]
    # nothing is overwritten without --force; with it, it is
    assert main(["export", str(path), "--format", "openscenario", "-o", str(out)]) == 2
    assert "already exists" in capsys.readouterr().err
    assert main(["export", str(path), "--format", "openscenario", "-o", str(out), "--ego-free", "--force"]) == 0
    capsys.readouterr()
    assert main(["export", str(path), "--format", "csv", "-o", str(out), "--ego-free", "--force"]) == 2
    assert main(["export", str(path), "--format", "gltf", "-o", str(out)]) == 2
    assert "--format must be one of" in capsys.readouterr().err
