"""Tracking: the generic core against brute force, and the image tracker on a real crash clip."""

from __future__ import annotations

import itertools
from pathlib import Path

import numpy as np
import pytest

from conftest import DATA, need
from deepcrashtest.perception.detect import make_detector
from deepcrashtest.perception.lifecycle import TrackBase, TrackCore, TrackState, assign
from deepcrashtest.perception.track import TRACK_COLUMNS, iter_tracks, track_video, warp_boxes
from deepcrashtest.video.source import open_video

CLIP = DATA / "crash_dad" / "dad_000478.mp4"


@pytest.mark.parametrize("shape", [(4, 4), (3, 5), (5, 2)])
def test_assign_is_optimal_against_brute_force(shape):
    rng = np.random.default_rng(7)
    for _ in range(20):
        cost = rng.random(shape)
        a = assign(cost, max_cost=2.0)
        got = sum(cost[r, c] for r, c in a.pairs)
        n = min(shape)
        if shape[0] >= shape[1]:
            best = min(sum(cost[p[j], j] for j in range(n)) for p in itertools.permutations(range(shape[0]), n))
        else:
            best = min(sum(cost[i, p[i]] for i in range(n)) for p in itertools.permutations(range(shape[1]), n))
        assert got == pytest.approx(best)
        assert len(a.pairs) == n


def test_assign_gates_and_never_matches_infinite_cost():
    cost = np.array([[0.1, np.inf], [0.95, 0.9]])
    a = assign(cost, max_cost=0.8)
    assert a.pairs == [(0, 0)] and a.unmatched_rows == [1] and a.unmatched_cols == [1]


def test_core_lifecycle_ids_at_confirmation():
    core: TrackCore[TrackBase] = TrackCore(min_hits=2, max_misses=2)
    a, b = core.spawn(TrackBase()), core.spawn(TrackBase())
    assert a.state is TrackState.TENTATIVE and a.track_id == 0
    res = core.step(np.array([[0.0], [np.inf]]), max_cost=0.5)  # a hit, b (tentative) missed -> deleted
    assert [t for t, _ in res.matched] == [a] and res.missed == [b]
    assert a.confirmed and a.track_id == 1 and b.state is TrackState.DELETED
    assert core.prune() == [b]
    for _ in range(2):
        core.step(np.zeros((1, 0)), max_cost=0.5)
    assert a.confirmed and a.misses == 2
    core.step(np.zeros((1, 0)), max_cost=0.5)
    assert a.state is TrackState.DELETED
    core.prune()
    c = core.spawn(TrackBase())
    core.step(np.zeros((1, 1)), max_cost=0.5)
    assert c.track_id == 2  # ids are never reused


def test_core_confirms_on_accumulated_scores():
    """With ``min_evidence`` a run of weak detections needs more rounds than one of strong ones."""
    core: TrackCore[TrackBase] = TrackCore(min_hits=2, max_misses=2, min_evidence=2.7)
    strong, weak = core.spawn(TrackBase(), 0.99), core.spawn(TrackBase(), 0.75)
    rounds = {id(strong): 0, id(weak): 0}
    for k in range(1, 5):
        core.step(np.array([[0.0, np.inf], [np.inf, 0.0]]), max_cost=0.5, scores=np.array([0.99, 0.75]))
        for t in (strong, weak):
            if t.confirmed and not rounds[id(t)]:
                rounds[id(t)] = k + 1  # detections so far, the first counted
    assert rounds[id(strong)] == 3 and rounds[id(weak)] == 4  # 2.97 >= 2.7 after 3; 0.75 x 4 = 3.0
    assert TrackCore(min_hits=1).spawn(TrackBase()).confirmed  # no evidence asked: the hits alone


@pytest.fixture(scope="module")
def clip_tracks():
    """The first 40 frames of a real crash clip, detector every 5th frame (8 detector runs)."""
    with open_video(need(CLIP)) as src:
        states = []
        df = track_video(
            src, make_detector("ssd-mobilenet"), detect_every=5, max_frames=40, on_frame=lambda ft: states.append(ft)
        )
    return df, states


