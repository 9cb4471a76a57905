"""Exports of real KITTI-derived scenarios, checked by the official schemas, checkers and readers.

* .xodr / .xosc: the XSDs shipped inside scenariogeneration (xmlschema) and the ASAM Quality
  Checkers (own environment .venv-qc, ``make qc-setup``); the reference line re-read by pyxodr
  passes through the road waypoints; the .xosc polylines replayed by an independent reader
  (tests/export_helpers.py) reproduce every vehicle's positions.
* Sequences 0003, 0008, 0010 (raw, and processed when the stage-2 pipeline is present).
"""

from __future__ import annotations

import copy
import math
from pathlib import Path

import numpy as np
import pytest
import shapely
from lxml import etree

from conftest import KITTI_TRACKING, need
from deepcrashtest.errors import UserError
from deepcrashtest.export import export_scenario
from deepcrashtest.export.opendrive import opendrive_lane_id, reference_line
from deepcrashtest.export.openscenario import EGO_NAME, entity_name, entry_time, write_parameter_distribution
from deepcrashtest.geometry.road import boundary_offsets
from deepcrashtest.scenario import Road, Scenario
from export_helpers import qc_available, read_xosc, run_qc

pytestmark = pytest.mark.filterwarnings("ignore::DeprecationWarning")  # commonroad's protobuf modules

SEQUENCES = (3, 8, 10)
POS_TOL_M = 0.05


def _schema_dir() -> Path:
    import scenariogeneration

    return Path(scenariogeneration.__file__).resolve().parents[1] / "schemas"


@pytest.fixture(scope="session")
def xsd():
    import xmlschema

    d = _schema_dir()
    return {
        "xosc": xmlschema.XMLSchema(str(d / "OpenSCENARIO_1_2.xsd")),
        "xodr": xmlschema.XMLSchema(str(d / "opendrive_17_core.xsd")),
    }


def _scenario(seq: int, stage: str) -> Scenario:
    from deepcrashtest.datasets.kitti.scenario import scenario_from_kitti

    sc = scenario_from_kitti(need(KITTI_TRACKING), seq)
    if stage == "processed":
        try:
            from deepcrashtest.trajectory.pipeline import process_scenario  # type: ignore[import-not-found]
        except ImportError:
            pytest.skip("stage-2 pipeline (deepcrashtest.trajectory.pipeline) not in this build")
        sc = process_scenario(sc, seed=0)
    return sc


_CACHE: dict[tuple[int, str], tuple[Scenario, Path]] = {}


CASES = [(s, st) for st in ("raw", "processed") for s in SEQUENCES]


@pytest.fixture(scope="session", params=CASES, ids=lambda p: f"{p[0]:04d}-{p[1]}")
def exported(request, tmp_path_factory):
    """(Scenario, folder) with scenario.xosc, road.xodr, commonroad.xml, trajectories.csv."""
    key = request.param
    if key not in _CACHE:
        sc = _scenario(*key)
        out = tmp_path_factory.mktemp(f"export_{key[0]:04d}_{key[1]}")
        for fmt in ("openscenario", "commonroad", "csv"):
            export_scenario(sc, fmt, out)
        _CACHE[key] = (sc, out)
    return _CACHE[key]


# --------------------------------------------------------------------------- schemas
def test_xodr_and_xosc_are_schema_valid(exported, xsd):
    sc, out = exported
    xsd["xodr"].validate(str(out / "road.xodr"))
    xsd["xosc"].validate(str(out / "scenario.xosc"))
    header = etree.parse(str(out / "road.xodr")).getroot().find("header")
    assert (header.get("revMajor"), header.get("revMinor")) == ("1", "7")
    elev = etree.parse(str(out / "road.xodr")).getroot().findall("road/elevationProfile/elevation")
    assert len(elev) == 1 and all(elev[0].get(k) == "0.0" for k in "abcd")


