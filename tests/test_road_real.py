"""The processed road holds the road users the video shows: lanes on both sides of the ego's lane and the
oncoming lanes, measured on real extractions (the demo highway clip, KITTI, crash clips)."""

from __future__ import annotations

import importlib.util
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from conftest import DATA, KITTI_TRACKING, ROOT, need
from deepcrashtest.geometry.road import boundary_offsets, oncoming_boundary_offsets
from deepcrashtest.scenario import Scenario

pytestmark = pytest.mark.filterwarnings("ignore::DeprecationWarning")  # commonroad's protobuf modules
SAMPLE = ROOT / "examples" / "highway_sample.mp4"


def _bench() -> Any:
    """bench/road_coverage.py (its selection of the vehicles moving along the road)."""
    spec = importlib.util.spec_from_file_location("road_coverage", ROOT / "bench" / "road_coverage.py")
    assert spec is not None and spec.loader is not None
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def _moving_along(sc: Scenario) -> dict[int, tuple[float, bool]]:
    """{agent id: (median lateral offset m of its seen positions, oncoming)} of the vehicles moving along the
    road (bench/road_coverage.py)."""
    return dict(_bench().moving_along(sc))


def _off_road(sc: Scenario) -> list[tuple[int, float]]:
    """(id, offset m) of the vehicles moving along the road whose median offset lies outside its lanes of
    their direction (the ego's carriageway, or the oncoming lanes)."""
    own, other = boundary_offsets(sc.road), oncoming_boundary_offsets(sc.road)
    bad = []
    for i, (d, oncoming) in _moving_along(sc).items():
        lanes = other if oncoming and len(other) else own
        if not min(lanes) <= d <= max(lanes):
            bad.append((i, round(d, 1)))
    return bad


@pytest.fixture(scope="module")
def demo(tmp_path_factory: pytest.TempPathFactory) -> Scenario:
    """The processed scenario of the demo clip (8 s of the Udacity highway video, lanes seen): the ego drives in
    the leftmost lane of a divided motorway (yellow line on its left, lanes and a car to its right), oncoming
    cars pass on the far carriageway behind the barrier and the grass."""
    from deepcrashtest.pipeline.extract import run_extract
    from deepcrashtest.trajectory.pipeline import process_scenario

    out: Path = tmp_path_factory.mktemp("demo_road")
    run_extract(need(SAMPLE), out, report=False, annotate=False)
    return process_scenario(Scenario.load(out / "scenario_raw.json"), seed=0)


def test_demo_road_holds_its_road_users_on_both_sides(demo):
    """On main (schema 1.2) the road was 2 lanes with the ego in the rightmost: the car 8.5 m to the right and
    the four oncoming cars 13-28 m to the left drove off the road (in the grass of the bird's-eye view)."""
    road, users = demo.road, _moving_along(demo)
    assert road.lane_timeline is not None and road.source == "ego_path"  # lane lines seen: they give the width
    assert sum(o for _, o in users.values()) >= 3 and sum(not o for _, o in users.values()) >= 1
    assert _off_road(demo) == []
    assert road.ego_lane == road.lane_count - 1 >= 2  # the leftmost lane, at least two lanes to its right
    assert road.oncoming_lane_count >= 2 and road.median_width >= road.lane_width  # a divided motorway