def test_output_table_contract(clip_tracks):
    df, states = clip_tracks
    assert list(df.columns) == TRACK_COLUMNS
    assert df["frame"].dtype == np.int64 and df["track_id"].min() >= 1
    assert set(df["category"]) <= {"car", "truck", "bus", "motorcycle", "bicycle"}
    assert set(df["state"]) == {"detected", "predicted"}
    assert (df["x2"] > df["x1"]).all() and (df["y2"] > df["y1"]).all()
    assert df["x1"].min() >= 0 and df["x2"].max() <= 1280 and df["y2"].max() <= 720
    assert len(states) == 40 and [s.frame.index for s in states] == list(range(40))
    assert np.allclose(df["time"], df["frame"] / 20.0)
    detected_frames = set(df.loc[df["state"] == "detected", "frame"])
    assert detected_frames <= set(range(0, 40, 5))  # detections only on detector frames
    assert [s.detections is not None for s in states] == [k % 5 == 0 for k in range(40)]


def test_records_table_is_pandas_own_table_of_the_records(clip_tracks):
    """The column-by-column table equals pandas' ``from_records`` + ``astype`` of the same rows (real
    tracker rows, and no rows)."""
    import pandas as pd

    from deepcrashtest.perception.track import frame_records, records_table

    _, states = clip_tracks
    records = [r for ft in states for r in frame_records(ft)]
    assert len(records) > 40
    for rows in (records, []):
        expected = pd.DataFrame.from_records(rows, columns=TRACK_COLUMNS).astype(
            {"frame": "int64", "time": "float64", "track_id": "int64", "category": "str", "score": "float64"}
            | {c: "float64" for c in ("x1", "y1", "x2", "y2")}
            | {"state": "str"}
        )
        pd.testing.assert_frame_equal(records_table(rows), expected)


def test_car_ahead_keeps_one_id(clip_tracks):
    """The car straight ahead (about x 680-770, y 400-480 px) is one track, carried between detections."""
    df, _ = clip_tracks
    ahead = df[(df["x1"] < 720) & (df["x2"] > 720) & (df["y1"] < 440) & (df["y2"] > 440)]
    assert ahead["track_id"].nunique() == 1
    # confirmed at the 2nd detection (frame 5), its frames before that reported too; never lost
    assert set(ahead["frame"]) == set(range(0, 40))
    track = df[df["track_id"] == ahead["track_id"].iloc[0]]
    cx = (track["x1"] + track["x2"]) / 2
    assert np.abs(np.diff(cx)).max() < 15  # carried smoothly: no jumps between frames


def test_iter_tracks_needs_fps_for_plain_frames():
    with pytest.raises(ValueError, match="fps"):
        next(iter_tracks(iter([]), make_detector("ssd-mobilenet:tiles=0")))


def test_detection_stage_ahead_gives_the_trackers_own_tracks():
    """detect_ahead | track_detected (extract runs them in two threads) = BoxTracker.update with its detector,
    on the first 16 frames of a real crash clip, detecting every 3rd frame."""
    from deepcrashtest.perception.track import BoxTracker, detect_ahead, track_detected

    with open_video(need(CLIP)) as src:
        frames = list(itertools.islice(src, 16))
    det = make_detector("ssd-mobilenet:tiles=0")
    calls: list[int] = []

    def counted(image):
        calls.append(1)
        return det(image)

    tracker = BoxTracker(det, fps=20.0, detect_every=3)
    direct = [tracker.update(f) for f in frames]
    ahead = list(track_detected(detect_ahead(frames, counted, 3), 20.0, 3))
    assert len(calls) == 6  # frames 0, 3, ..., 15
    assert [ft.detections is not None for ft in ahead] == [k % 3 == 0 for k in range(16)]
    assert [(ft.frame.index, ft.tracks, ft.backfill) for ft in ahead] == [
        (ft.frame.index, ft.tracks, ft.backfill) for ft in direct
    ]
    assert any(ft.tracks for ft in ahead)


@pytest.fixture(scope="module")
def dad512_tracks(tmp_path_factory):
    """dad_000512's tracks table as ``extract`` writes it (geometry off)."""
    import pandas as pd

    from deepcrashtest.pipeline.extract import run_extract

    out = tmp_path_factory.mktemp("dad512") / "out"
    run_extract(need(DATA / "crash_dad" / "dad_000512.mp4"), out, report=False, annotate=False, geometry=False)
    return pd.read_csv(out / "tracks.csv")


