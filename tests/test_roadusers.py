"""Road users the crash clips need (pedestrians, two-wheelers with their rider), third-party crashes,
compilations (one scenario per shot) and roads inferred where no lanes are seen. All on real data:
DAD crash clips, KITTI tracking labels (sequence 0012: a cyclist, a pedestrian, cars)."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from conftest import DATA, KITTI_TRACKING, need
from deepcrashtest.datasets.kitti.scenario import scenario_from_kitti
from deepcrashtest.scenario import Scenario
from deepcrashtest.sim import prepare, replay_error, simulate
from deepcrashtest.sim.testcases import meet

pytestmark = pytest.mark.filterwarnings("ignore::DeprecationWarning")  # commonroad's protobuf modules

DAD = DATA / "crash_dad"
PEDESTRIAN, CYCLIST = 3, 1  # KITTI 0012 track ids + 1


@pytest.fixture(scope="module")
def kitti12() -> Scenario:
    return scenario_from_kitti(need(KITTI_TRACKING), 12, road_users=True)


def _frame(clip: str, index: int) -> np.ndarray:
    from deepcrashtest.video.source import open_video

    with open_video(need(DAD / f"{clip}.mp4")) as src:
        return next(f.image for f in src if f.index == index)


def test_riders_join_their_two_wheeler_on_real_dad_frames():
    from deepcrashtest.perception.detect import make_detector
    from deepcrashtest.perception.roadusers import merge_riders

    det = make_detector("ssd-mobilenet")
    # dad_000493 frame 40: a scooter and its rider (detected as a person) -> one motorcycle covering both
    raw = det(_frame("dad_000493", 40))
    assert {"motorcycle", "pedestrian"} <= set(raw.categories)
    merged = merge_riders(raw)
    assert "pedestrian" not in set(merged.categories) and len(merged) == len(raw) - 1
    person = raw.boxes[list(raw.categories).index("pedestrian")]
    moto = merged.boxes[list(merged.categories).index("motorcycle")]
    assert moto[0] <= person[0] and moto[1] <= person[1] and moto[2] >= person[2] and moto[3] >= person[3]
    # dad_000487 frame 60: a busy pavement; riders join the bicycles, the walkers stay pedestrians
    raw = det(_frame("dad_000487", 60))
    merged = merge_riders(raw)
    n_ped = int((merged.categories == "pedestrian").sum())
    assert "bicycle" in set(merged.categories) and n_ped >= 8
    assert n_ped == int((raw.categories == "pedestrian").sum()) - (len(raw) - len(merged))


def test_pedestrian_replays_its_path_and_cyclist_is_a_bicycle(kitti12):
    cats = {a.id: a.category for a in kitti12.agents}
    assert cats[PEDESTRIAN] == "pedestrian" and cats[CYCLIST] == "bicycle"
    world = prepare(kitti12)
    assert world.mass[world.ids.index(PEDESTRIAN)] == 75.0 and world.holonomic[world.ids.index(PEDESTRIAN)]
    err = replay_error(kitti12, simulate(world), until_collision=False)["per_vehicle"]
    # a walker follows its (smoothed) labelled path; the bicycle model alone measured 0.047 m here
    assert err[str(PEDESTRIAN)] < 0.02
    assert err[str(CYCLIST)] < 0.15


def test_exports_with_pedestrian_and_cyclist(kitti12, tmp_path):
    import scenariogeneration
    import xmlschema
    from lxml import etree

    from deepcrashtest.export import export_scenario
    from deepcrashtest.export.commonroad import ego_collision_steps
    from export_helpers import qc_available, read_xosc, run_qc

    for fmt in ("openscenario", "commonroad"):
        export_scenario(kitti12, fmt, tmp_path)
    xosc = tmp_path / "scenario.xosc"
    schemas = Path(scenariogeneration.__file__).resolve().parents[1] / "schemas"
    xmlschema.XMLSchema(str(schemas / "OpenSCENARIO_1_2.xsd")).validate(str(xosc))
    peds = etree.parse(str(xosc)).getroot().findall(".//ScenarioObject/Pedestrian")
    assert [p.get("name") for p in peds] == [f"Agent{PEDESTRIAN}"] and peds[0].get("pedestrianCategory") == "pedestrian"
    replay = read_xosc(xosc)[f"Agent{PEDESTRIAN}"]  # the reference point of a pedestrian is its centre
    tr = kitti12.vehicle(PEDESTRIAN).trajectory
    assert replay.center_x == 0.0
    assert np.allclose(replay.centre_at(np.array(tr.t[3:6])), np.column_stack([tr.x[3:6], tr.y[3:6]]), atol=0.05)
    if qc_available():
        report = run_qc("xosc", xosc, tmp_path / "qc")
        assert report["checkers"]["check_asam_xosc_xml_valid_schema"] == "completed" and not report["errors"]
    from commonroad.common.file_reader import CommonRoadFileReader

    cr, _ = CommonRoadFileReader(str(tmp_path / "commonroad.xml")).open()
    types = {o.obstacle_id: o.obstacle_type.name for o in cr.dynamic_obstacles}
    assert "PEDESTRIAN" in types.values() and "BICYCLE" in types.values()
    assert ego_collision_steps(cr, kitti12.ego) == []  # the drivability checker: KITTI holds no crash


def test_third_party_crash_is_reproduced_and_searched(kitti12, tmp_path):
    from deepcrashtest.search.run import SearchConfig, run_search

    crash = meet(kitti12, PEDESTRIAN, CYCLIST, 3.0)  # the real walker moved into the real cyclist's way
    assert crash.collision is not None and not crash.collision.involves_ego
    res = simulate(crash)
    first = res.metrics["first_contact"]
    assert set(first["vehicles"]) == {PEDESTRIAN, CYCLIST} and abs(first["time"] - 3.0) < 0.1
    assert first["relative_speed"] > 1.0 and not res.metrics["collided"]  # the ego touches nobody
    # a later ego crash (car 2 moved to meet the ego at 5 s; its path crosses the ego earlier) is still the
    # ego's collision, with its own delta-v
    both = simulate(meet(crash, 2, 0, 5.0).evolve(collision=crash.collision))
    assert both.metrics["first_contact"]["vehicles"] == first["vehicles"]
    assert both.metrics["collided"] and both.metrics["collision_vehicle"] == 2
    assert 3.1 < both.metrics["collision_time"] <= 5.1 and both.metrics["delta_v_ego"] > 0.5
    cfg = SearchConfig(starts=2, noise_variants=2, method="random", boundary_directions=0, max_scenarios=1)
    summary = run_search(crash, tmp_path, SearchConfig(**{**cfg.__dict__, "video": False}))
    q = summary["crash"]
    assert q["kind"] == "third-party" and q["reproduced"] and abs(q["simulated_time_s"] - 3.0) < 0.1
    assert "ego touches no road user" in q["safe_means"]
    variant = Scenario.load(summary["outputs"]["safe_scenarios"][0])
    assert variant.collision is not None and variant.collision.participants == crash.collision.participants


def test_agent_collisions_from_the_recorded_run_are_the_simulated_ones(kitti12):
    """A third-party crash's contacts from the agents' recorded run (no per-step run) are ``simulate``'s, bit for
    bit (times, pair, relative speed, Box2D's point and delta-v); where the ego touches someone they are refused."""
    from deepcrashtest.search.run import SearchConfig, crash_question
    from deepcrashtest.sim import agent_collisions

    crash = meet(kitti12, PEDESTRIAN, CYCLIST, 3.0)
    fast = agent_collisions(prepare(crash))
    assert fast is not None and fast == simulate(crash).collisions and len(fast) >= 1
    assert fast[0]["delta_v"] and fast[0]["point"] is not None
    cfg = SearchConfig(method="random")
    world = prepare(crash)
    assert crash_question(crash, cfg, lambda: world) == crash_question(crash, cfg)  # the search's two ways
    both = meet(crash, 2, 0, 5.0).evolve(collision=crash.collision)  # the ego hits car 2 as well
    assert agent_collisions(prepare(both)) is None


def test_road_inferred_from_road_users_where_no_lanes_are_seen(kitti12):
    from deepcrashtest.trajectory.pipeline import process_scenario
    from deepcrashtest.trajectory.road import inferred_lanes

    sc = process_scenario(kitti12)
    road = sc.road
    assert road.source == "road_users" and 3.0 <= road.lane_width <= 3.75 and 1 <= road.lane_count <= 6
    assert any("no lane lines seen" in w for w in sc.warnings)
    assert inferred_lanes([], 3.5) == (3.5, 1, 0)
    width, count, ego_lane = inferred_lanes([3.3, -3.3, 6.6, 40.0], 3.5)  # 40 m: another road, ignored
    assert abs(width - 3.3) < 0.03 and (count, ego_lane) == (4, 1)


def _compilation(path: Path, parts: list[tuple[str, int, int]], size: tuple[int, int] = (480, 270)) -> list[int]:
    """Concatenate frames of real clips into one H.264 file (a compilation); returns the first frame of each part."""
    import av
    import cv2

    from deepcrashtest.video.source import open_video

    starts, n = [], 0
    with av.open(str(path), "w") as out:
        stream = out.add_stream("libx264", rate=20)
        stream.width, stream.height, stream.pix_fmt = size[0], size[1], "yuv420p"
        for clip, a, b in parts:
            starts.append(n)
            with open_video(need(DAD / f"{clip}.mp4")) as src:
                for f in src:
                    if f.index > b:
                        break
                    if f.index >= a:
                        img = cv2.resize(f.image, size, interpolation=cv2.INTER_AREA)
                        out.mux(stream.encode(av.VideoFrame.from_ndarray(img, format="bgr24")))
                        n += 1
        out.mux(stream.encode(None))
    return starts


def test_compilation_gives_one_scenario_per_shot(tmp_path):
    from deepcrashtest.pipeline.extract import run_extract
    from deepcrashtest.video.shots import detect_shots

    video = tmp_path / "compilation.mp4"
    starts = _compilation(video, [("dad_000478", 56, 79), ("dad_000512", 60, 83)])
    shots = detect_shots(video)
    assert [(s.first_frame, s.last_frame) for s in shots] == [(0, starts[1] - 1), (starts[1], 47)]
    res = run_extract(
        video, tmp_path / "out", "ssd-mobilenet:tiles=0", detect_every=8, lanes=False, report=False, annotate=False
    )
    assert res["cuts_s"] == [starts[1] / 20.0] and [r["shot"] for r in res["shots"]] == ["shot_01", "shot_02"]
    for r, shot in zip(res["shots"], shots, strict=True):
        tracks = (tmp_path / "out" / r["shot"] / "tracks.csv").read_text().splitlines()[1:]
        frames = {int(line.split(",")[0]) for line in tracks}
        assert frames and shot.first_frame <= min(frames) and max(frames) <= shot.last_frame
        raw = json.loads((tmp_path / "out" / r["shot"] / "scenario_raw.json").read_text())
        sc = Scenario.from_dict(raw)
        assert sc.video_frame(sc.ego.trajectory.t[0]) == shot.first_frame  # the compilation's own frame numbers


@pytest.fixture(scope="module")
def yolo(yolo_ok):
    from deepcrashtest.perception.detect import make_detector

    return make_detector("yolo26n")


def _labelled_boxes(clip: str) -> list[np.ndarray]:
    from deepcrashtest.datasets.crash_labels import load_crash_labels

    label = load_crash_labels(Path(__file__).resolve().parents[1] / "bench" / "labels" / "dad_crashes.json")[clip]
    return [np.array(p.box, float) for p in label.participants if not p.ego]


def test_riders_of_a_hidden_scooter_and_two_scooters_in_one_box_are_separate_road_users(yolo):
    """dad_000487: a scooter with two riders at the ego's bumper is two person boxes (the riders hide it);
    dad_000512: one motorcycle box covers both colliding scooters. Each labelled scooter must be one
    road user (a motorcycle box overlapping its label, IoU >= 0.5) at the contact frames."""
    from deepcrashtest.perception.boxes import iou_matrix
    from deepcrashtest.perception.roadusers import road_users, track_category

    # frames, and those near enough to the contact frame (97, 89) for the labelled boxes to hold
    for clip, frames, near in (("dad_000487", (85, 90), (85,)), ("dad_000512", (89, 90), (89, 90))):
        labels = _labelled_boxes(clip)
        for f in frames:
            image = _frame(clip, f)
            users = road_users(yolo(image), picture=(0, 0, image.shape[1], image.shape[0]))  # as the tracker calls it
            motos = users.boxes[users.categories == "motorcycle"]
            tall = users.boxes[:, 3] - users.boxes[:, 1] > 250  # the riders, 280-420 px tall
            assert not (tall & (users.categories == "pedestrian")).any(), (clip, f, users)
            assert int((tall & (users.categories == "motorcycle")).sum()) == len(labels), (clip, f, users)
            for box in labels if f in near else []:
                best = iou_matrix(box, motos).max() if len(motos) else 0.0
                assert best >= 0.5, (clip, f, box, motos)
    # a track whose riders were a two-wheeler in 2 of 7 detection rounds is a two-wheeler; a walker is not
    assert track_category({"pedestrian": 5, "motorcycle": 2}) == "motorcycle"
    assert track_category({"pedestrian": 7}) == "pedestrian"
    assert track_category({"pedestrian": 9, "bicycle": 1}) == "pedestrian"


def test_a_pickup_reported_as_car_and_truck_is_one_road_user(yolo):
    """dad_000550 (a scooter runs into the front of a pickup truck): YOLO's NMS runs per class, and at frames
    30-95 it reports the pickup as a ``car`` and a ``truck`` box almost the same (IoU 0.95-0.99); re-encoded at
    crf 35 the two became two tracks, two crash pairs with the scooter, and the contact was taken 0.3 s early
    on the wrong one. Road users: one vehicle per box, the other vehicles kept."""
    from scipy.sparse.csgraph import connected_components

    from deepcrashtest.perception.boxes import iou_matrix
    from deepcrashtest.perception.roadusers import MOTOR_VEHICLES, road_users

    for f in (65, 90):
        raw = yolo(_frame("dad_000550", f))
        veh = np.isin(raw.categories, MOTOR_VEHICLES)
        m = iou_matrix(raw.boxes[veh], raw.boxes[veh])
        np.fill_diagonal(m, 0.0)
        assert m.max() > 0.9  # the same pickup twice, as the detector reports it
        users = road_users(raw)
        kept = users.boxes[np.isin(users.categories, MOTOR_VEHICLES)]
        k = iou_matrix(kept, kept)
        np.fill_diagonal(k, 0.0)
        assert k.max(initial=0.0) < 0.8, (f, kept)
        groups, _ = connected_components(m >= 0.8, directed=False)  # one per vehicle
        assert len(kept) == groups, (f, kept)
    label = _labelled_boxes("dad_000550")
    users = road_users(yolo(_frame("dad_000550", 88)))
    vehicles = users.boxes[np.isin(users.categories, MOTOR_VEHICLES)]
    assert max(iou_matrix(b, vehicles).max() for b in label) >= 0.5  # the labelled pickup is one of them


def test_people_walking_together_brush_past_in_stage_2_and_the_simulator():
    """KITTI 0017's labelled road users: 9 pedestrians and 2 cyclists on a pavement, people walking in groups whose
    boxes (larger than their bodies) touch. The simulator counts no contact between two pedestrians (it sent 7 and 8
    into Box2D at 2.5 s, two people walking side by side), stage 2 keeps all 11 where the labels put them (it
    dropped 2 after nudges that could not keep each 0.5 m from everyone), the plausibility check does not count
    them as passing through each other; a cyclist moved into a pedestrian still collides, and so do two walkers that are
    the scenario's collision."""
    from deepcrashtest.eval.plausibility import overlapping_pairs
    from deepcrashtest.trajectory.collision import vehicle_box
    from deepcrashtest.trajectory.crash import contact_after_apart
    from deepcrashtest.trajectory.pipeline import process_scenario

    raw = scenario_from_kitti(need(KITTI_TRACKING), 17, road_users=True)
    walker = {a.id: a for a in raw.agents if a.category == "pedestrian"}
    assert contact_after_apart(vehicle_box(walker[7]), vehicle_box(walker[8])) is not None  # they do touch
    assert simulate(raw).metrics["first_contact"] is None
    assert not [p for p in overlapping_pairs(raw) if {p[0], p[1]} <= set(walker)]
    processed = process_scenario(raw)
    assert sorted(a.id for a in processed.agents) == sorted(a.id for a in raw.agents)
    assert simulate(processed).metrics["first_contact"] is None
    cyclist = next(a.id for a in raw.agents if a.category == "bicycle")
    hit = simulate(meet(raw, cyclist, 7, 3.0)).metrics["first_contact"]  # on its way it meets walker 9 first
    assert hit is not None and cyclist in hit["vehicles"] and set(hit["vehicles"]) - {cyclist} <= set(walker)
    hit = simulate(meet(raw, 3, 5, 3.0)).metrics["first_contact"]  # two walkers the scenario says collided do
    assert hit is not None and set(hit["vehicles"]) == {3, 5} and abs(hit["time"] - 3.0) < 0.1


def test_riders_at_the_bumper_of_a_letterboxed_picture_are_found_at_the_pictures_bottom(yolo):
    """dad_000487 frame 90: the two riders at the ego's bumper, two upright person boxes whose scooter is hidden, are
    one motorcycle because they reach the picture's lowest rows. Letterboxed (120 px bars above and below) the
    picture's bottom is not the frame's: the tracker passes the picture, and only the picture finds them; two walkers
    side by side higher up are no riders however the frame is framed."""
    from deepcrashtest.perception.detections import Detections
    from deepcrashtest.perception.roadusers import road_users

    det = yolo(_frame("dad_000487", 90))
    shifted = Detections(det.boxes + np.array([0, 120, 0, 120], np.float32), det.scores, det.categories)

    def riders(users: Detections) -> int:
        tall = users.boxes[:, 3] - users.boxes[:, 1] > 250
        return int((tall & (users.categories == "motorcycle")).sum())

    assert riders(road_users(det, picture=(0, 0, 1280, 720))) == 1
    assert riders(road_users(shifted, picture=(0, 120, 1280, 840))) == 1
    assert riders(road_users(shifted, picture=(0, 0, 1280, 960))) == 0  # the frame's bottom is the bars'
    assert riders(road_users(det)) == 0  # no picture: only a squat box over both riders joins them