# --------------------------------------------------------------------------- OpenDRIVE geometry
def test_reference_line_passes_through_waypoints_pyxodr(exported):
    """pyxodr (an independent OpenDRIVE reader) samples the line; every waypoint lies on it."""
    from pyxodr.road_objects.network import RoadNetwork

    sc, out = exported
    road = RoadNetwork(str(out / "road.xodr"), resolution=0.05).get_roads()[0]
    line = shapely.LineString(road.reference_line)
    dev = [line.distance(shapely.Point(p)) for p in sc.road.centerline()]
    assert max(dev) < POS_TOL_M, f"max waypoint deviation {max(dev):.4f} m"
    # the lane the road came from (ego_path roads: the ego's lane) is centred on the waypoints
    lanes = {lane.id: lane for section in road.lane_sections for lane in section.lanes}
    left = sc.road.oncoming_lane_count + (1 if sc.road.oncoming_lane_count and sc.road.median_width else 0)
    right = [opendrive_lane_id(k, sc.road.lane_count) for k in range(sc.road.lane_count)]
    assert sorted(lanes) == sorted(right + list(range(1, left + 1)))  # the oncoming lanes: left lanes 1..
    ego_lane = lanes[opendrive_lane_id(sc.road.ego_lane, sc.road.lane_count)]
    centre = shapely.LineString(np.asarray(ego_lane.centre_line)[:, :2])
    lane_dev = max(centre.distance(shapely.Point(p)) for p in sc.road.centerline())
    assert lane_dev < POS_TOL_M
    widths = np.diff(boundary_offsets(sc.road))
    assert np.allclose(widths, sc.road.lane_width)


def test_kitti_roads_curve():
    """0008 and 0010 are curved roads: the heading of their reference line turns by > 10 degrees."""
    from deepcrashtest.datasets.kitti.scenario import scenario_from_kitti

    for seq in (8, 10):
        sc = scenario_from_kitti(need(KITTI_TRACKING), seq)
        hdg = np.unwrap([seg.hdg for seg in reference_line(sc.road)])
        assert hdg.max() - hdg.min() > math.radians(10), (seq, math.degrees(hdg.max() - hdg.min()))


# --------------------------------------------------------------------------- ASAM Quality Checkers
@pytest.fixture(scope="session")
def qc():
    if not qc_available():
        pytest.skip("ASAM Quality Checkers not installed: run `make qc-setup` (creates .venv-qc)")
    return run_qc


def _assert_clean(report: dict, schema_checker: str) -> None:
    assert report["errors"] == [], report["errors"][:5]
    bad = {k: v for k, v in report["checkers"].items() if v == "error"}
    assert not bad, f"checker(s) crashed: {bad}"
    assert report["checkers"][schema_checker] == "completed"  # the schema check really ran


def test_asam_qc_opendrive_and_openscenario(exported, qc, tmp_path):
    sc, out = exported
    r_xodr = qc("xodr", out / "road.xodr", tmp_path)
    _assert_clean(r_xodr, "check_asam_xodr_xml_valid_schema")
    r_xosc = qc("xosc", out / "scenario.xosc", tmp_path)
    _assert_clean(r_xosc, "check_asam_xosc_xml_valid_schema")
    assert r_xodr["warnings"] == [] and r_xosc["warnings"] == []


def test_asam_qc_reports_a_broken_file(exported, qc, tmp_path):
    """Control: the harness fails on an error-level issue (an invalid rule and a negative width)."""
    sc, out = exported
    bad_xosc = tmp_path / "scenario.xosc"
    bad_xosc.write_text((out / "scenario.xosc").read_text().replace("greaterOrEqual", "atLeast"))
    (tmp_path / "road.xodr").write_text((out / "road.xodr").read_text())
    assert qc("xosc", bad_xosc, tmp_path / "r1")["errors"]
    bad_xodr = tmp_path / "bad.xodr"
    bad_xodr.write_text((out / "road.xodr").read_text().replace('revMinor="7"', 'revMinor="seven"'))
    assert qc("xodr", bad_xodr, tmp_path / "r2")["errors"]