def _vehicle_detections(df) -> dict[int, np.ndarray]:
    """Each vehicle track's detected rows (frame, x1, y1, x2, y2 px), in frame order."""
    seen = df[(df["state"] == "detected") & df["category"].isin(["car", "van", "truck", "bus"])].sort_values("frame")
    return {int(k): g[["frame", "x1", "y1", "x2", "y2"]].to_numpy(float) for k, g in seen.groupby("track_id")}


def test_a_parked_car_a_scooter_passes_in_front_of_keeps_its_track(dad512_tracks):
    """dad_000512 (the ego stopped at a junction, scooters crossing in front of parked cars): the optical flow inside
    a parked car's box followed a scooter passing in front of it (the carried box ran 500 px across the picture in
    24 frames) and the car, detected again where it stood 0.5 s later, started a second track: two cars in one
    place in the scenario. A vehicle's track missed by the first matching is now matched where its
    constant-velocity box overlaps a detection by IoU >= 0.5 (``perception.track.REACQUIRE_IOU``): no vehicle
    track is reborn where another's detections ended (main: tracks 4 -> 10 and 5 -> 14, IoU 0.95 / 0.97), and the
    frames it was carried through are reported again on the line between its two detections
    (``FrameTracks.bridged``)."""
    from deepcrashtest.perception.boxes import iou_matrix

    df = dad512_tracks
    tracks = _vehicle_detections(df)
    assert len(tracks) >= 8  # the parked cars, the bonnet, the cars arriving
    reborn = [
        (a, b)
        for a, ra in tracks.items()
        for b, rb in tracks.items()
        if 0 < rb[0, 0] - ra[-1, 0] <= 30 and iou_matrix(ra[-1, 1:], rb[:1, 1:])[0, 0] >= 0.7
    ]
    assert reborn == []
    # and the frames carried in between lie on the line between the detections, not where the flow dragged them
    rows = df[df["track_id"].isin(tracks)]
    for k, r in tracks.items():
        if (iou_matrix(r[:1, 1:], r[:, 1:])[0] >= 0.8).all():  # a standing road user (the ego stands too)
            own = rows[(rows["track_id"] == k) & rows["frame"].between(r[0, 0], r[-1, 0])]  # between its detections
            assert iou_matrix(r[:1, 1:], own[["x1", "y1", "x2", "y2"]].to_numpy(float))[0].min() >= 0.5, k


def test_the_ego_bonnet_taken_for_a_car_is_told_from_road_users(dad512_tracks, tmp_path):
    """dad_000512 (the ego stopped: the bonnet is as still as the road, ``bonnet_contour`` cannot find it): the
    detector reports the bonnet, whose top the by-eye label puts at row 575 (``bench/labels/bonnet_rows.json``), as
    a "car" 1,000-1,120 px wide along the picture's bottom; placed in 3D it lands inside the ego's nose or across it,
    as its box's heading turns out (with another track set, round occlude24: across, and it stayed in the scenario).
    ``geometry.ego_parts.ego_part_tracks`` (default camera: no calibration needed) names that track and no other;
    ccd_000340's car, which fills the picture's bottom as the ego hits it, is a road user."""
    import json

    import pandas as pd

    from deepcrashtest.geometry.camera import default_camera
    from deepcrashtest.geometry.ego_parts import ego_part_tracks
    from deepcrashtest.pipeline.extract import run_extract

    label = json.loads((Path(__file__).resolve().parents[1] / "bench" / "labels" / "bonnet_rows.json").read_text())
    top = label["dad_000512"]["centre"]
    seen = dad512_tracks[dad512_tracks["state"] == "detected"]
    at_bottom = seen.groupby("track_id").agg(top=("y1", "median"), bottom=("y2", "median"))
    bonnet = sorted(int(k) for k, r in at_bottom.iterrows() if abs(r["top"] - top) <= 60 and r["bottom"] >= 715)
    assert len(bonnet) == 1
    assert ego_part_tracks(dad512_tracks, default_camera(1280, 720), (1280, 720)) == bonnet

    run_extract(need(DATA / "crash_ccd" / "ccd_000340.mp4"), tmp_path / "out", report=False, annotate=False,
                geometry=False)  # fmt: skip
    crash = pd.read_csv(tmp_path / "out" / "tracks.csv")
    assert (crash["y2"] >= 715).any() and ((crash["x2"] - crash["x1"]) >= 640).any()  # the crash car, near
    assert ego_part_tracks(crash, default_camera(1280, 720), (1280, 720)) == []


