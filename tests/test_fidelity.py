"""Reconstruction fidelity: projection against KITTI labels, the reprojection metric, crash comparison."""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np
import pandas as pd
import pytest
from tests.conftest import DATA, need
from tests.conftest import KITTI_TRACKING as KITTI

from deepcrashtest.datasets.kitti.files import read_calib, read_labels
from deepcrashtest.geometry.project import project_box
from deepcrashtest.perception.boxes import iou_matrix
from deepcrashtest.scenario import Camera, Scenario

KITTI_TYPES = ("Car", "Van", "Truck", "Pedestrian", "Cyclist")


def _kitti_projection_ious() -> list[tuple[str, float]]:
    """Project every labelled 3D box of the six KITTI frames with our camera model; IoU with its 2D label."""
    out = []
    for seq in ("0001", "0016"):
        calib = read_calib(need(KITTI / "calib" / f"{seq}.txt"))
        labels = read_labels(KITTI / "label_02" / f"{seq}.txt")
        K = calib.K
        shift = np.linalg.solve(K, calib.P2[:, 3])  # camera 2 sits beside the rectified camera 0
        camera = Camera(fx=K[0, 0], fy=K[1, 1], cx=K[0, 2], cy=K[1, 2], height_m=1.65, forward_offset_m=0.0)
        for png in sorted(need(KITTI / "image_02" / seq).glob("*.png")):
            rows = labels[(labels["frame"] == int(png.stem)) & labels["type"].isin(KITTI_TYPES)]
            for r in rows.itertuples():
                x, y, z = r.x + shift[0], r.y + shift[1], r.z + shift[2]
                # camera (x right, y down, z forward) -> world (x forward, y left, z up); KITTI ry = 0 faces +x
                pb = project_box(
                    camera, (0.0, 0.0, 0.0), z, -x, -r.ry - math.pi / 2, r.l, r.w, r.h,
                    z0=1.65 - y, image_size=(1242, 375),
                )  # fmt: skip
                assert pb.box is not None
                out.append((r.type, float(iou_matrix(pb.box, np.array([r.x1, r.y1, r.x2, r.y2]))[0, 0])))
    return out


def test_projection_agrees_with_kitti_labels():
    ious = _kitti_projection_ious()
    assert len(ious) >= 50
    assert np.median([v for _, v in ious]) >= 0.85
    vehicles = [v for t, v in ious if t in ("Car", "Van", "Truck")]
    assert np.median(vehicles) >= 0.95  # a rigid box: only the label's own rounding remains


def test_boxes_behind_or_across_the_camera():
    cam = Camera(fx=700.0, fy=700.0, cx=640.0, cy=360.0, height_m=1.3, forward_offset_m=0.0)
    ahead = project_box(cam, (0.0, 0.0, 0.0), 20.0, 0.0, 0.0, 4.5, 1.8, 1.5, image_size=(1280, 720))
    assert ahead.box is not None
    # a car 20 m ahead, 1.8 m wide: ~63 px wide at its rear face, centred
    assert ahead.box[2] - ahead.box[0] == pytest.approx(700 * 1.8 / 17.75, rel=0.02)
    assert 0.5 * (ahead.box[0] + ahead.box[2]) == pytest.approx(640.0, abs=0.5)
    behind = project_box(cam, (0.0, 0.0, 0.0), -10.0, 0.0, 0.0, 4.5, 1.8, 1.5, image_size=(1280, 720))
    assert behind.box is None and np.isnan(behind.corners).all()
    # alongside, half behind the camera: the near-plane clip keeps a box reaching the image's left edge
    beside = project_box(cam, (0.0, 0.0, 0.0), 0.5, 2.5, 0.0, 4.5, 1.8, 1.5, image_size=(1280, 720))
    assert beside.box is not None and beside.box[0] == 0.0
    assert np.isnan(beside.corners).any() and np.isfinite(beside.corners).any()
    # pitch down: the horizon moves up, a far box's bottom edge moves up with it
    pitched = cam.model_copy(update={"pitch_rad": 0.05})
    far = project_box(pitched, (0.0, 0.0, 0.0), 80.0, 0.0, 0.0, 4.5, 1.8, 1.5)
    level = project_box(cam, (0.0, 0.0, 0.0), 80.0, 0.0, 0.0, 4.5, 1.8, 1.5)
    assert far.box is not None and level.box is not None
    assert level.box[3] - far.box[3] == pytest.approx(700 * math.tan(0.05), abs=3.0)


