"""The Scenario contract: round trip, validation messages, schema version, atomic save."""

from __future__ import annotations

import json
import math

import numpy as np
import pytest

from deepcrashtest.errors import ScenarioError, UserError
from deepcrashtest.scenario import SCHEMA_VERSION, Scenario, Trajectory, json_schema


def test_round_trip_is_lossless(kitti8_raw, tmp_path):
    path = kitti8_raw.save(tmp_path / "s.json")
    again = Scenario.load(path)
    assert again == kitti8_raw
    assert again.to_json() == kitti8_raw.to_json()


def test_save_refuses_overwrite_without_force(kitti8_raw, tmp_path):
    path = tmp_path / "s.json"
    path.write_text("precious")
    with pytest.raises(UserError, match="already exists"):
        kitti8_raw.save(path)
    assert path.read_text() == "precious"
    kitti8_raw.save(path, force=True)
    assert Scenario.load(path).name == "kitti_0008"
    assert [p.name for p in tmp_path.iterdir()] == ["s.json"]  # no temp file left behind
    assert path.stat().st_mode & 0o044 == 0o044  # readable by others, like any file the user writes


def test_failed_save_leaves_old_file(kitti8_raw, tmp_path, monkeypatch):
    path = tmp_path / "s.json"
    path.write_text("old")

    def boom(self):
        raise RuntimeError("disk full")

    monkeypatch.setattr(Scenario, "to_json", boom)
    with pytest.raises(RuntimeError):
        kitti8_raw.save(path, force=True)
    assert path.read_text() == "old"
    assert [p.name for p in tmp_path.iterdir()] == ["s.json"]


def _mutated(sc: Scenario, fn) -> dict:
    d = json.loads(sc.to_json())
    fn(d)
    return d


@pytest.mark.parametrize(
    ("mutate", "message"),
    [
        (lambda d: d["ego"]["trajectory"]["x"].__setitem__(3, math.nan), r"ego\.trajectory\.x\.3"),
        (lambda d: d["ego"]["trajectory"]["t"].__setitem__(5, 0.0), r"t must increase strictly"),
        (lambda d: d["ego"]["trajectory"]["speed"].__setitem__(2, -1.0), r"ego\.trajectory\.speed\.2"),
        (lambda d: d["ego"]["trajectory"]["speed"].__setitem__(2, 120.0), r"physical limit 90"),
        (lambda d: d["ego"]["trajectory"]["y"].pop(), r"y has .* samples but t has"),
        (lambda d: d["source"].__setitem__("fps", -5), r"source\.fps"),
        (lambda d: d["source"].__setitem__("fps", 0), r"source\.fps"),
        (lambda d: d.__setitem__("schema_version", "2.0"), r"schema_version 2\.0 is not supported"),
        (lambda d: d.__setitem__("schema_version", "1.9"), r"schema_version 1\.9 is not supported"),
        (lambda d: d.pop("schema_version"), r"missing schema_version"),
        (lambda d: d["agents"][0].__setitem__("id", 0), r"ids must be unique"),
        (lambda d: d["road"].__setitem__("centerline_x", [0.0]), r"road"),
        (lambda d: d.__setitem__("unknown_field", 1), r"unknown_field"),
        (lambda d: d["agents"][1].__setitem__("trajectory_class", "D9T9"), r"agents\.1\.trajectory_class"),
    ],
)
def test_validation_names_the_field(kitti8_raw, mutate, message):
    with pytest.raises(ScenarioError, match=message):
        Scenario.from_dict(_mutated(kitti8_raw, mutate))


def test_processed_scenarios_enforce_acceleration_limit(kitti8_raw):
    def spike(d):
        d["stage"] = "processed"
        d["agents"] = []
        d["ego"]["trajectory"]["speed"][10] += 5.0  # +5 m/s within 0.1 s = 50 m/s^2

    with pytest.raises(ScenarioError, match=r"ego.trajectory: \|acceleration\| 50.* exceeds the physical limit"):
        Scenario.from_dict(_mutated(kitti8_raw, spike))


@pytest.mark.parametrize(
    ("content", "message"),
    [
        ("", "empty"),
        ("{not json", "invalid JSON at line 1"),
        ("[1, 2]", "expected a JSON object"),
        ('{"schema_version": "1.0", "x": NaN}', "non-finite number NaN"),
    ],
)
def test_load_bad_files(tmp_path, content, message):
    p = tmp_path / "bad.json"
    p.write_text(content)
    with pytest.raises(UserError, match=message):
        Scenario.load(p)