# --------------------------------------------------------------------------- OpenSCENARIO replay
def _replay_error(sc: Scenario, xosc_path: Path) -> float:
    """Max distance (m) between the replayed polylines and the Scenario at its samples; checks triggers."""
    ents = read_xosc(xosc_path)
    assert set(ents) == {entity_name(v, sc.ego.id) for v in sc.vehicles()}
    worst = 0.0
    for veh in sc.vehicles():
        ent = ents[entity_name(veh, sc.ego.id)]
        t_enter = entry_time(veh)
        if veh.id != sc.ego.id and t_enter > 0:
            assert ent.deleted_at_init and ent.added_at is not None and ent.init_teleport is None
        else:
            assert ent.init_teleport is not None and not ent.deleted_at_init
        a = veh.trajectory.arrays()
        keep = a["t"] >= t_enter - 1e-9
        if ent.times.size < 2:
            assert keep.sum() < 2
            continue
        assert ent.start_rule == "greaterOrEqual"
        assert ent.start_trigger == pytest.approx(t_enter)
        assert ent.times[0] == pytest.approx(t_enter)
        got = ent.centre_at(a["t"][keep])
        err = np.hypot(got[:, 0] - a["x"][keep], got[:, 1] - a["y"][keep])
        worst = max(worst, float(err.max()))
    return worst


def test_xosc_replay_matches_scenario(exported):
    """Every vehicle's polyline, replayed by time, is within 5 cm of the Scenario at every sample."""
    sc, out = exported
    worst = _replay_error(sc, out / "scenario.xosc")
    assert worst < POS_TOL_M, f"max replay position error {worst:.4f} m"


def test_xosc_replay_off_grid_times_and_start_delays(kitti8_raw, tmp_path, xsd):
    """Trajectories on a 30 Hz grid and start delays between samples (as stage 2 may produce)."""
    sc = copy.deepcopy(kitti8_raw)
    for veh in sc.vehicles():
        a = veh.trajectory.arrays()
        t = np.arange(a["t"][0], a["t"][-1] + 1e-9, 1 / 30)
        if len(t) < 2:
            continue
        veh.trajectory = type(veh.trajectory).from_arrays(
            t, *(np.interp(t, a["t"], a[k]) for k in ("x", "y", "yaw", "speed"))
        )
        if veh.id != sc.ego.id and t[-1] - t[0] > 0.2:
            veh.start_delay_s = float(t[0] + 0.05)  # between two samples
    export_scenario(sc, "openscenario", tmp_path)
    xsd["xosc"].validate(str(tmp_path / "scenario.xosc"))
    assert _replay_error(sc, tmp_path / "scenario.xosc") < POS_TOL_M


def test_xosc_ego_start_parameters_shift_the_ego(exported):
    sc, out = exported
    ents = read_xosc(out / "scenario.xosc")
    base = ents[EGO_NAME]
    moved = read_xosc(out / "scenario.xosc", {"EgoStartDx": 1.5, "EgoStartDy": -0.75})[EGO_NAME]
    d = moved.ref_xyh[:, :2] - base.ref_xyh[:, :2]
    assert np.allclose(d, [1.5, -0.75], atol=1e-6)
    assert np.allclose(np.subtract(moved.init_teleport[:2], base.init_teleport[:2]), [1.5, -0.75], atol=1e-6)
    agent = next(n for n, e in ents.items() if n != EGO_NAME and e.times.size)  # agents stay put
    assert np.array_equal(read_xosc(out / "scenario.xosc", {"EgoStartDx": 3.0})[agent].ref_xyh, ents[agent].ref_xyh)