def _label_tracks(kitti_root: Path, seq: int, max_frame: int) -> pd.DataFrame:
    """KITTI's labelled 2D boxes as a tracks table (track id + 1 = the scenario agent's id)."""
    lab = read_labels(kitti_root / "label_02" / f"{seq:04d}.txt")
    lab = lab[lab["type"].isin(["Car", "Van", "Truck"]) & (lab["frame"] < max_frame)]
    return lab.assign(track_id=lab["track_id"] + 1)[["frame", "track_id", "x1", "y1", "x2", "y2"]]


def exact_replay(scenario: Scenario, dt: float = 0.02):
    """A SimResult whose states are the scenario's own trajectories: the replay of a perfect simulator."""
    from deepcrashtest.sim import SimResult

    times = np.arange(int(round(scenario.duration() / dt)) + 1) * dt
    vehicles = scenario.vehicles()
    states = np.full((len(times), len(vehicles), 4), np.nan)
    present = np.zeros((len(times), len(vehicles)), bool)
    for i, v in enumerate(vehicles):
        a = v.trajectory.arrays()
        inside = (times >= a["t"][0] - 1e-9) & (times <= a["t"][-1] + 1e-9)
        present[:, i] = inside
        for j, key in enumerate(("x", "y", "yaw", "speed")):
            states[inside, i, j] = np.interp(times[inside], a["t"], a[key])
    return SimResult({}, times, [v.id for v in vehicles], states, present, [], "exact", dt)


def test_exact_replay_reprojects_like_the_scenario(kitti8_raw, kitti_root):
    from deepcrashtest.eval.fidelity import evaluate_fidelity

    tracks = _label_tracks(kitti_root, 8, 100)
    res = evaluate_fidelity(kitti8_raw, tracks, exact_replay(kitti8_raw))
    proc, sim = res.reprojection["processed"], res.reprojection["simulated"]
    assert proc["pairs"] == len(tracks) and proc["coverage"] == 1.0
    # real labels placed with ORB-SLAM poses: the scenario's flat road (the ground under these cars lies
    # ~2.1 m below the camera, not 1.65 m) shifts boxes down by ~9 px, which caps the IoU near 0.55
    assert proc["mean_iou"] >= 0.45 and proc["share_iou_ge_0_5"] >= 0.5
    assert abs(proc["median_du_px"]) < 3.0 and proc["median_dv_px"] < -5.0  # right bearing, ground too high
    assert sim["pairs"] == proc["pairs"] and sim["coverage"] == 1.0
    # label tracks are all observed: the figure over every tracked box is the same one
    assert res.reprojection["all_tracked_boxes"] == {"processed": proc["mean_iou"], "simulated": sim["mean_iou"]}
    assert abs(sim["mean_iou"] - proc["mean_iou"]) < 0.02
    assert abs(sim["median_centre_px"] - proc["median_centre_px"]) < 2.0
    # a time shift of 0.3 s (3 KITTI frames) in the mapping must show: the metric sees timing
    shifted = kitti8_raw.evolve(source=kitti8_raw.source.model_copy(update={"time_offset_s": 0.3}))
    worse = evaluate_fidelity(shifted, tracks).reprojection["processed"]
    assert worse["mean_iou"] < proc["mean_iou"] - 0.03