def test_a_parked_car_is_not_dragged_by_the_scooter_passing_in_front_of_it(dad512_tracks):
    """dad_000512 (the ego stopped at a junction, two scooters crossing in front of parked cars): between detections
    a box is carried by the optical flow of the corners inside it, and the corners inside a parked car's box were the
    scooter's while it passed in front: the car's box was dragged along with it (the silver car's 720 -> 895 px in
    10 frames, the black car's at the left edge 0 -> 150 px) and the car, detected again where it stood, started a
    second track (main: tracks 2 -> 12 and 1 -> 9, the new track's first box on the old track's last detections by
    IoU 0.61 / 0.97: two cars in one place in the scenario). Corners inside the box of a road user in front
    (its bottom edge lower in the picture: ``perception.flow.occluded_points``) are now left out: no vehicle track is
    born on a box another vehicle track was detected on in the 1.5 s before (IoU >= 0.4)."""
    from deepcrashtest.perception.boxes import iou_matrix

    df = dad512_tracks
    tracks = _vehicle_detections(df)
    assert len(tracks) >= 8  # the parked cars, the bonnet, the cars arriving
    born_over = []
    for b, rb in tracks.items():
        for a, ra in tracks.items():
            before = ra[(ra[:, 0] < rb[0, 0]) & (ra[:, 0] >= rb[0, 0] - 30)]  # a's detections in the 1.5 s before b
            if a != b and len(before) and iou_matrix(rb[:1, 1:], before[:, 1:]).max() >= 0.4:
                born_over.append((a, b))
    assert born_over == []


def test_only_the_corners_in_front_of_a_box_are_left_out_of_its_flow():
    """``occluded_points``: a point of a parked car's box (bottom row 482 px) inside a scooter's box lower in the
    picture (bottom row 578 px) is the scooter's; the scooter's own points are never the car's, and a box whose
    bottom edge is within a tenth of the car's height of the car's is beside it, not in front."""
    from deepcrashtest.perception.flow import occluded_points

    boxes = np.array([[698, 387, 862, 482], [760, 320, 980, 578], [600, 380, 720, 490]], float)  # car, scooter, beside
    pts = np.array([[700, 400], [800, 450], [860, 470]], float)
    assert occluded_points(pts, 0, boxes).tolist() == [False, True, True]
    assert not occluded_points(pts, 1, boxes).any()
    assert not occluded_points(np.array([[650, 420]], float), 0, boxes).any()  # inside the box beside, not in front
    assert occluded_points(np.zeros((0, 2)), 0, boxes).shape == (0,)


def test_a_road_user_the_detector_stops_seeing_is_drawn_dashed_with_a_question_mark():
    """The tracker counts the detector's calls that missed a confirmed track (``TrackedBox.missed``), and the
    annotated video draws such a carried box dashed and labels it ``id class ?`` (ccd_001135: a car coasting 1.1 s
    across the windscreen of the car spinning in front of the ego looked like a detection there)."""
    from deepcrashtest.perception.annotate import Annotator, id_colour
    from deepcrashtest.perception.detections import Detections
    from deepcrashtest.perception.track import BoxTracker, FrameTracks

    need(CLIP)
    with open_video(CLIP) as src:
        frames = [f for f, _ in zip(src, range(12), strict=False)]
    size = (frames[0].image.shape[1], frames[0].image.shape[0])
    tracker = BoxTracker(None, fps=20.0, detect_every=2)
    car = np.array([[500.0, 300.0, 640.0, 400.0]], np.float32)
    out: list[FrameTracks] = []
    for k, fr in enumerate(frames):
        dets = None
        if k % 2 == 0:  # seen at the first three calls, then missed
            seen = k < 6
            dets = Detections(car if seen else car[:0], np.full(int(seen), 0.9, np.float32), np.array(["car"] * seen))
        out.append(tracker.update_boxes(dets, fr.index, fr.time, size, fr.image))
    missed = [ft.tracks[0].missed if ft.tracks else None for ft in out]
    assert missed[2:6] == [0, 0, 0, 0] and missed[6:10] == [1, 1, 2, 2], missed
    annotator = Annotator(fps=20.0)
    colour = np.array(id_colour(out[4].tracks[0].track_id))

    def top_edge_share(ft: FrameTracks) -> float:
        img = annotator.draw(ft)
        x1, y1, x2, _ = (int(round(v)) for v in ft.tracks[0].box)
        edge = img[y1, x1 + 100 : x2 - 5].astype(int)  # right of the label
        return float(np.mean(np.abs(edge - colour).sum(axis=1) < 60))

    assert top_edge_share(out[5]) > 0.9  # carried by the flow between two calls that saw it: a solid line
    assert 0.3 < top_edge_share(out[7]) < 0.7  # the last call missed it: dashes


