"""Crash detection in the video: synthetic tracks with known answers, the camera jolt on a real CCD clip,
and the user's --crash override (parsing, bad values)."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import numpy as np
import pandas as pd
import pytest

from conftest import ROOT, need
from deepcrashtest.errors import UserError
from deepcrashtest.perception.crash_detect import GlobalMotion, detect_crash
from deepcrashtest.perception.crash_ego import ego_scores
from deepcrashtest.perception.crash_tracks import box_growth, jolt_score
from deepcrashtest.pipeline.crash import crash_for_raw, parse_crash
from deepcrashtest.scenario import Scenario
from trajectory_cases import raw_scenario, track, vehicle

W, H, FPS = 1280, 720, 10.0
DATA = Path(__file__).resolve().parents[2] / "shared" / "data"


def _rows(tid: int, frames: range, box) -> list[dict]:  # type: ignore[no-untyped-def]
    out = []
    for f in frames:
        x1, y1, x2, y2 = box(f)
        out.append(dict(frame=f, time=f / FPS, track_id=tid, category="car", x1=x1, y1=y1, x2=x2, y2=y2))
    return out


def _approach(f: int) -> tuple[float, float, float, float]:
    """A car ahead growing in the image until frame 30 (contact: it stops growing), then pushed away."""
    s = 120 * 1.12 ** min(f, 30) if f <= 30 else 120 * 1.12**30 * 0.99 ** (f - 30)
    return 640 - s, 330 - 0.3 * s, 640 + s, 330 + 0.55 * s


def _far(f: int) -> tuple[float, float, float, float]:
    return 100 + f, 300, 180 + f, 350


def test_ego_crash_found_at_the_knee_of_the_box_growth():
    tracks = pd.DataFrame(_rows(4, range(0, 40), _approach) + _rows(9, range(0, 40), _far))
    found = detect_crash(tracks, W, H, FPS)
    assert found is not None and found.pair == (0, 4)
    assert abs(found.frame - 30) <= 1 and 0.4 < found.confidence <= 1.0


def test_jolt_sets_the_ego_contact_frame():
    tracks = pd.DataFrame(_rows(4, range(0, 40), _approach))
    frames = np.arange(40)
    shifts = np.zeros((40, 2))
    shifts[27, 1] = 9.0  # the camera jumps between frames 26 and 27
    found = detect_crash(tracks, W, H, FPS, motion=(frames, shifts))
    assert found is not None and abs(found.frame - 27) <= 1 and found.evidence["jolt"] > 0.9


def test_third_party_contact_with_a_sudden_change_of_motion():
    def scooter(f: int) -> tuple[float, float, float, float]:  # rides right, then is knocked away at 20
        x = 300 + 12 * min(f, 20) + (40 * (f - 20) if f > 20 else 0)
        y = 380 + (25 * (f - 20) if f > 20 else 0)
        return x, y, x + 60, y + 120

    def car(f: int) -> tuple[float, float, float, float]:
        return 600, 400, 800, 500

    tracks = pd.DataFrame(_rows(2, range(0, 30), scooter) + _rows(3, range(0, 30), car))
    found = detect_crash(tracks, W, H, FPS)
    assert found is not None and found.pair == (2, 3) and 17 <= found.frame <= 22


# Person boxes (frame, x1, y1, x2, y2 px, 1280x720) measured by `extract`: dad_000487 mirrored (20 fps, detector rounds
# every 5 frames), the two riders of the scooter that hits the ego at frame 97, one detected as one box over both at
# frames 85-90; ccd_000882 (10 fps), the woman struck by the ego at frame 30.
RIDER_BOTH = [(60, 32, 367, 91, 581), (65, 24, 334, 173, 678), (70, 65, 329, 205, 683), (75, 79, 329, 232, 691)]
RIDER_BOTH += [(80, 101, 324, 265, 693), (85, 38, 284, 332, 700), (90, 105, 279, 400, 716), (95, 65, 313, 241, 682)]
RIDER_BACK = [(60, 263, 408, 314, 561), (65, 166, 403, 235, 588), (70, 89, 396, 171, 613), (75, 2, 303, 119, 648)]
RIDER_BACK += [(80, 0, 291, 133, 672), (85, 54, 280, 198, 694), (90, 136, 270, 293, 718), (95, 96, 278, 235, 678)]
STRUCK = [(22, 420, 292, 482, 451), (23, 424, 290, 487, 452), (24, 405, 291, 505, 503), (25, 409, 289, 518, 522)]
STRUCK += [(26, 419, 280, 535, 570), (27, 429, 269, 557, 588), (28, 376, 241, 559, 627), (29, 364, 230, 566, 655)]
STRUCK += [(30, 217, 188, 572, 632), (31, 171, 169, 581, 648)]


def _person_rows(tid: int, rows: list[tuple[int, int, int, int, int]]) -> pd.DataFrame:
    cols = ["frame", "x1", "y1", "x2", "y2"]
    return pd.DataFrame(rows, columns=cols).assign(track_id=tid, category="pedestrian", state="detected")


def test_a_squat_box_over_two_riders_is_not_a_pedestrian_knocked_over():
    """A person box turning squat (height/width 2.2 -> 1.4) because the detector drew one box over the two riders of a
    scooter (the other rider's own track inside it, at its distance) is not a pedestrian struck off their feet:
    dad_000487 mirrored had its crash put there, 0.6 s before the contact. The struck woman of ccd_000882, whose box
    turns squat over no one, still is, at the contact frame."""
    both, back = _person_rows(15, RIDER_BOTH), _person_rows(18, RIDER_BACK)
    people = pd.concat([both, back], ignore_index=True)
    g = both.set_index("frame")
    assert not ego_scores(g, 1280, 720, 20.0, {}, people=people)["knocked_over"].any()
    alone = ego_scores(g, 1280, 720, 20.0, {})["knocked_over"]  # without the other rider's track: read as a fall
    assert list(alone[alone].index) == [85]
    woman = _person_rows(6, STRUCK)
    fell = ego_scores(woman.set_index("frame"), 1280, 720, 10.0, {}, people=woman)["knocked_over"]
    assert list(fell[fell].index) == [30]


#: dad_000487 cut 1.5 s before its crash (``bench/fidelity_perturbed.py --variants late``), 20 fps: a scooter rider
#: detected as a person every 5th frame, one detection (frame 20) boxed with the scooter under them.
RIDER_LATE = [(0, 1094, 335, 1236, 691), (5, 1072, 328, 1237, 684), (10, 1038, 303, 1280, 692)]
RIDER_LATE += [(15, 990, 320, 1157, 678), (20, 900, 282, 1208, 702), (25, 963, 276, 1179, 706)]
RIDER_LATE += [(30, 1059, 335, 1211, 649)]


def test_a_person_box_upright_again_at_the_next_detection_did_not_fall():
    """A person's box squat for one detection (height/width 2.1 -> 1.36) and upright again at the next, a quarter
    second later (2.0), is no one struck off their feet: the late-cut dad_000487 had its crash put there, 0.5 s
    before the contact (found on the label since). A next detection further off than ``BACK_UP_WITHIN_S`` says
    nothing: the squat box is a fall (the struck woman of ccd_000882 is next seen 0.6 s later, on the bonnet)."""
    from deepcrashtest.perception.crash_ego import BACK_UP_WITHIN_S

    rider = _person_rows(3, RIDER_LATE)
    timed = rider.assign(time=rider["frame"] / 20.0)
    assert not ego_scores(timed.set_index("frame"), 1280, 720, 20.0, {})["knocked_over"].any()
    untimed = ego_scores(rider.set_index("frame"), 1280, 720, 20.0, {})["knocked_over"]  # no time: read as a fall
    assert list(untimed[untimed].index) == [20]
    slow = timed[timed["frame"] != 25]  # the next detection 0.5 s later
    assert 0.5 > BACK_UP_WITHIN_S
    fell = ego_scores(slow.set_index("frame"), 1280, 720, 20.0, {})["knocked_over"]
    assert list(fell[fell].index) == [20]
    woman = _person_rows(6, STRUCK)
    woman = woman.assign(time=woman["frame"] / 10.0)
    fell = ego_scores(woman.set_index("frame"), 1280, 720, 10.0, {}, people=woman)["knocked_over"]
    assert list(fell[fell].index) == [30]


def test_a_box_that_only_widens_is_not_closing_in():
    """dad_000512 through a longer lens (``bench/fidelity_perturbed.py --variants zoom``): a scooter crosses in front of
    the stopped ego, its box 184 px wide then 449 px (the detector boxed it from its side) at a steady 330 px height;
    its growth in area read as closing in at full rate and made an ego crash 0.75 s before the scooters' own. A box
    that widens with its height steady turns or is seen from a new side: it is not closing in. A car coming nearer
    (both sides growing) and one at the bumper, its box cut by the picture's bottom, still are."""

    def crossing(f: int) -> tuple[float, float, float, float]:
        x = 100 + 30 * f
        w = 184 if f < 12 else 449
        return x, 310, x + w, 640

    def cut_at_the_bottom(f: int) -> tuple[float, float, float, float]:
        s = 200 * 1.08**f
        return 640 - s, 400 - 0.2 * s, 640 + s, H

    boxes = pd.DataFrame(_rows(4, range(24), crossing)).set_index("frame")
    assert box_growth(boxes, FPS, W, H).abs().max() < 1e-9
    assert box_growth(boxes, FPS).max() > 1.0  # its area alone: 1.49/s
    nearer = box_growth(pd.DataFrame(_rows(4, range(0, 40), _approach)).set_index("frame"), FPS, W, H)
    assert nearer.loc[5:25].min() == pytest.approx(10 * np.log(1.12), rel=1e-6)
    bumper = box_growth(pd.DataFrame(_rows(4, range(12), cut_at_the_bottom)).set_index("frame"), FPS, W, H)
    assert bumper.loc[3:9].min() > 0.3


def test_nothing_found_when_nobody_is_near():
    assert detect_crash(pd.DataFrame(_rows(9, range(0, 40), _far)), W, H, FPS) is None


def test_camera_jolt_on_a_real_crash_clip():
    """ccd_000080: rear-end at speed; labelled contact frame 31 (bench/labels/ccd_crashes.json)."""
    import av

    video = DATA / "crash_ccd" / "ccd_000080.mp4"
    if not video.exists():
        pytest.skip("CCD clips not available")
    gm = GlobalMotion()
    with av.open(str(video)) as c:
        for i, f in enumerate(c.decode(video=0)):
            gm.update(i, f.to_ndarray(format="bgr24"))
    frames, shifts = gm.arrays()
    scores = jolt_score(frames, shifts, 10.0)
    first = min(f for f, s in scores.items() if s >= 0.3)
    assert abs(first - 31) <= 1


def test_parse_crash():
    assert parse_crash("95:ego,7").pair == (0, 7) and parse_crash("95").pair is None
    assert parse_crash(" 95 : 3 , 7 ").pair == (3, 7) and parse_crash("95:3,7").frame == 95
    for bad in ("", "x", "95:", "95:3", "95:3,3", "95:-1,2", "95:car,2", "-3"):
        with pytest.raises(UserError, match="--crash"):
            parse_crash(bad)


def test_user_crash_into_the_raw_scenario():
    raw = raw_scenario([vehicle(7, track(lambda t: (30 + 5 * t, 0 * t), 0, 100))])
    tracks = pd.DataFrame(_rows(7, range(0, 101), _far))
    sc, rec = crash_for_raw(raw, tracks, None, parse_crash("60:ego,7"))
    assert isinstance(sc, Scenario) and sc.collision is not None
    assert sc.collision.participants == (0, 7) and sc.collision.source == "user"
    assert sc.collision.time_s == pytest.approx(sc.scenario_time(6.0))
    assert rec["user_spec"] == "60:ego,7" and sc.provenance.parameters["crash_detection"]["found"]
    with pytest.raises(UserError, match="no track 8"):
        crash_for_raw(raw, tracks, None, parse_crash("60:ego,8"))
    with pytest.raises(UserError, match="outside the video"):
        crash_for_raw(raw, tracks, None, parse_crash("500:ego,7"))
    none, rec2 = crash_for_raw(raw, tracks, None)
    assert none.collision is None and rec2["found"] is False


def test_cli_bad_crash_value_one_line_exit_2(tmp_path):
    video = DATA / "crash_ccd" / "ccd_000080.mp4"
    if not video.exists():
        pytest.skip("CCD clips not available")
    proc = subprocess.run(
        [sys.executable, "-m", "deepcrashtest.cli", "extract", str(video), "-o", str(tmp_path / "o"), "--crash", "9x"],
        capture_output=True, text=True, timeout=120,
    )  # fmt: skip
    assert proc.returncode == 2 and "--crash" in proc.stderr and len(proc.stderr.strip().splitlines()) == 1
    assert not (tmp_path / "o").exists() or not any((tmp_path / "o").iterdir())


def test_a_box_jumping_onto_a_truck_beside_it_is_no_ego_crash(tmp_path):
    """KITTI's stop-and-go highway queue (78 real frames, no crash): from frame 8 the detector gives one box over
    the green truck ahead-right and the tanker beside it, and the truck's track takes it (240 -> 480 px wide in
    one frame, onto the picture's top and right borders). That step is the detector's box switching, not a road
    user closing in: no crash is found (the growth counted as approach once made it an ego crash at 0.75)."""
    from deepcrashtest.pipeline.extract import run_extract
    from deepcrashtest.scenario import Scenario

    folder = need(DATA / "kitti_raw_highway_queue" / "image_02" / "data")
    run_extract(folder, tmp_path / "queue", fps=10.0, report=False, annotate=False, lanes=False)
    raw = Scenario.load(tmp_path / "queue" / "scenario_raw.json")
    tracks = pd.read_csv(tmp_path / "queue" / "tracks.csv")
    w = (tracks["x2"] - tracks["x1"]).groupby(tracks["track_id"])
    assert (w.apply(lambda s: float(np.log(s).diff().max())) > 0.5).any()  # a box doubled its width in one frame
    assert raw.collision is None, raw.provenance.parameters.get("crash_detection")


def test_a_car_parked_at_the_side_that_the_ego_turns_past_is_no_ego_crash(tmp_path):
    """KITTI odometry seq00, frames 80-159 (real frames, no crash): the ego turns right at a corner past a car parked
    at the right. Its box is cut by the right border in every frame (it enters the view as the ego turns), so it grows
    fast while it is near, with no camera jolt; 1.5 s later it has left the view at the side. A motor vehicle the ego
    strikes stays in view or jolts the camera: no crash (an ego crash at 0.48 while only a road user leaving the
    view within 1 s counted as driving past)."""
    from deepcrashtest.pipeline.extract import run_extract
    from deepcrashtest.scenario import Scenario

    folder = need(DATA / "kitti_odometry" / "seq00_frames0000-0159" / "image_0")
    run_extract(folder, tmp_path / "turn", fps=10.0, report=False, annotate=False, lanes=False, frame_range=(80, 159))
    raw = Scenario.load(tmp_path / "turn" / "scenario_raw.json")
    tracks = pd.read_csv(tmp_path / "turn" / "tracks.csv")
    width = raw.source.width
    detected = tracks[tracks["state"] == "detected"]
    cut_right = (detected["x2"] >= width - 4).groupby(detected["track_id"]).all()
    sizes = tracks.groupby("track_id").size().reindex(cut_right.index)
    assert (cut_right & (sizes >= 15)).any()  # a car detected only cut by the right border, tracked 1.5 s and more
    assert raw.collision is None, raw.provenance.parameters.get("crash_detection")


def test_parked_cars_passed_in_a_row_are_no_crash_between_them(tmp_path):
    """KITTI odometry seq00 mirrored (real frames flipped left to right), frames 40-110: the ego drives past cars
    parked in a row at the right. At frame 76 the nearer car's track takes a box on the car behind it and a new
    track starts on the nearer one: the two boxes overlap, are close on the ground and both speed up across the
    view as the ego passes. What they share is the view's motion, not theirs: the change of the offset between
    the two boxes (``motion_change(a, ..., other=b)``) bounds the pair's motion change, and no crash is found (a
    crash between them at 0.37 when each box's own change counted)."""
    from deepcrashtest.pipeline.extract import run_extract
    from deepcrashtest.scenario import Scenario

    folder = need(DATA / "kitti_odometry" / "seq00_frames0000-0159" / "image_0")
    mirrored = _mirrored(folder, tmp_path / "mirrored")
    run_extract(mirrored, tmp_path / "row", fps=10.0, report=False, annotate=False, lanes=False, frame_range=(40, 110))
    raw = Scenario.load(tmp_path / "row" / "scenario_raw.json")
    assert len(raw.agents) >= 8  # the parked cars along the street are tracked
    assert raw.collision is None, raw.provenance.parameters.get("crash_detection")


def test_a_detector_box_over_two_parked_cars_for_one_round_is_no_motion(tmp_path):
    """KITTI odometry seq06's first 51 frames through ``run_extract``: a car parked behind trees at the left, 42 px
    wide, is given one box over it and the car beside it (91 px, the same height) for one detection round, then
    59 px again. ``switched_box`` marks that box and the frames carried from it up to the next detection, where the
    track's motion change is 0 (the jump and the jump back read 0.87, a crash between the two parked cars at 0.90;
    0.51 now, from the next boxes' jitter)."""
    from deepcrashtest.perception.crash_tracks import motion_change, per_track
    from deepcrashtest.pipeline.extract import run_extract

    folder = need(DATA / "kitti_odometry" / "seq06_frames0000-0050" / "image_0")
    result = run_extract(folder, tmp_path / "s06", fps=10.0, report=False, annotate=False, lanes=False)
    switched = 0
    for g in per_track(pd.read_csv(tmp_path / "s06" / "tracks.csv"), 10.0).values():
        det = g[g["state"] == "detected"]
        dw = np.diff(np.log((det["x2"] - det["x1"]).to_numpy(float)))
        dh = np.diff(np.log((det["y2"] - det["y1"]).to_numpy(float)))
        for k in range(1, len(det) - 1):  # wider by 50 % and back, at the same height
            if dw[k - 1] > 0.4 and dw[k] < -0.3 and max(abs(dh[k - 1]), abs(dh[k])) < 0.1:
                switched += 1
                frames = det.index[k], det.index[k + 1]
                assert g.loc[frames[0] : frames[1], "switched"].all()
                assert float(motion_change(g, 1241, 10.0).loc[frames[0] : frames[1]].max()) == 0.0
    assert switched >= 1
    assert result["crash_detection"].get("confidence", 0.0) < 0.6


def test_a_truck_beside_the_ego_from_the_start_whose_one_edge_jitters_is_no_ego_crash(tmp_path):
    """KITTI's stop-and-go highway queue mirrored (real frames flipped left to right, no crash): the tanker fills the
    left of the view from the first frame, its box cut by the picture's left side and top, and only its inner edge
    moves, jittering with the detector's extent (383 -> 498 -> 425 -> 505 px wide) while the queue stands. Its growth
    rate read as closing in (0.29, an ego crash at 0.52); the box never grew by the 0.2 in log size of an approach
    within a second (``crash_ego.EGO_MIN_RISE``): no crash."""
    from deepcrashtest.pipeline.extract import run_extract
    from deepcrashtest.scenario import Scenario

    folder = need(DATA / "kitti_raw_highway_queue" / "image_02" / "data")
    mirrored = _mirrored(folder, tmp_path / "mirrored")
    run_extract(mirrored, tmp_path / "queue", fps=10.0, report=False, annotate=False, lanes=False)
    raw = Scenario.load(tmp_path / "queue" / "scenario_raw.json")
    tracks = pd.read_csv(tmp_path / "queue" / "tracks.csv")
    first = tracks[tracks["frame"] == tracks["frame"].min()]
    assert ((first["x1"] <= 4) & (first["y1"] <= 4) & (first["x2"] - first["x1"] > 300)).any()  # the tanker at once
    assert raw.collision is None, raw.provenance.parameters.get("crash_detection")


def test_a_car_across_the_whole_portrait_view_is_not_seen_standing_before_the_jolt(tmp_path):
    """ccd_000330 cropped to its central 9:16 portrait (real frames, 404 x 720 px; a phone filming upright): the
    RAV4 ahead fills the narrow view's whole width 0.8 s before the rear-end, so its box cannot widen. That was read as
    the car standing at the bumper since frame 30 and the contact moved there from the jolt at 38 (the label). A box
    across the whole width is not seen standing: the contact stays at the jolt."""
    import av

    from deepcrashtest.datasets.crash_labels import load_crash_labels
    from deepcrashtest.pipeline.extract import run_extract
    from deepcrashtest.video.writer import VideoWriter

    label = load_crash_labels(ROOT / "bench" / "labels" / "ccd_crashes.json")["ccd_000330"]
    assert label.contact_frame is not None
    with av.open(str(need(DATA / label.video))) as src:
        frames = [f.to_ndarray(format="bgr24") for f in src.decode(video=0)]
    h, w = frames[0].shape[:2]
    cw = int(h * 9 / 16) // 2 * 2
    x0 = (w - cw) // 2
    video = tmp_path / "portrait.mp4"
    with VideoWriter(video, label.fps, cw, h, crf=20, preset="veryfast") as writer:
        for img in frames:
            writer.write(np.ascontiguousarray(img[:, x0 : x0 + cw]))
    result = run_extract(video, tmp_path / "out", annotate=False, report=False, lanes=False, shots=False)
    found = result["crash_detection"]
    assert found["found"] and found["pair"][0] == "ego", found
    assert abs(found["frame"] - label.contact_frame) / label.fps <= 0.25, found


def _mirrored(folder: Path, dest: Path) -> Path:
    """``dest`` holding every PNG frame of ``folder`` flipped left to right (real frames, the road seen mirrored)."""
    import cv2

    dest.mkdir()
    for f in sorted(folder.glob("*.png")):
        cv2.imwrite(str(dest / f.name), cv2.flip(cv2.imread(str(f)), 1))
    return dest


def test_two_road_users_whose_boxes_never_meet_are_no_crash_pair():
    """A pair whose boxes never meet in the image scores 0 on every frame (no costlier cue computed for it: most
    pairs of a busy street), its contact at their first common frame, and the clip has no crash."""
    from deepcrashtest.perception.crash_pair import pair_contact, pair_scores
    from deepcrashtest.perception.crash_tracks import per_track

    def right(f: int) -> tuple[float, float, float, float]:  # a car keeping its lane far right
        return 1000 - f, 380, 1100 - f, 450

    tracks = pd.DataFrame(_rows(2, range(5, 30), _far) + _rows(3, range(0, 30), right))
    per = per_track(tracks, FPS)
    s = pair_scores(per[2], per[3], W, H, fps=FPS)
    assert list(s.index) == list(range(5, 30)) and not s["score"].any()
    score, frame, pair, _ = pair_contact(s, (2, 3), FPS)
    assert (score, frame, pair) == (0.0, 5, (2, 3))
    assert detect_crash(tracks, W, H, FPS) is None