def test_projection_round_trips_through_the_extraction_localiser():
    """A box projected with the scenario camera and localised again lands where it was (same conventions)."""
    from deepcrashtest.geometry.camera import default_camera, with_horizon
    from deepcrashtest.geometry.localize import GroundPlaneLocalizer

    cam = with_horizon(default_camera(1280, 720), 340.0, "vanishing_point")
    for x, y in [(10.0, 0.0), (20.0, 2.0), (30.0, -3.0)]:
        pb = project_box(cam, (0.0, 0.0, 0.0), x, y, 0.0, 4.4, 1.8, 1.5, image_size=(1280, 720))
        assert pb.box is not None
        p = GroundPlaneLocalizer().localize(pb.box[None], ["car"], cam, (1280, 720))
        assert p.z[0] + cam.forward_offset_m == pytest.approx(x, abs=0.3)
        assert -p.x[0] == pytest.approx(y, abs=0.2)


@pytest.fixture(scope="module")
def kitti8_crash(kitti8_raw):
    """KITTI 0008 with real agent 11 moved to meet the ego at t = 10 s, replayed for 11 s."""
    from deepcrashtest.sim import simulate
    from deepcrashtest.sim.testcases import meet_ego

    sc = meet_ego(kitti8_raw, 11, 10.0)
    return sc, simulate(sc, duration=11.0)


def test_crash_compared_with_a_label(kitti8_crash, kitti_root):
    from deepcrashtest.datasets.crash_labels import CrashLabel, Participant
    from deepcrashtest.eval.fidelity import evaluate_fidelity

    sc, sim = kitti8_crash
    tracks = _label_tracks(kitti_root, 8, 130)

    def label(frame: int, track_id: int) -> CrashLabel:
        row = tracks[(tracks["frame"] == frame) & (tracks["track_id"] == track_id)]
        box = tuple(float(v) for v in row[["x1", "y1", "x2", "y2"]].to_numpy()[0])
        return CrashLabel("kitti8", "-", 10.0, True, frame, (Participant(True), Participant(False, box, "car")))

    result = evaluate_fidelity(sc, tracks, sim, label(100, 11))
    good = result.crash
    assert good["label"]["scenario_ids"] == [0, 11]
    assert good["first_contact"]["participants"] == [0, 11]
    assert good["same_pair"] and good["reproduced"] and abs(good["dt_s"]) < 0.05
    assert good["relative_speed_mps"] > 5.0 and good["contacts_before_crash"] == 0
    early = evaluate_fidelity(sc, tracks, sim, label(90, 11)).crash  # labelled 1 s earlier: not reproduced
    assert early["same_pair"] and not early["reproduced"] and early["dt_s"] == pytest.approx(1.0, abs=0.05)
    other = tracks[(tracks["frame"] == 100) & (tracks["track_id"] != 11)]["track_id"].iloc[0]
    wrong = evaluate_fidelity(sc, tracks, sim, label(100, int(other))).crash  # another road user
    assert wrong["same_pair"] is False and wrong["reproduced"] is False
    none = evaluate_fidelity(sc, tracks, sim, None).crash
    assert none["video_has_crash"] is True and none["first_contact"]["participants"] == [0, 11]
    from deepcrashtest.eval.fidelity import fidelity_json
    from deepcrashtest.viz.fidelity_section import fidelity_section

    section = fidelity_section(json.loads(fidelity_json(result)))  # the report reads fidelity.json
    assert "the replay reproduces the labelled crash" in section.body and "0-11 at video 10" in section.body


def test_crash_label_files_load_and_bad_ones_are_refused(tmp_path):
    from deepcrashtest.datasets.crash_labels import load_crash_labels
    from deepcrashtest.errors import UserError

    root = Path(__file__).resolve().parents[1] / "bench" / "labels"
    dad = load_crash_labels(root / "dad_crashes.json")
    ccd = load_crash_labels(root / "ccd_crashes.json")
    assert len(ccd) == 13 and all(lab.crash and any(p.ego for p in lab.participants) for lab in ccd.values())
    assert all(lab.first_accident_frame is not None for lab in ccd.values())
    two_wheel = [
        k for k, lab in dad.items() if lab.third_party and any(p.category == "motorcycle" for p in lab.participants)
    ]
    assert len(two_wheel) >= 3 and not dad["highway_project_video"].crash
    bad = tmp_path / "bad.json"
    for text in ('{"format": "x"}', '{"format": "deepcrashtest-crash-labels", "clips": {"a": {"video": "v", "fps": 20,'
                 ' "crash": true, "contact_frame": 3, "participants": [{"who": "ego"}]}}}', "not json"):  # fmt: skip
        bad.write_text(text)
        with pytest.raises(UserError):
            load_crash_labels(bad)