def test_boxes_warp_through_a_homography_as_opencv_maps_their_corners():
    """``warp_boxes``: each edge at the mean of its two corners' images, the corners mapped as OpenCV's
    ``perspectiveTransform`` maps them; the identity leaves the boxes as they are."""
    cv2 = pytest.importorskip("cv2")
    rng = np.random.default_rng(3)
    xy = rng.uniform(0, 1000, (20, 2))
    boxes = np.c_[xy, xy + rng.uniform(5, 200, (20, 2))]
    H = np.array([[1.01, 0.02, -30.0], [-0.01, 0.99, 5.0], [1e-5, -2e-5, 1.0]])
    x1, y1, x2, y2 = boxes.T
    corners = np.stack([np.c_[x1, y1], np.c_[x2, y1], np.c_[x2, y2], np.c_[x1, y2]], axis=1)  # (n, 4, 2)
    img = cv2.perspectiveTransform(corners.reshape(-1, 1, 2), H).reshape(-1, 4, 2)
    expected = np.c_[
        (img[:, 0, 0] + img[:, 3, 0]) / 2, (img[:, 0, 1] + img[:, 1, 1]) / 2,
        (img[:, 1, 0] + img[:, 2, 0]) / 2, (img[:, 2, 1] + img[:, 3, 1]) / 2,
    ]  # fmt: skip
    np.testing.assert_allclose(warp_boxes(boxes, H), expected, rtol=1e-9, atol=1e-6)
    np.testing.assert_allclose(warp_boxes(boxes, np.eye(3)), boxes)


def test_a_camera_turning_right_moves_the_scene_left_by_its_focal_times_the_angles_tangent():
    """``rotation_homographies``: a camera yawing right by 3 deg between two frames (camera axes: x right, y down,
    z forward; the rotation about y) moves a box at the principal point left by fx tan(3 deg) and keeps its row."""
    from scipy.spatial.transform import Rotation

    from deepcrashtest.geometry.frames import rotation_homographies

    K = np.array([[700.0, 0.0, 620.0], [0.0, 700.0, 190.0], [0.0, 0.0, 1.0]])
    poses = np.repeat(np.eye(4)[None], 2, axis=0)
    poses[1, :3, :3] = Rotation.from_euler("y", 3.0, degrees=True).as_matrix()
    H = rotation_homographies(poses, K)
    assert H[0] is None
    moved = warp_boxes(np.array([[600.0, 170.0, 640.0, 210.0]]), H[1])[0]
    shift = 700.0 * np.tan(np.radians(3.0))
    assert np.mean(moved[[0, 2]]) == pytest.approx(620.0 - shift, abs=0.05)
    assert np.mean(moved[[1, 3]]) == pytest.approx(190.0, abs=0.05)


def test_tracking_boxes_needs_a_camera_motion_for_every_frame():
    """``track_boxes(..., camera_motion=...)``: a pose log shorter than the detections is a clear error."""
    from deepcrashtest.perception.detections import Detections
    from deepcrashtest.perception.track import track_boxes

    box = Detections(np.array([[100.0, 100.0, 150.0, 140.0]]), np.array([0.9]), np.array(["car"]))
    with pytest.raises(ValueError, match="camera_motion has 1 frames"):
        track_boxes([box, box], 10.0, (640, 480), camera_motion=[None])
    table = track_boxes([box, box, box], 10.0, (640, 480), camera_motion=[None, np.eye(3), np.eye(3)], min_hits=1)
    assert set(table["frame"]) == {0, 1, 2}