def test_load_directory_and_missing(tmp_path):
    with pytest.raises(UserError, match="is a directory"):
        Scenario.load(tmp_path)
    with pytest.raises(UserError, match="no such"):
        Scenario.load(tmp_path / "nope.json")


def test_trajectory_helpers():
    tr = Trajectory.from_arrays([0, 1, 2], [0, 10, 20], [0, 0, 0], [0, 0, 0], [10, 10, 10])
    assert tr.state_at(1.5)["x"] == pytest.approx(15.0)
    assert tr.max_abs_accel() == (0.0, 1)


def test_json_schema_validates_real_file_and_rejects_bad(kitti8_raw):
    import jsonschema  # an independent validator of the exported schema

    schema = json_schema()
    assert schema["title"].endswith(SCHEMA_VERSION)
    data = json.loads(kitti8_raw.to_json())
    jsonschema.validate(data, schema)
    data["ego"]["trajectory"]["speed"][0] = -3.0
    with pytest.raises(jsonschema.ValidationError):
        jsonschema.validate(data, schema)


def test_migrates_1_0_files_and_keeps_the_time_mapping() -> None:
    """A 1.0 processed file loads as 1.1 with the lead-in and the ego's first frame in source.time_offset_s."""
    from deepcrashtest.scenario import migrate

    data = {
        "schema_version": "1.0",
        "source": {"path": "v.mp4", "fps": 20.0, "frame_count": 100, "width": 64, "height": 48},
        "ego": {"first_frame": 10},
        "provenance": {"parameters": {"video_time_offset_s": 3.0}},
    }
    out = migrate(data)
    assert out["schema_version"] == SCHEMA_VERSION
    assert out["source"]["time_offset_s"] == pytest.approx(3.0 - 10 / 20.0)
    assert data["schema_version"] == "1.0"  # the input is not changed


def test_a_1_2_file_reads_as_a_one_way_road(kitti8_raw) -> None:
    """Schema 1.3 adds the oncoming lanes (``Road.oncoming_lane_count``, ``median_width``), 1.4 the side traffic
    keeps to (``Road.driving_side``): a 1.2 file (without them) loads as 1.6 with no oncoming lanes in right-hand
    traffic, the road it described; a 1.3 file as 1.6 in right-hand traffic; 1.4 writes them."""
    data = json.loads(kitti8_raw.to_json())
    assert data["schema_version"] == SCHEMA_VERSION == "1.6"
    assert data["road"]["oncoming_lane_count"] == 0 and data["road"]["median_width"] == 0.0
    assert data["road"]["driving_side"] == "right"
    new = ("oncoming_lane_count", "median_width", "driving_side")
    old = dict(data, schema_version="1.2", road={k: v for k, v in data["road"].items() if k not in new})
    sc = Scenario.from_dict(old)
    assert sc.schema_version == "1.6" and sc.road == kitti8_raw.road
    v13 = dict(data, schema_version="1.3", road={k: v for k, v in data["road"].items() if k != "driving_side"})
    assert Scenario.from_dict(v13).road == kitti8_raw.road
    with pytest.raises(ValueError, match="driving_side"):
        Scenario.from_dict(dict(data, road=dict(data["road"], driving_side="middle")))


def test_evolve_validates_and_third_party_collision(kitti8_raw):
    """Scenario.evolve returns a validated copy; a collision may name two agents but not an unknown one."""
    a, b = kitti8_raw.agents[0].id, kitti8_raw.agents[1].id
    sc = kitti8_raw.evolve(collision={"time_s": 1.0, "other_id": a, "agent_id": b, "source": "user"})
    assert sc.collision is not None and sc.collision.participants == (a, b) and not sc.collision.involves_ego
    assert kitti8_raw.collision is None or kitti8_raw.collision.source != "user"
    with pytest.raises(ScenarioError, match="collision.other_id 9999"):
        kitti8_raw.evolve(collision={"time_s": 1.0, "other_id": 9999, "agent_id": b})
    with pytest.raises(ScenarioError, match="unknown Scenario field"):
        kitti8_raw.evolve(colision=None)
    assert sc.scenario_time(sc.video_time(2.5)) == pytest.approx(2.5)