def test_cli_refuses_bad_input_before_any_work(kitti8_raw, kitti_root, tmp_path):
    from deepcrashtest.cli import main

    sc_path = tmp_path / "scenario.json"
    kitti8_raw.save(sc_path)
    args = ["evaluate", "fidelity", str(sc_path), "--no-video-out", "-o", str(tmp_path / "out")]
    assert main(args) == 2  # no tracks.csv beside the scenario
    _label_tracks(kitti_root, 8, 20).to_csv(tmp_path / "tracks.csv", index=False)
    labels = Path(__file__).resolve().parents[1] / "bench" / "labels" / "dad_crashes.json"
    assert main([*args, "--labels", str(labels)]) == 2  # the labels do not know this clip
    (tmp_path / "out").mkdir(exist_ok=True)
    (tmp_path / "out" / "fidelity.json").write_text("{}")
    assert main(args) == 2  # refuses to overwrite without --force
    assert (tmp_path / "out" / "fidelity.json").read_text() == "{}"


def test_overlay_video_draws_the_replay_over_the_frames(kitti_root, tmp_path):
    """fidelity.mp4 on KITTI 0001's three real frames: H.264, one frame per input, boxes drawn over the image."""
    import av
    import cv2

    from deepcrashtest.datasets.kitti.scenario import scenario_from_kitti
    from deepcrashtest.eval.fidelity import evaluate_fidelity
    from deepcrashtest.viz.fidelity_video import write_fidelity_video

    folder = need(kitti_root / "image_02" / "0001")
    sc = scenario_from_kitti(kitti_root, 1)
    tracks = _label_tracks(kitti_root, 1, 25)
    sim = exact_replay(sc)
    res = evaluate_fidelity(sc, tracks, sim)
    out = write_fidelity_video(sc, res, sim, folder, tracks, tmp_path / "fidelity.mp4")
    assert out["frames"] == 3
    with av.open(str(tmp_path / "fidelity.mp4")) as c:
        assert c.streams.video[0].codec_context.name == "h264"
        frames = [f.to_ndarray(format="bgr24")[:375, :1242] for f in c.decode(video=0)]
    original = cv2.imread(str(folder / "000010.png"))
    changed = np.abs(frames[0].astype(int) - original.astype(int)).max(axis=2) > 60
    # the projected boxes of the cars in view are drawn: changed pixels inside their tracked boxes
    rows = res.pairs[(res.pairs["frame"] == 10) & (res.pairs["simulated_iou"] > 0.3)]
    assert len(rows) >= 3
    for r in rows.itertuples():
        x1, y1, x2, y2 = (int(v) for v in (r.x1, r.y1, r.x2, r.y2))
        assert changed[max(y1 - 5, 0) : y2 + 5, max(x1 - 5, 0) : x2 + 5].any()
    assert changed.mean() < 0.2  # the video is still the video