def test_ego_free_leaves_the_ego_without_trajectory(exported, tmp_path, xsd):
    sc, _ = exported
    res = export_scenario(sc, "openscenario", tmp_path, ego_free=True)
    assert res["ego_free"] is True
    xsd["xosc"].validate(str(tmp_path / "scenario.xosc"))
    ents = read_xosc(tmp_path / "scenario.xosc")
    assert ents[EGO_NAME].times.size == 0 and ents[EGO_NAME].init_teleport is not None
    x0, y0 = sc.ego.trajectory.x[0], sc.ego.trajectory.y[0]
    got = ents[EGO_NAME]
    h = got.init_teleport[2]
    centre = (got.init_teleport[0] + got.center_x * math.cos(h), got.init_teleport[1] + got.center_x * math.sin(h))
    assert math.hypot(centre[0] - x0, centre[1] - y0) < 1e-4
    assert sum(e.times.size > 0 for e in ents.values()) == sum(len(a.trajectory) > 1 for a in sc.agents)


# --------------------------------------------------------------------------- parameter distribution
def test_parameter_distribution_file(exported, tmp_path, xsd, qc):
    sc, out = exported
    variants = [{"EgoStartDx": 1.25, "EgoStartDy": -0.5}, {"EgoStartDx": -2.0, "EgoStartDy": 0.0}]
    path = write_parameter_distribution(out / "scenario.xosc", variants, tmp_path / "variants.xosc")
    xsd["xosc"].validate(str(path))
    root = etree.parse(str(path)).getroot()
    ref = root.find("ParameterValueDistribution/ScenarioFile").get("filepath")
    assert (path.parent / ref).resolve() == (out / "scenario.xosc").resolve()
    sets = root.findall(".//ParameterValueSet")
    got = [{a.get("parameterRef"): float(a.get("value")) for a in s.findall("ParameterAssignment")} for s in sets]
    assert got == variants
    report = qc("xosc", path, tmp_path / "qc")
    assert report["errors"] == []
    with pytest.raises(UserError, match="does not declare"):
        write_parameter_distribution(out / "scenario.xosc", [{"EgoSpeed": 3.0}], tmp_path / "v2.xosc")
    with pytest.raises(UserError, match="already exists"):
        write_parameter_distribution(out / "scenario.xosc", variants, path)


# --------------------------------------------------------------------------- a tight synthetic curve
@pytest.mark.parametrize("oncoming", [0, 2])
def test_tight_curve_road(tmp_path, kitti8_raw, xsd, qc, oncoming):
    """A 90-degree bend of radius 25 m with three lanes (and two oncoming ones beside them, without a median):
    waypoints on the line, checkers clean."""
    from pyxodr.road_objects.network import RoadNetwork

    ang = np.linspace(0.0, math.pi / 2, 40)
    road = Road(
        centerline_x=(25.0 * np.sin(ang)).tolist(),
        centerline_y=(25.0 * (1 - np.cos(ang))).tolist(),
        lane_count=3,
        ego_lane=1,
        lane_width=3.25,
        oncoming_lane_count=oncoming,
        source="lanes",
    )
    curved = copy.deepcopy(kitti8_raw)
    curved.road = road
    export_scenario(curved, "openscenario", tmp_path)
    xsd["xodr"].validate(str(tmp_path / "road.xodr"))
    xroad = RoadNetwork(str(tmp_path / "road.xodr"), resolution=0.05).get_roads()[0]
    line = shapely.LineString(xroad.reference_line)
    assert max(line.distance(shapely.Point(p)) for p in road.centerline()) < POS_TOL_M
    ids = sorted(lane.id for section in xroad.lane_sections for lane in section.lanes)
    assert ids == [-3, -2, -1, *range(1, oncoming + 1)]  # the oncoming lanes: left lanes beside the centre line
    length = sum(seg.length for seg in reference_line(road))
    assert length == pytest.approx(25.0 * math.pi / 2, rel=1e-3)  # the arc's own length
    _assert_clean(qc("xodr", tmp_path / "road.xodr", tmp_path / "qc"), "check_asam_xodr_xml_valid_schema")