def test_demo_oncoming_lanes_in_opendrive_and_commonroad(demo, tmp_path):
    """The oncoming lanes are exported: OpenDRIVE left lanes (positive ids, a median lane first) that pass the
    schema and the ASAM checkers; CommonRoad lanelets running the opposite way that hold the oncoming cars."""
    import shapely
    from commonroad.common.file_reader import CommonRoadFileReader
    from pyxodr.road_objects.network import RoadNetwork

    from deepcrashtest.export import export_scenario
    from export_helpers import qc_available, run_qc

    export_scenario(demo, "openscenario", tmp_path)
    export_scenario(demo, "commonroad", tmp_path)
    road = demo.road
    xroad = RoadNetwork(str(tmp_path / "road.xodr"), resolution=0.5).get_roads()[0]
    ids = sorted(lane.id for section in xroad.lane_sections for lane in section.lanes)
    assert ids == [*range(-road.lane_count, 0), *range(1, road.oncoming_lane_count + 2)]  # + the median lane 1
    if qc_available():
        report = run_qc("xodr", tmp_path / "road.xodr", tmp_path / "qc")
        assert report["errors"] == [] and report["warnings"] == []
    cr, _ = CommonRoadFileReader(str(tmp_path / "commonroad.xml")).open()
    lanelets = {lanelet.lanelet_id: lanelet for lanelet in cr.lanelet_network.lanelets}
    assert len(lanelets) == road.lane_count + road.oncoming_lane_count
    tangent = road.centerline()[-1] - road.centerline()[0]
    for i, lanelet in lanelets.items():
        along = float((lanelet.center_vertices[-1] - lanelet.center_vertices[0]) @ tangent)
        assert (along < 0) == (i > road.lane_count)  # the oncoming lanelets run the other way
    oncoming = [lanelet.polygon.shapely_object for i, lanelet in lanelets.items() if i > road.lane_count]
    for v in demo.agents:
        if v.id in _moving_along(demo) and _moving_along(demo)[v.id][1]:
            seen = np.flatnonzero(np.asarray(v.trajectory.observed, bool))
            k = int(seen[len(seen) // 4])  # a quarter of the way through what the video showed
            point = shapely.Point(v.trajectory.x[k], v.trajectory.y[k])
            assert any(p.buffer(1.0).contains(point) for p in oncoming), v.id


def test_demo_birdseye_draws_the_oncoming_lanes(demo, tmp_path):
    """The bird's-eye view draws the oncoming carriageway: road surface where the oncoming cars drive and the
    solid yellow lines between the directions."""
    from deepcrashtest.sim import simulate
    from deepcrashtest.viz import birdseye

    res = simulate(demo, controller="replay")
    oncoming = [i for i, (_, o) in _moving_along(demo).items() if o]
    col = {vid: i for i, vid in enumerate(res.vehicle_ids)}
    k = int(np.argmax(res.present[:, [col[i] for i in oncoming]].sum(axis=1)))
    frames = birdseye.render_frames(demo, res, stride=max(k, 1))
    frame = [next(frames) for _ in range(2 if k else 1)][-1]
    yellow = np.all(np.abs(frame.astype(int) - birdseye.DIRECTIONS) <= 30, axis=2)
    assert yellow.sum() > 500


def test_birdseye_marks_each_vehicles_front(demo):
    """A box fits a vehicle both ways round: the bird's-eye view draws each vehicle's front edge dark, so a car
    facing against its path (or turned half round) shows. Checked on the ego of the demo's replay, just inside its
    front and its rear edge."""
    from deepcrashtest.sim import simulate
    from deepcrashtest.viz import birdseye

    res = simulate(demo, controller="replay")
    frame = next(birdseye.render_frames(demo, res)).astype(float).mean(axis=2)
    x, y, yaw, _ = res.states[0, 0]
    view = birdseye._View(np.array([x + birdseye.AHEAD_M * np.cos(yaw), y + birdseye.AHEAD_M * np.sin(yaw)]))
    pts = view.px(birdseye._box(x, y, yaw, demo.ego.length, demo.ego.width)).astype(float)
    front, rear = (pts[0] + pts[3]) / 2, (pts[1] + pts[2]) / 2
    axis = (front - rear) / np.linalg.norm(front - rear)

    def shade(p: np.ndarray) -> float:
        c, r = np.round(p).astype(int)
        return float(frame[r - 1 : r + 2, c - 1 : c + 2].mean())

    assert shade(front - 1.5 * axis) < shade(rear + 1.5 * axis) - 40


@pytest.mark.parametrize("seq", [9])
def test_kitti_oncoming_cars_drive_on_the_oncoming_lanes(seq):
    """KITTI training sequences from labels (no lane lines: the road is inferred from the road users): the
    oncoming cars across the median are on the oncoming lanes; on main (one direction only, offsets beyond 12 m
    ignored) they were off the road."""
    from deepcrashtest.datasets.kitti.scenario import scenario_from_kitti
    from deepcrashtest.trajectory.pipeline import process_scenario

    sc = process_scenario(scenario_from_kitti(need(KITTI_TRACKING), seq, road_users=True), seed=0)
    users = _moving_along(sc)
    assert any(o for _, o in users.values())
    assert _off_road(sc) == []
    assert sc.road.oncoming_lane_count >= 1


def test_crash_clip_oncoming_cars_beyond_the_median(tmp_path):
    """ccd_000330 (no lane lines seen: the road is inferred): the ego moves slowly while oncoming cars pass
    9-14 m to its left; on main (one direction, offsets beyond 12 m ignored) two of the three were off the road."""
    from deepcrashtest.pipeline.extract import run_extract
    from deepcrashtest.trajectory.pipeline import process_scenario

    run_extract(need(DATA / "crash_ccd" / "ccd_000330.mp4"), tmp_path, report=False, annotate=False)
    sc = process_scenario(Scenario.load(tmp_path / "scenario_raw.json"), seed=0)
    assert sc.road.source == "road_users" and any("no lane lines seen" in w for w in sc.warnings)
    assert sum(o for _, o in _moving_along(sc).values()) >= 2
    assert _off_road(sc) == []
    assert sc.road.oncoming_lane_count >= 1


def _mirrored(sc: Scenario) -> Scenario:
    """``sc`` seen in a mirror about the ego's direction of travel (world y -> -y, headings negated): a real
    right-hand-traffic scene as the same scene in left-hand traffic (no lane lines: none to mirror)."""
    d = sc.model_dump()
    for v in [d["ego"], *d["agents"]]:
        tr = v["trajectory"]
        tr["y"] = [-y for y in tr["y"]]
        tr["yaw"] = [-a for a in tr["yaw"]]
        v["spline"] = None
    d["road"]["centerline_y"] = [-y for y in d["road"]["centerline_y"]]
    assert d["road"]["lane_timeline"] is None and d["collision"] is None
    return Scenario.model_validate(d)


@pytest.fixture(scope="module")
def kitti9_left() -> tuple[Scenario, Scenario, Scenario]:
    """KITTI 9 from labels (a road with oncoming cars across a median, right-hand traffic), processed as it is,
    and mirrored into left-hand traffic processed with ``driving_side`` left and (wrongly) right."""
    from deepcrashtest.datasets.kitti.scenario import scenario_from_kitti
    from deepcrashtest.trajectory.params import Stage2Params
    from deepcrashtest.trajectory.pipeline import process_scenario

    raw = scenario_from_kitti(need(KITTI_TRACKING), 9, road_users=True)
    left = Stage2Params(driving_side="left")
    return (
        process_scenario(raw, seed=0),
        process_scenario(_mirrored(raw), seed=0, params=left),
        process_scenario(_mirrored(raw), seed=0),
    )


def test_left_hand_traffic_puts_the_oncoming_lanes_right_of_the_ego(kitti9_left):
    """The mirrored scene with ``driving_side`` left gets the mirrored road: the same lanes, the ego's lane
    counted from the other side, the oncoming lanes on its right holding the oncoming cars. Read as right-hand
    traffic (all a road could be before) the road had no oncoming lanes and the oncoming cars across the median
    drove off it."""
    rht, lht, wrong = (sc.road for sc in kitti9_left)
    assert lht.driving_side == "left" and rht.driving_side == "right"
    assert (lht.lane_count, lht.oncoming_lane_count, lht.lane_width, lht.median_width) == (
        rht.lane_count,
        rht.oncoming_lane_count,
        rht.lane_width,
        rht.median_width,
    )
    assert lht.ego_lane == rht.lane_count - 1 - rht.ego_lane
    assert np.allclose(oncoming_boundary_offsets(lht), -oncoming_boundary_offsets(rht))
    assert np.all(oncoming_boundary_offsets(lht) < boundary_offsets(lht)[0] + 1e-9)  # right of the carriageway
    assert _off_road(kitti9_left[1]) == []
    assert wrong.oncoming_lane_count == 0 and _off_road(kitti9_left[2]) != []  # oncoming cars in the grass


def test_left_hand_traffic_exports(kitti9_left, tmp_path):
    """OpenDRIVE: rule LHT, the ego's carriageway as left lanes (positive ids, the reference line's direction
    under LHT) and the oncoming lanes as right lanes, valid for the schema and the ASAM checkers; CommonRoad: the
    oncoming lanelets run the other way right of the ego's and hold the oncoming cars."""
    import shapely
    from commonroad.common.file_reader import CommonRoadFileReader
    from lxml import etree
    from pyxodr.road_objects.network import RoadNetwork

    from deepcrashtest.export import export_scenario
    from export_helpers import qc_available, run_qc

    sc = kitti9_left[1]
    export_scenario(sc, "openscenario", tmp_path)
    export_scenario(sc, "commonroad", tmp_path)
    road = sc.road
    assert etree.parse(str(tmp_path / "road.xodr")).find("road").get("rule") == "LHT"
    xroad = RoadNetwork(str(tmp_path / "road.xodr"), resolution=0.5).get_roads()[0]
    ids = sorted(lane.id for section in xroad.lane_sections for lane in section.lanes)
    median = 1 if road.median_width > 0 else 0
    assert ids == [*range(-road.oncoming_lane_count - median, 0), *range(1, road.lane_count + 1)]
    if qc_available():
        report = run_qc("xodr", tmp_path / "road.xodr", tmp_path / "qc")
        assert report["errors"] == [] and report["warnings"] == []
    cr, _ = CommonRoadFileReader(str(tmp_path / "commonroad.xml")).open()
    lanelets = {lanelet.lanelet_id: lanelet for lanelet in cr.lanelet_network.lanelets}
    tangent = road.centerline()[-1] - road.centerline()[0]
    normal = np.array([-tangent[1], tangent[0]])
    for i, lanelet in lanelets.items():
        along = float((lanelet.center_vertices[-1] - lanelet.center_vertices[0]) @ tangent)
        assert (along < 0) == (i > road.lane_count)
    own_right = min(
        float(np.mean(lanelets[1].right_vertices @ normal)), float(np.mean(lanelets[1].left_vertices @ normal))
    )
    oncoming = {i: lanelet for i, lanelet in lanelets.items() if i > road.lane_count}
    assert all(float(np.mean(lanelet.center_vertices @ normal)) < own_right for lanelet in oncoming.values())
    users = _moving_along(sc)
    for v in sc.agents:
        if v.id in users and users[v.id][1]:
            seen = np.flatnonzero(np.asarray(v.trajectory.observed, bool))
            k = int(seen[len(seen) // 4])
            point = shapely.Point(v.trajectory.x[k], v.trajectory.y[k])
            assert any(lanelet.polygon.shapely_object.buffer(1.0).contains(point) for lanelet in oncoming.values())


def test_left_hand_traffic_birdseye_divider(kitti9_left):
    """The bird's-eye view draws the solid yellow line between the directions on the ego carriageway's right
    edge in left-hand traffic (left of the ego in the mirrored road: none would be drawn there)."""
    from deepcrashtest.sim import simulate
    from deepcrashtest.viz import birdseye

    sc = kitti9_left[1]
    frame = next(birdseye.render_frames(sc, simulate(sc, controller="replay"), stride=1))
    yellow = np.all(np.abs(frame.astype(int) - birdseye.DIRECTIONS) <= 30, axis=2)
    rows = np.flatnonzero(yellow.any(axis=1))
    assert yellow.sum() > 500
    assert rows.mean() > frame.shape[0] / 2  # world y right of the ego is down in the view