def test_the_overlay_says_when_the_replay_has_ended(kitti_root):
    """A scenario ends at its crash, the video goes on: past the replay's last step the overlay draws no 3D box and
    says the replay ended there (dad_000487: the boxes vanished 0.15 s after the contact, with no word why)."""
    import cv2

    from deepcrashtest.datasets.kitti.scenario import scenario_from_kitti
    from deepcrashtest.eval.fidelity import evaluate_fidelity
    from deepcrashtest.sim import simulate
    from deepcrashtest.viz.fidelity_video import FidelityPainter

    folder = need(kitti_root / "image_02" / "0001")
    sc = scenario_from_kitti(kitti_root, 1)
    tracks = _label_tracks(kitti_root, 1, 25)
    sim = simulate(sc, duration=sc.frame_time(15) + 0.01)  # the replay runs to frame 15, the video on to 20
    painter = FidelityPainter(sc, evaluate_fidelity(sc, tracks, sim), sim)
    assert painter.replay_ended(sc.frame_time(15)) is None
    line = painter.replay_ended(sc.frame_time(20))
    assert line is not None and line.startswith("REPLAY ENDED at ")
    ended_at = float(line.removeprefix("REPLAY ENDED at ").split("s ")[0])  # video time, s
    frame15 = sc.video_time(sc.frame_time(15))
    assert frame15 <= ended_at <= frame15 + 0.035  # the span asked (+0.01 s), its last 0.02 s step, the print's 0.005
    empty = tracks.iloc[:0]
    for frame, ended in ((15, False), (20, True)):
        image = cv2.imread(str(folder / f"{frame:06d}.png"))
        changed = np.abs(painter.draw(frame, image, empty).astype(int) - image.astype(int)).max(axis=2) > 60
        assert changed[90:115].any() == ended  # the line (the labelled contact's line would be above it)
        assert changed[130:].any() != ended  # the replay's 3D boxes, none once it has ended


def test_the_trackers_coasting_after_a_lost_road_user_is_not_counted(yolo_ok):
    """ccd_000340, tracked as extract tracks a 10 fps clip (the detector every other frame): a car far
    ahead is hidden by the minivan that turns into the ego; its track coasts on for frames after its last
    detection, and those boxes lie on the minivan, not on the hidden car. The reprojection counts a
    track's boxes from its first to its last detection only; every detected box stays."""
    from deepcrashtest.eval.fidelity import detection_anchored
    from deepcrashtest.perception.detect import DEFAULT_DETECTOR, make_detector
    from deepcrashtest.perception.track import frame_records, iter_tracks, records_table
    from deepcrashtest.video.source import open_video

    rows: list[tuple[object, ...]] = []
    with open_video(need(DATA / "crash_ccd" / "ccd_000340.mp4")) as src:
        frames = (f for f in src if f.index <= 27)
        for ft in iter_tracks(frames, make_detector(DEFAULT_DETECTOR), detect_every=2, fps=src.meta.fps):
            rows.extend(frame_records(ft))
    tracks = records_table(rows)
    kept = detection_anchored(tracks)
    dropped = tracks.loc[tracks.index.difference(kept.index)]
    assert (kept["state"] == "detected").sum() == (tracks["state"] == "detected").sum()
    assert len(dropped) and (dropped["state"] == "predicted").all()
    last = tracks[tracks["state"] == "detected"].groupby("track_id")["frame"].max()
    assert (dropped["frame"].to_numpy() > dropped["track_id"].map(last).to_numpy()).all()  # only trailing coasts
    inside = []  # share of each coasted box inside another road user's box of that frame
    for r in dropped.itertuples(index=False):
        others = tracks[(tracks["frame"] == r.frame) & (tracks["track_id"] != r.track_id)]
        b = np.array([r.x1, r.y1, r.x2, r.y2])
        o = others[["x1", "y1", "x2", "y2"]].to_numpy(float)
        w = np.clip(np.minimum(o[:, 2], b[2]) - np.maximum(o[:, 0], b[0]), 0, None)
        h = np.clip(np.minimum(o[:, 3], b[3]) - np.maximum(o[:, 1], b[1]), 0, None)
        inside.append(float((w * h).max() / ((b[2] - b[0]) * (b[3] - b[1]))) if len(o) else 0.0)
    print("coasted boxes:", len(dropped), "inside another road user's box:", np.round(inside, 2))
    assert max(inside) >= 0.9  # the hidden car's coasting box sits on the car that hid it