def test_evolve_equals_a_whole_revalidation_and_still_checks_the_physics(kitti8_raw):
    """evolve keeps the unchanged fields' validated models: the result is the same file as validating the whole
    changed dump (KITTI 0008), and a changed trajectory is still checked, alone and against the others."""
    ego = kitti8_raw.ego.trajectory.arrays()
    moved = Trajectory.from_arrays(ego["t"], ego["x"] + 1.5, ego["y"] - 0.5, ego["yaw"], ego["speed"])
    changes = {"name": "moved", "ego": kitti8_raw.ego.model_copy(update={"trajectory": moved})}
    fast = kitti8_raw.evolve(**changes)
    whole = Scenario.from_dict({**kitti8_raw.model_dump(), "name": "moved", "ego": changes["ego"].model_dump()})
    assert fast.to_json() == whole.to_json()
    assert fast.agents[0] is kitti8_raw.agents[0]  # shared, not validated again
    bad = moved.model_dump()
    bad["speed"][3] = 95.0
    with pytest.raises(ScenarioError, match="physical limit 90"):
        kitti8_raw.evolve(ego={**kitti8_raw.ego.model_dump(), "trajectory": bad})
    spike = moved.model_dump()
    spike["speed"][10] += 5.0  # 50 m/s^2: refused by the whole scenario's check of a processed scenario
    with pytest.raises(ScenarioError, match=r"acceleration\| 50"):
        kitti8_raw.evolve(stage="processed", agents=[], ego={**kitti8_raw.ego.model_dump(), "trajectory": spike})


def test_evolve_of_a_processed_scenario_checks_the_physics_of_what_changed_only(kitti8_raw):
    """evolve of a processed scenario (KITTI 0008, its smooth agents) skips the physics check of the vehicles it
    shares (checked when that scenario was validated), still refuses a changed agent's trajectory, and a raw
    scenario made processed has every vehicle checked."""
    smooth = [a for a in kitti8_raw.agents if a.trajectory.accel_problem("a") is None]
    jerky = [a for a in kitti8_raw.agents if a.trajectory.accel_problem("a") is not None]
    assert len(smooth) >= 3 and jerky  # label tracks: some jump above the limit
    sc = kitti8_raw.evolve(stage="processed", agents=smooth, collision=None)
    fast = sc.evolve(name="renamed")
    assert fast.agents[0] is sc.agents[0]
    assert fast.to_json() == Scenario.from_dict({**sc.model_dump(), "name": "renamed"}).to_json()
    k = max(range(len(smooth)), key=lambda i: len(smooth[i].trajectory))
    arr = smooth[k].trajectory.arrays()
    arr["speed"][3] += 5.0  # ~50 m/s^2 in a changed agent
    spiky = smooth[k].model_copy(update={"trajectory": Trajectory.from_arrays(**arr)})
    with pytest.raises(
        ScenarioError, match=rf"agents\[id={smooth[k].id}\].trajectory: \|acceleration\| \d+\.\d m/s\^2 at sample 4"
    ):
        sc.evolve(agents=[*smooth[:k], spiky, *smooth[k + 1 :]])
    with pytest.raises(ScenarioError, match="acceleration"):  # raw -> processed: the shared agents checked too
        kitti8_raw.evolve(stage="processed", agents=[*smooth, jerky[0]], collision=None)


def _text_loop(v: str) -> str:
    """The per-character check ``scenario._text`` replaced (the reference)."""
    for i, ch in enumerate(v):
        if (ord(ch) < 32 and ch not in "\t\n\r") or ord(ch) == 127 or 0xD800 <= ord(ch) <= 0xDFFF:
            raise ValueError(f"control or invalid character U+{ord(ch):04X} at position {i}")
    return v


def test_text_check_refuses_exactly_what_the_character_loop_refused(kitti8_raw):
    """Every code point (and the real scenario's texts) gets the same answer and message as the old loop."""
    from deepcrashtest.scenario import _text

    def answer(fn, v):
        try:
            return fn(v)
        except ValueError as exc:
            return str(exc)

    texts = [kitti8_raw.source.path, *kitti8_raw.warnings, *kitti8_raw.provenance.history]
    texts += [f"ok {chr(c)} tail\x7f" for c in range(0x110000)]
    assert all(answer(_text, v) == answer(_text_loop, v) for v in texts)
    assert answer(_text, "a\u0085b\x1fc") == "control or invalid character U+001F at position 3"


def test_a_1_4_file_reads_with_the_camera_along_the_ego(kitti8_raw) -> None:
    """Schema 1.5 adds the camera's yaw relative to the ego's heading (``Camera.yaw_rad``, ``CameraAttitude.yaw_rad``):
    a 1.4 file (without them) loads as 1.6 with the camera looking along the ego; a yaw series turns the projected
    view (a road user ahead moves right in the image when the camera turns left) and is checked like pitch and roll."""
    from deepcrashtest.geometry.project import project_box
    from deepcrashtest.scenario import CameraAttitude

    data = json.loads(kitti8_raw.to_json())
    assert data["camera"]["yaw_rad"] == 0.0
    old = dict(data, schema_version="1.4", camera={k: v for k, v in data["camera"].items() if k != "yaw_rad"})
    sc = Scenario.from_dict(old)
    assert sc.schema_version == "1.6" and sc.camera == kitti8_raw.camera
    att = CameraAttitude(video_t=[0.0, 1.0], pitch_rad=[0.0, 0.0], roll_rad=[0.0, 0.0], yaw_rad=[0.0, 0.05])
    cam = kitti8_raw.camera.model_copy(update={"attitude": att})
    assert cam.at_video_time(0.5).yaw_rad == pytest.approx(0.025) and cam.at_video_time(0.0).yaw_rad == 0.0
    ahead = (20.0, 0.0, 0.0, 4.5, 1.8, 1.5)
    straight = project_box(cam.at_video_time(0.0), (0.0, 0.0, 0.0), *ahead, image_size=(1242, 375)).box
    turned = project_box(cam.at_video_time(1.0), (0.0, 0.0, 0.0), *ahead, image_size=(1242, 375)).box
    shift = 0.5 * (turned[0] + turned[2] - straight[0] - straight[2])
    assert shift == pytest.approx(cam.fx * math.tan(0.05), rel=0.05)
    with pytest.raises(ValueError, match="yaw_rad"):
        CameraAttitude(video_t=[0.0, 1.0], pitch_rad=[0.0, 0.0], roll_rad=[0.0, 0.0], yaw_rad=[0.0])
    with pytest.raises(ValueError, match="0.5 rad"):
        CameraAttitude(video_t=[0.0], pitch_rad=[0.0], roll_rad=[0.0], yaw_rad=[0.6])


def test_a_variable_frame_rate_video_maps_each_frame_by_its_own_time(kitti8_raw) -> None:
    """Schema 1.6 adds ``VideoSource.frame_times``: a phone's variable-frame-rate file (frames dropped, their own
    timestamps kept) is not ``frame / fps`` apart, and every frame <-> time conversion (the crash's frame, the
    fidelity's reprojection, the viewer's frame) goes through them: each frame's time is its own, the frame shown at a
    time is the last one not after it, frames past the list continue at the mean rate. A 1.5 file loads as 1.6 with
    none (``frame / fps``); times that do not increase are refused."""
    times = [0.0, 0.05, 0.10, 0.25, 0.30, 0.45, 0.50]  # 20 fps with frames 3, 4, 7, 8 dropped
    fps = (len(times) - 1) / times[-1]
    src = kitti8_raw.source.model_copy(
        update={"fps": fps, "frame_count": len(times), "time_offset_s": 2.0, "frame_times": times}
    )
    sc = kitti8_raw.evolve(source=src)
    for k, t in enumerate(times):
        assert sc.frame_time(k) == pytest.approx(t + 2.0)
        assert sc.video_frame(sc.frame_time(k)) == k
        assert sc.video_frame(sc.frame_time(k) + 0.01) == k
    assert sc.video_frame(2.0 + 0.2) == 2  # frame 2 (0.10 s) is on screen until frame 3 (0.25 s)
    assert sc.video_frame(2.0 - 0.01) is None and sc.video_frame(2.0 + 0.5 + 1.0 / fps) is None
    assert sc.frame_time(len(times)) == pytest.approx(2.0 + 0.5 + 1.0 / fps)
    for offset in np.linspace(-3.0, 3.0, 61):  # frames past the list round-trip too (the viewer steps through them)
        for rate in (5.0, 12.0, 29.97):
            src = sc.source.model_copy(update={"fps": rate, "frame_count": 12, "time_offset_s": float(offset)})
            late = sc.evolve(source=src)
            assert [late.video_frame(late.frame_time(k)) for k in range(12)] == list(range(12)), (offset, rate)
    assert Scenario.from_dict(json.loads(sc.to_json())).source.frame_times == times
    data = json.loads(kitti8_raw.to_json())
    assert "frame_times" in data["source"] and data["source"]["frame_times"] is None
    v15 = dict(data, schema_version="1.5", source={k: v for k, v in data["source"].items() if k != "frame_times"})
    assert Scenario.from_dict(v15).source == kitti8_raw.source
    cfr = kitti8_raw.source
    assert kitti8_raw.video_frame(kitti8_raw.frame_time(7)) == 7 and cfr.frame_times is None
    with pytest.raises(ValueError, match="frame_times"):
        Scenario.from_dict(dict(data, source=dict(data["source"], frame_times=[0.0, 0.1, 0.1])))
