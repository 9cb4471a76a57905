"""The monocular path on real KITTI data: boxes-only tracking, ego from poses, self-calibration,
the ground-plane 3D tracker and its world-frame score, and the KITTI result writer.

KITTI tracking sequence 0014 (106 frames, a training sequence, not one of the held-out 3, 8, 10)
keeps these fast."""

from __future__ import annotations

import dataclasses

import numpy as np
import pandas as pd
import pytest

from deepcrashtest.datasets.kitti.files import KittiSequence, read_calib, read_labels, read_poses
from deepcrashtest.datasets.kitti.results import scenario_result_table, write_results
from deepcrashtest.datasets.kitti.scenario import kitti_world_transform, scenario_from_kitti
from deepcrashtest.datasets.kitti.world import KittiWorld
from deepcrashtest.eval.clear_mot import EvalSequence, clear_only
from deepcrashtest.eval.kitti import ground_truth_frames, hypotheses_from_results, hypotheses_from_table
from deepcrashtest.eval.kitti_mono import (
    DEFAULT_MONO,
    LabelNoise,
    evaluate_mono,
    image_tracks,
    noisy_label_boxes,
    prepare_mono,
)
from deepcrashtest.eval.kitti_rules import MATCH_RULES, apply_kitti_rules
from deepcrashtest.geometry.egomotion import EgoMotion
from deepcrashtest.geometry.mono_config import Cues, MonoConfig
from deepcrashtest.geometry.mono_size import hull_factor, oblique_width, width_m
from deepcrashtest.geometry.selfcalib import focal_from_motion, self_calibrate
from deepcrashtest.scenario import Camera

SEQ = 14


@pytest.fixture(scope="module")
def prep(kitti_root):
    return prepare_mono(kitti_root, SEQ)


def test_ego_from_poses_is_the_kitti_world_path(kitti_root):
    poses = read_poses(KittiSequence(kitti_root, SEQ).poses)
    ego = EgoMotion.from_poses(poses, 10.0)
    _, ego_xy, yaw = kitti_world_transform(poses, forward_offset_m=0.0)
    assert np.allclose(np.column_stack([ego.x, ego.y]), ego_xy, atol=1e-9)
    assert np.allclose(ego.yaw, yaw)
    assert len(ego) == len(poses) and np.allclose(ego.t, np.arange(len(poses)) / 10.0)
    step = np.hypot(np.diff(ego.x), np.diff(ego.y)) * 10.0
    assert np.allclose(np.median(ego.speed), np.median(step), rtol=0.05) and ego.speed.max() < 40


def test_boxes_only_tracking_backfills_and_keeps_ids(prep):
    tracks = image_tracks(prep, DEFAULT_MONO)
    assert (tracks["track_id"] >= 1).all() and set(tracks["state"]) <= {"detected", "predicted"}
    assert not tracks.duplicated(["frame", "track_id"]).any()
    first = tracks.groupby("track_id")["frame"].min()
    detected = tracks[tracks["state"] == "detected"].groupby("track_id")["frame"].min()
    assert (first == detected).all()  # a track starts at its first detection (backfilled), not at confirmation
    assert (first == 0).sum() >= 2  # the cars seen from the first frame on keep their first frames


def test_result_writer_round_trip_scores_the_labels_perfectly(kitti_root, tmp_path):
    """Label Scenario -> KITTI result file -> read back and scored: every visible car is found."""
    sc = scenario_from_kitti(kitti_root, SEQ)
    world = KittiWorld(read_poses(KittiSequence(kitti_root, SEQ).poses))
    prep = prepare_mono(kitti_root, SEQ)
    table = scenario_result_table(sc, world, prep.P2, image_size=prep.size)
    path = write_results(table, tmp_path / "0014.txt")
    with pytest.raises(Exception, match="exists"):
        write_results(table, path)
    back = read_labels(path)
    assert len(back) == len(table) and set(back["type"]) <= {"Car", "Van", "Truck"}
    rule = MATCH_RULES["distance"]
    gt = ground_truth_frames(kitti_root, SEQ, world)
    for hyps in (hypotheses_from_table(table, world), hypotheses_from_results(path, world)):
        frames = [apply_kitti_rules(g, h, rule) for g, h in zip(gt, hyps, strict=True)]
        res = clear_only([EvalSequence("0014", frames)], rule)["0014"]
        assert res["MOTA"] > 0.95 and res["IDSW"] == 0


def test_mono_path_real_numbers_kitti_camera(kitti_root):
    """PointRCNN's 2D boxes only, ORB-SLAM3 ego, KITTI camera: a real score that can fail."""
    res = evaluate_mono(kitti_root, [SEQ])
    row = res["sequences"]["0014"]
    assert row["MOTA"] > 38.0  # measured 43.1 with the tuned defaults
    # the goal is 5 % up to 40 m (met on the held-out 3, 8, 10); on 0014 the cars 0-20 m away
    # come out 5.8 % (range bias +5.5 %, of which the hull factor's ~2 %: it over-corrects near cars),
    # 20-40 m 4.4 %
    for b, goal in (("0-20 m", 6.5), ("20-40 m", 5.0)):
        assert row["position_error"][b]["n"] > 50
        assert row["position_error"][b]["median_pct"] <= goal
    assert {"MOTA", "MOTP", "IDSW", "FP", "FN", "HOTA"} <= set(row)
    # the matched cars' headings (box-fitted, stage 1) against the labels' (modulo a half turn): measured 5.5 deg
    # median, 2 % over 20 deg (6.9 deg, 17 % before round boxfit28); facing the ego's way where nothing tells
    # (parked): 10 % the other way round
    heading = row["heading_error"]
    assert heading["n"] > 200 and heading["median_deg"] < 9.0 and heading["share_over_20_deg"] < 0.25


def test_self_calibration_recovers_the_kitti_camera(prep):
    tracks = image_tracks(prep, DEFAULT_MONO)
    start = Camera(fx=621.0, fy=621.0, cx=prep.size[0] / 2, cy=prep.size[1] / 2, height_m=1.3)
    cal = self_calibrate(tracks, start, prep.size, EgoMotion.from_poses(prep.world.poses, 10.0))
    cam = cal.camera
    assert cam.intrinsics_source == cam.pitch_source == cam.height_source == "self_calibration"
    assert abs(cam.fy / prep.camera.fy - 1.0) < 0.1  # 90-deg default is 12 % off
    motion = focal_from_motion(tracks, prep.size, start.cx, EgoMotion.from_poses(prep.world.poses, 10.0))
    assert motion is not None and abs(motion[0] / prep.camera.fy - 1.0) < 0.015  # measured -1.3 %
    assert abs(cam.height_m - 1.65) < 0.25
    assert cam.focal_sigma_px and cam.height_sigma_m and cam.horizon_sigma_px is not None
    without_ego = self_calibrate(tracks, start, prep.size, None)
    assert without_ego.camera.fy == start.fy and any("default 621 px kept" in n for n in without_ego.notes)
    # the unmeasured default focal length says how uncertain it is (the true one is 14 % longer)
    assert without_ego.camera.focal_sigma_px == pytest.approx(0.35 * start.fy)
    assert without_ego.summary()["fy_sigma"] == pytest.approx(0.35 * start.fy, abs=0.1)


def test_noisy_label_boxes_are_seeded(kitti_root, prep):
    labels = read_labels(KittiSequence(kitti_root, SEQ).labels)
    a = noisy_label_boxes(labels, prep.world.n_frames, prep.size, LabelNoise(seed=1), prep.camera)
    b = noisy_label_boxes(labels, prep.world.n_frames, prep.size, LabelNoise(seed=1), prep.camera)
    c = noisy_label_boxes(labels, prep.world.n_frames, prep.size, LabelNoise(seed=2), prep.camera)
    assert all(np.array_equal(x.boxes, y.boxes) for x, y in zip(a, b, strict=True))
    assert not all(np.array_equal(x.boxes, y.boxes) for x, y in zip(a, c, strict=True))
    n_labels = int(labels["type"].isin(["Car", "Van", "Truck", "Pedestrian", "Person"]).sum())  # every road user
    n_labels += 2 * int((labels["type"] == "Cyclist").sum())  # a rider and a bicycle
    n = sum(len(x) for x in a)
    assert 0.7 * n_labels < n < 1.3 * n_labels + 0.3 * prep.world.n_frames * 2


def test_cli_mono_json_and_bad_camera(kitti_root):
    import json

    from typer.testing import CliRunner

    from deepcrashtest.cli import app

    runner = CliRunner()
    args = ["evaluate", "kitti", "--data", str(kitti_root), "--sequences", str(SEQ), "--mono", "--json"]
    out = runner.invoke(app, args)
    assert out.exit_code == 0, out.output
    row = json.loads(out.stdout)["sequences"]["0014"]
    assert row["position_error"]["20-40 m"]["n"] > 0 and row["camera"]["sources"] == ["kitti_calib"] * 3
    from test_cli import assert_one_line_error, run

    assert_one_line_error(run(*args[:-1], "--camera", "nikon"), "--camera must be one of")


def test_hull_factor_explains_the_label_box_heights(kitti_root):
    """A car lower than the camera shows its roof: its box is taller than its near face, the more so
    the nearer it is (KITTI 0001 labels: unoccluded, untruncated cars, box height against fy H / z_near)."""
    seq = KittiSequence(kitti_root, 1)
    fy = read_calib(seq.calib).P2[1, 1]
    lab = read_labels(seq.labels)
    c = lab[(lab["type"] == "Car") & (lab["occluded"] == 0) & (lab["truncated"] == 0)]
    ext = 0.5 * (c["l"] * np.abs(np.sin(c["ry"])) + c["w"] * np.abs(np.cos(c["ry"])))
    z_near = (c["z"] - ext).to_numpy()
    ok = z_near > 5
    c, z_near = c[ok], z_near[ok]
    ratio = (c["y2"] - c["y1"]).to_numpy() / (fy * c["h"].to_numpy() / z_near)
    factor = np.array([
        hull_factor(h, ln, w, hc, np.array([z]), np.array([x / zc]))[0]
        for h, ln, w, hc, z, x, zc in zip(c["h"], c["l"], c["w"], c["y"], z_near, c["x"], c["z"], strict=True)
    ])  # fmt: skip
    assert len(c) > 300 and np.median(factor) > 1.01
    plain, hull = np.median(np.abs(np.log(ratio))), np.median(np.abs(np.log(ratio / factor)))
    assert hull < 0.9 * plain  # measured 0.018 against 0.023


def _clean_cars(kitti_root, seq_no: int) -> tuple[Camera, pd.DataFrame]:
    """A KITTI sequence's camera (left colour, 1.65 m high) and its unoccluded, untruncated labelled cars."""
    seq = KittiSequence(kitti_root, seq_no)
    p2 = read_calib(seq.calib).P2
    lab = read_labels(seq.labels)
    camera = Camera(fx=p2[0, 0], fy=p2[0, 0], cx=p2[0, 2], cy=p2[1, 2], height_m=1.65)
    return camera, lab[(lab["type"] == "Car") & (lab["occluded"] == 0) & (lab["truncated"] == 0)]


def _label_cues(c: pd.DataFrame, camera: Camera, z: np.ndarray) -> tuple[np.ndarray, np.ndarray, Cues]:
    """Label boxes' widths (px), bearings (tan) and width-cue inputs (``z``: the bottom-edge depth slot, m)."""
    box_w = (c["x2"] - c["x1"]).to_numpy()
    bearing = (0.5 * (c["x1"] + c["x2"]).to_numpy() - camera.cx) / camera.fx
    none = np.zeros(len(c), bool)
    return box_w, bearing, Cues(z, z, box_w, box_w, bearing, none, none)


def test_width_cue_reads_the_box_edges_of_cars_beside_the_axis(kitti_root):
    """A car parallel to the optical axis and off it shows its side: its box runs from the side's far end to the
    near face's outer corner. KITTI 0001 labels (unoccluded, untruncated cars heading along the axis, near face
    5-40 m): the width cue's near-face depth from the label box, the label's size and the box-edge geometry
    (``MonoConfig.width_box_edges``, off by default: it lowered the dashcam clips' reprojection IoU) is within 3 % on
    median for the cars off the axis (|tan| > 0.15; measured -0.7 %), where the extent across the
    line of sight at the box centre's bearing read them 7.2 % too far, and nearer overall (median |log| 0.051
    against 0.063)."""
    camera, c = _clean_cars(kitti_root, 1)
    fx = camera.fx
    c = c[np.abs(np.abs(c["ry"]) - np.pi / 2) < 0.1]  # heading along the optical axis
    z_near = (c["z"] - 0.5 * c["l"]).to_numpy()
    ok = (z_near > 5) & (z_near < 40)
    c, z_near = c[ok], z_near[ok]
    box_w, bearing, cues = _label_cues(c, camera, z_near)

    def log_error(cfg: MonoConfig) -> np.ndarray:
        z = [fx * width_m(ln, w, cues, np.array([i]), camera, cfg)[0] / box_w[i] for i, (ln, w) in enumerate(
            zip(c["l"], c["w"], strict=True))]  # fmt: skip
        return np.log(np.array(z) / z_near)

    new, old = log_error(MonoConfig(width_box_edges=True)), log_error(MonoConfig())
    off = np.abs(bearing) > 0.15
    assert len(c) > 300 and off.sum() > 200
    assert abs(np.median(new[off])) < 0.03 and np.median(old[off]) > 0.05
    assert np.median(np.abs(new)) < 0.9 * np.median(np.abs(old))


def test_pitch_bounce_calibrates_the_focal_where_parked_cars_mislead(kitti_root):
    """Training sequence 0004: the parked-vehicle estimate is a mode of moving cars (367 px from 11
    agreeing tracks, true 721) and the unknown camera scored MOTA -91; the boxes' fast vertical
    wobble against the ORB-SLAM3 pitch gives the focal length within 3 % (measured 725 px on the image tracks
    of round mono8, 738 px, +2.3 %, on round mono9's: tentative tracks from boxes of 0.7, more far cars)."""
    from deepcrashtest.geometry.selfcalib import focal_from_pitch

    p4 = prepare_mono(kitti_root, 4)
    tracks = image_tracks(p4, DEFAULT_MONO)
    ego = EgoMotion.from_poses(p4.world.poses, 10.0)
    assert ego.pitch is not None and np.degrees(np.ptp(ego.pitch)) < 10.0
    bounce = focal_from_pitch(tracks, p4.size, ego)
    assert bounce is not None and abs(bounce[0] / p4.camera.fy - 1.0) < 0.03 and bounce[1] < 0.05
    start = Camera(fx=621.0, fy=621.0, cx=p4.size[0] / 2, cy=p4.size[1] / 2, height_m=1.3)
    cal = self_calibrate(tracks, start, p4.size, ego)
    assert abs(cal.fy / p4.camera.fy - 1.0) < 0.04  # measured +3.1 % (mono8's tracks +1.5 %; was -48 %)
    assert cal.camera.focal_sigma_px is not None and cal.camera.focal_sigma_px < 0.08 * cal.fy  # measured 6.1 %
    # image-based ego-motion (no external pitch) measured its path with the assumed focal: no echo of it
    image_ego = dataclasses.replace(ego, pitch=None)
    echo = self_calibrate(tracks, start, p4.size, image_ego, ego_scaled_by_height=True)
    assert echo.camera.fy == start.fy and any("cannot calibrate" in n for n in echo.notes)
    assert echo.ego_scale == pytest.approx(echo.height_m / start.height_m)


def test_turn_focal_removes_the_camera_swing(prep):
    """Sequence 0014 (true fy 707 px): in a turn the camera, ahead of the rear axle, also steps sideways,
    which moves the boxes the same way as the rotation: leaving that step in read the focal length 16 %
    long (817 px); without it +6 % from the default 621 px (751 px) and +3 % from the true one."""
    from deepcrashtest.geometry.selfcalib import focal_from_rotation

    tracks = image_tracks(prep, DEFAULT_MONO)
    ego = EgoMotion.from_poses(prep.world.poses, 10.0)
    for fy0, tol in ((621.0, 0.08), (prep.camera.fy, 0.045)):
        est = focal_from_rotation(tracks, prep.size, prep.size[0] / 2, ego, fy0)
        assert est is not None and est[2] >= 100 and abs(est[0] / prep.camera.fy - 1.0) < tol, (fy0, est)


#: Held-out MOTA floors (KITTI camera, PointRCNN 2D boxes): about 2 points under what the tuned
#: defaults measure (85.93 / 66.07 / 90.17, README; round mono9's confirmation by accumulated scores, chosen
#: on the training sequences; before it 79.94 / 67.56 / 83.10), so a return to that state fails on 0003 and
#: 0010. The path is deterministic (no random choice).
HELD_OUT_FLOOR = {"0003": 83.5, "0008": 64.0, "0010": 88.0}


def test_held_out_mota_does_not_regress(kitti_root):
    """The held-out sequences 3, 8, 10 (never used to choose a setting) through the monocular path."""
    rows = evaluate_mono(kitti_root, [3, 8, 10])["sequences"]
    for name, floor in HELD_OUT_FLOOR.items():
        assert rows[name]["MOTA"] >= floor, (name, rows[name]["MOTA"])


def _rows_added_by(prep, **off_settings):
    """(ego, rows with the default settings, rows with ``off_settings``, the rows only the default adds)."""
    from deepcrashtest.eval.kitti_mono import ego_of
    from deepcrashtest.geometry.mono3d import localize_tracks

    tracks = image_tracks(prep, DEFAULT_MONO)
    ego = ego_of(prep.world)
    cfg = DEFAULT_MONO.mono
    on = localize_tracks(tracks, prep.camera, ego, prep.size, 10.0, cfg)
    off = localize_tracks(tracks, prep.camera, ego, prep.size, 10.0, dataclasses.replace(cfg, **off_settings))
    extra = on.merge(off[["track_id", "frame"]], how="left", indicator=True)
    return ego, on, off, extra[extra["_merge"] == "left_only"]


def test_far_receding_tracks_are_carried_past_their_end(kitti_root):
    """Extension rows are undetected, beyond the minimum range, and only on tracks that recede."""
    prep = prepare_mono(kitti_root, 2)  # highway: cars drive away beyond the detector's reach
    cfg = DEFAULT_MONO.mono
    ego, on, off, extra = _rows_added_by(prep, extend_s=0.0)
    assert len(extra) > 20 and not extra["detected"].any() and extra["x1"].isna().all()
    assert len(on) - len(extra) == len(off)
    ex = extra.merge(pd.DataFrame({"frame": ego.frame, "ex": ego.x, "ey": ego.y}), on="frame")
    assert len(ex) == len(extra)
    assert (np.hypot(ex["x"] - ex["ex"], ex["y"] - ex["ey"]) >= cfg.extend_min_range_m - 1.0).all()


def test_a_carried_track_is_seen_only_where_the_video_showed_it(kitti_root):
    """The extension that carries far tracks past their end (KITTI 0002: cars driving away) is the monocular
    tracker's guess, not what the video showed: the raw agent's first and last frames are its tracked ones, and
    stage 2 neither smooths nor flags the extension as observed; it continues the track by its own rules (on
    d0d1f6b the processed agents were "observed" over the whole extension, up to 4 s past their last box)."""
    from deepcrashtest.eval.kitti_mono import mono_scenario
    from deepcrashtest.trajectory.params import Stage2Params
    from deepcrashtest.trajectory.pipeline import process_scenario

    prep = prepare_mono(kitti_root, 2)
    tracks = image_tracks(prep, DEFAULT_MONO)
    raw, _ = mono_scenario(prep, DEFAULT_MONO, tracks=tracks)
    sc = process_scenario(raw)
    pad = Stage2Params().observed_pad_s
    processed = {a.id: a for a in sc.agents}
    carried = 0
    for a in raw.agents:
        rows = tracks[tracks["track_id"] == a.id]
        assert rows["frame"].min() <= a.first_frame <= a.last_frame <= rows["frame"].max()  # frames it was tracked in
        t, seen = np.asarray(a.trajectory.t), np.asarray(a.trajectory.observed, bool)
        shown = t[seen][-1] - t[seen][0] + 2 * pad
        if a.id not in processed or t[-1] - t[0] <= shown + 0.2:
            continue
        carried += 1
        p = processed[a.id].trajectory
        t_obs = np.asarray(p.t)[np.asarray(p.observed, bool)]
        assert t_obs[-1] - t_obs[0] <= shown + 1e-6
    assert carried >= 3


def test_near_ground_contacts_size_the_track(kitti_root):
    """A track's height fused with its near ground contacts (bottom edge far below the horizon) is
    closer to the labelled car's than the class prior's posterior alone, and it lifts the MOTA of
    training sequence 0006 (81.0 against 71.4 without; chosen on the 18 training sequences: 62.04 -> 63.84
    combined). On by default where the camera's height is measured (the KITTI camera's is)."""
    from deepcrashtest.eval.boxes import iou_2d
    from deepcrashtest.eval.kitti_mono import ego_of, quick_mota
    from deepcrashtest.geometry.mono3d import localize_tracks

    prep = prepare_mono(kitti_root, 6)
    tracks = image_tracks(prep, DEFAULT_MONO)
    ego = ego_of(prep.world)
    labels = read_labels(KittiSequence(kitti_root, 6).labels)
    cars = labels[labels["type"] == "Car"]
    on_cfg = DEFAULT_MONO.mono  # on by default (the KITTI camera's height is measured)
    off_cfg = dataclasses.replace(DEFAULT_MONO.mono, contact_min_below_px=None)
    errors = []
    for cfg in (on_cfg, off_cfg):
        st = localize_tracks(tracks, prep.camera, ego, prep.size, 10.0, cfg)
        st = st[st["detected"]]
        label_h: dict[int, list[float]] = {}
        for f, g in st.groupby("frame"):
            lab = cars[cars["frame"] == f]
            if len(lab):
                iou = iou_2d(g[["x1", "y1", "x2", "y2"]].to_numpy(float), lab[["x1", "y1", "x2", "y2"]].to_numpy(float))
                for k, tid in enumerate(g["track_id"]):
                    if iou[k].max() >= 0.7:
                        label_h.setdefault(int(tid), []).append(float(lab["h"].iloc[int(iou[k].argmax())]))
        height = st.groupby("track_id")["height"].first()
        errors.append({t: abs(np.log(height[t] / np.median(v))) for t, v in label_h.items() if len(v) >= 5})
    on, off = errors
    changed = [t for t in on if abs(on[t] - off[t]) > 1e-6]
    assert len(changed) >= 5
    assert np.median([on[t] for t in changed]) < np.median([off[t] for t in changed]) - 0.003
    mota_on = quick_mota([prep], DEFAULT_MONO)[0]
    mota_off = quick_mota([prep], dataclasses.replace(DEFAULT_MONO, mono=off_cfg))[0]
    assert mota_on >= 75.0 and mota_on - mota_off > 7.0, (mota_on, mota_off)


def test_tracks_without_near_contacts_size_themselves_from_their_nearest(kitti_root):
    """A track that never comes within 150 px of the horizon takes its size from its nearest ground contacts
    (bottom edge >= 90 px below the horizon, ``MonoConfig.contact_far_below_px``): on training sequence 0004
    (MOTA 45.2 against 34.6 without; 54.2 / 41.3 before the image tracker moved its carried boxes with the camera's
    rotation, ``MonoTracking.camera_motion``; chosen on the 18 training sequences: 64.55 -> 65.37 combined) only
    such tracks change, and the sizes the per-frame horizon rests on do not."""
    from deepcrashtest.eval.kitti_mono import ego_of, quick_mota
    from deepcrashtest.geometry.mono3d import localize_tracks

    prep = prepare_mono(kitti_root, 4)
    off_cfg = dataclasses.replace(DEFAULT_MONO.mono, contact_far_below_px=None)
    tracks = image_tracks(prep, DEFAULT_MONO)
    ego = ego_of(prep.world)
    on = localize_tracks(tracks, prep.camera, ego, prep.size, 10.0, DEFAULT_MONO.mono)
    off = localize_tracks(tracks, prep.camera, ego, prep.size, 10.0, off_cfg)
    assert (on["horizon_v"].fillna(-1) == off["horizon_v"].fillna(-1)).all()
    dh = on.groupby("track_id")["height"].first() - off.groupby("track_id")["height"].first()
    det = tracks[(tracks["state"] == "detected") & (tracks["y1"] > 1) & (tracks["y2"] < prep.size[1] - 2)]
    below = det["y2"] - on.groupby("track_id")["horizon_v"].median().reindex(det["track_id"]).to_numpy()
    nearest = below.groupby(det["track_id"]).max().reindex(dh.index)
    changed = dh.abs() > 1e-6
    assert changed.sum() >= 10
    assert (nearest[changed] < 150 + 10).all()  # tracks with contacts >= 150 px keep their size (horizon row +- few px)
    mota_on = quick_mota([prep], DEFAULT_MONO)[0]
    mota_off = quick_mota([prep], dataclasses.replace(DEFAULT_MONO, mono=off_cfg))[0]
    assert mota_on >= 43.0 and mota_on - mota_off > 8.0, (mota_on, mota_off)


def test_near_ground_contacts_need_a_measured_or_self_calibrated_camera_height(prep):
    """With a default camera height (a dashcam clip whose boxes could not calibrate it) the near ground contacts
    measure nothing: the tracks are exactly as without them. With the KITTI camera's measured height they change
    some tracks' heights; with a self-calibrated one (its 1-sigma given) they change them less, their shared error
    widened by that 1-sigma (``MonoConfig.contact_self_calibrated_sigmas``), and not at all without a 1-sigma."""
    from deepcrashtest.eval.kitti_mono import ego_of
    from deepcrashtest.geometry.mono3d import localize_tracks

    tracks = image_tracks(prep, DEFAULT_MONO)
    ego = ego_of(prep.world)
    off_cfg = dataclasses.replace(DEFAULT_MONO.mono, contact_min_below_px=None)
    heights = {}
    cameras = (("kitti_calib", None), ("self_calibration", 0.1), ("self_calibration", None), ("default", 0.2))
    for source, sigma in cameras:
        cam = prep.camera.model_copy(update={"height_source": source, "height_sigma_m": sigma})
        on = localize_tracks(tracks, cam, ego, prep.size, 10.0, DEFAULT_MONO.mono)
        off = localize_tracks(tracks, cam, ego, prep.size, 10.0, off_cfg)
        dh = np.log(on.groupby("track_id")["height"].first() / off.groupby("track_id")["height"].first())
        heights[(source, sigma)] = dh
    measured, self_calibrated = heights[("kitti_calib", None)], heights[("self_calibration", 0.1)]
    assert (measured.abs() > 1e-3).sum() >= 2
    changed = measured.abs() > 1e-3
    assert (self_calibrated[changed].abs() > 1e-4).all()
    assert (self_calibrated[changed].abs() < measured[changed].abs()).all()
    assert (heights[("self_calibration", None)] == 0).all() and (heights[("default", 0.2)] == 0).all()


def test_near_ground_contacts_size_the_tracks_under_a_self_calibrated_camera_height(prep):
    """An unknown camera's height, self-calibrated from the boxes (the fleet's height against the class priors), is
    the unit in which the near ground contacts measure each vehicle's own height (a van's, a low saloon's): round
    cont43 uses them there, their shared error widened by 3 of the camera height's 1-sigma. Training sequence 0014,
    unknown camera: MOTA 58.4 against 56.0 without (18 training sequences 64.52 -> 65.46, KITTI camera unchanged)."""
    from deepcrashtest.eval.kitti_mono import quick_mota

    off = dataclasses.replace(
        DEFAULT_MONO, mono=dataclasses.replace(DEFAULT_MONO.mono, contact_self_calibrated_sigmas=None)
    )
    mota_on = quick_mota([prep], DEFAULT_MONO, camera="unknown")[0]
    mota_off = quick_mota([prep], off, camera="unknown")[0]
    assert mota_on >= 57.0 and mota_on - mota_off > 1.5, (mota_on, mota_off)


def test_forward_axis_column_from_road_users_beside_the_ego_path(kitti_root):
    """Training sequence 0001: road users keep their offset from the ego path, which measures the
    column of the camera's forward axis (KITTI P2: 609.6 px) where the image centre (621.5) is 12 px off
    (measured 606.9 +- 1.2 px from 76 tracks; the calibrated camera 607.4)."""
    from deepcrashtest.geometry.selfcalib import BOX_HEIGHT_EXCESS, _usable
    from deepcrashtest.geometry.selfcalib_axis import axis_column_from_path

    p1 = prepare_mono(kitti_root, 1)
    tracks = image_tracks(p1, DEFAULT_MONO)
    ego = EgoMotion.from_poses(p1.world.poses, 10.0)
    true_cx = p1.camera.cx
    est = axis_column_from_path(_usable(tracks, p1.size), p1.camera.fy, p1.size[0] / 2, ego, BOX_HEIGHT_EXCESS)
    assert est is not None and abs(est[0] - true_cx) < 5.0 and est[1] < 5.0 and est[2] >= 30
    start = Camera(fx=621.0, fy=621.0, cx=p1.size[0] / 2, cy=p1.size[1] / 2, height_m=1.3)
    cal = self_calibrate(tracks, start, p1.size, ego)
    assert abs(cal.camera.cx - true_cx) < 5.0 < abs(start.cx - true_cx)
    assert any("forward axis column" in n for n in cal.notes)


@pytest.mark.parametrize("sequence", [18, 19])
def test_forward_axis_column_where_the_image_centre_is_far_off(kitti_root, sequence):
    """Training sequences 0018 / 0019, whose principal point (KITTI P2: 600.4 px) lies 19-20 px left of the image
    centre: the self-calibrated column lies within 6 px of it (5.3 / -1.7 px off). With the path estimate's
    bootstrap sigma inflated x 4 (before round axis34) the image-centre prior pulled it to 11.0 / 6.3 px off."""
    p = prepare_mono(kitti_root, sequence)
    tracks = image_tracks(p, DEFAULT_MONO)
    ego = EgoMotion.from_poses(p.world.poses, 10.0)
    start = Camera(fx=621.0, fy=621.0, cx=p.size[0] / 2, cy=p.size[1] / 2, height_m=1.3)
    cal = self_calibrate(tracks, start, p.size, ego)
    assert abs(start.cx - p.camera.cx) > 15.0
    assert abs(cal.camera.cx - p.camera.cx) < 6.0, (cal.camera.cx, p.camera.cx)


def test_unknown_camera_held_out_0008(kitti_root):
    """Held-out 0008 with an unknown camera (a floor): MOTA 50.69 with the image centre as the forward
    axis, 54.17 with the axis column calibrated (618.6 px, true 609.6), 52.18 on merged main (tracks
    confirmed after 3 hits), 55.85 before round axis34, 59.42 after it (616.2 px), 60.62 after round cont43 (near
    ground contacts under the self-calibrated height): the goal of 60 met; the floor leaves a few rows for another
    CPU's floating point; never used to choose a setting)."""
    rows = evaluate_mono(kitti_root, [8], camera="unknown")["sequences"]
    assert rows["0008"]["MOTA"] >= 59.5, rows["0008"]["MOTA"]


def test_cut_boxes_at_a_track_end_are_carried(prep):
    """Boxes cut at the bottom and a side (a car the ego passes: no depth cue) at a track's ends are carried by
    the motion model for at most ``carry_cut_s``, detected, and within the 2 m gate of a labelled car (median)."""
    cfg = DEFAULT_MONO.mono
    _, _, _, extra = _rows_added_by(prep, carry_cut_s=0.0)
    w, h = prep.size
    assert len(extra) >= 5 and extra["detected"].all()
    assert ((extra["y2"] >= h - 2) & ((extra["x1"] <= 1) | (extra["x2"] >= w - 2))).all()
    for _, g in extra.groupby("track_id"):
        assert len(g) <= round(cfg.carry_cut_s * 10.0) * 2
    near = []
    for _, row in extra.iterrows():  # each carried row against the nearest labelled car of its frame
        gt = prep.ground_truth[int(row["frame"])].objects.world
        near.append(np.hypot(gt[:, 0] - row["x"], gt[:, 1] - row["y"]).min() if len(gt) else np.inf)
    assert np.median(near) < 2.0


def test_confirmation_by_accumulated_scores_tracks_far_cars(kitti_root):
    """Training sequence 0002 (highway, cars receding far ahead, boxes of scores 0.7-0.97): tentative tracks
    from any kept box, confirmed once their scores add up to 3.8 (round mono9, chosen on the 18 training
    sequences: combined MOTA 63.84 -> 64.55), score 53.1; births from boxes of 0.97 only after 3 hits, 42.1. With the
    box-edge width where vehicles head along the axis (``width_edges_along_deg``) 49.7 against 38.2."""
    from deepcrashtest.eval.kitti_mono import quick_mota

    prep = prepare_mono(kitti_root, 2)
    old = dataclasses.replace(DEFAULT_MONO, new_track_score=0.97, min_hits=3, min_evidence=0.0)
    now, before = quick_mota([prep], DEFAULT_MONO)[0], quick_mota([prep], old)[0]
    assert now >= 48.0 and now - before > 7.0, (now, before)


def test_axis_column_skips_rows_across_a_bend(kitti_root):
    """Training sequences 0009 and 0020 (true column 609.6 / 607.2 px), unknown camera: where the path has
    turned between the camera and the point, a depth error moves every point across the bent path the
    same way, like a column error. Using such rows read the column +3.9 / +6.7 px off; without them +1.4 /
    +4.4 px (``selfcalib_axis.MAX_PATH_TURN_DEG``)."""
    from deepcrashtest.datasets.kitti.scenario import KITTI_CAMERA_FORWARD_OFFSET_M
    from deepcrashtest.eval.kitti_mono import ego_of
    from deepcrashtest.geometry.camera import default_camera
    from deepcrashtest.geometry.selfcalib import BOX_HEIGHT_EXCESS, _usable
    from deepcrashtest.geometry.selfcalib_axis import axis_column_from_path

    for seq, tol in ((9, 2.5), (20, 5.5)):
        p = prepare_mono(kitti_root, seq)
        tracks, ego = image_tracks(p, DEFAULT_MONO), ego_of(p.world)
        start = default_camera(*p.size).model_copy(update={"forward_offset_m": KITTI_CAMERA_FORWARD_OFFSET_M})
        cam = self_calibrate(tracks, start, p.size, ego).camera
        boxes = _usable(tracks, p.size)
        est = axis_column_from_path(boxes, cam.fy, start.cx, ego, BOX_HEIGHT_EXCESS)
        assert est is not None
        est = axis_column_from_path(boxes, cam.fy, est[0], ego, BOX_HEIGHT_EXCESS)
        assert est is not None and est[2] >= 40 and abs(est[0] - p.camera.cx) < tol, (seq, est, p.camera.cx)


def test_road_profile_from_the_tracks_follows_the_labels_road(kitti_root):
    """The road's drop below the camera against range, from the tracks alone (``MonoConfig.road_profile``, off by
    default: it did not lift training MOTA, see ``bench/tune_mono.py`` round mono12): on training sequence 0005 the
    labelled cars' road, read against the horizon rows the path used, lies ~6 % (log) further below the camera at
    45-60 m than at 12-20 m, and the profile the tracks give rises by about as much (flat road: 0)."""
    from deepcrashtest.eval.kitti_mono import ego_of
    from deepcrashtest.geometry.mono3d import localize_tracks, road_profile_of

    prep = prepare_mono(kitti_root, 5)
    tracks = image_tracks(prep, DEFAULT_MONO)
    ego = ego_of(prep.world)
    cam = prep.camera
    on = dataclasses.replace(DEFAULT_MONO.mono, road_profile=True)
    assert road_profile_of(tracks, cam, ego, prep.size, DEFAULT_MONO.mono) is None
    road = road_profile_of(tracks, cam, ego, prep.size, on)
    assert road is not None
    rise = float(np.log(road.ratio(np.array([52.5]))[0] / road.ratio(np.array([16.0]))[0]))
    states = localize_tracks(tracks, cam, ego, prep.size, 10.0, on)
    hv = states.dropna(subset=["horizon_v"]).groupby("frame")["horizon_v"].median()
    lab = read_labels(KittiSequence(kitti_root, 5).labels)
    lab = lab[lab["type"].isin(["Car", "Van"]) & (lab["occluded"] <= 1) & lab["frame"].isin(hv.index)]
    z = lab["z"].to_numpy(float)
    drop = lab["y"].to_numpy(float) + (cam.cy - hv.loc[lab["frame"]].to_numpy(float)) * z / cam.fy
    near, far = (float(np.median(np.log(drop[(z >= lo) & (z < hi)]))) for lo, hi in ((12, 20), (45, 60)))
    label_rise = far - near
    assert label_rise > 0.03, label_rise
    assert abs(rise - label_rise) < 0.5 * label_rise, (rise, label_rise)


def _label_type(rows: pd.DataFrame, labels: pd.DataFrame) -> str:
    """The label type most of a track's ``rows`` (their image boxes) cover with IoU >= 0.5 ("none": no label)."""
    from deepcrashtest.eval.boxes import iou_2d

    votes = []
    for f, box in zip(rows["frame"], rows[["x1", "y1", "x2", "y2"]].to_numpy(float), strict=True):
        lab = labels[labels["frame"] == f]
        iou = iou_2d(box[None], lab[["x1", "y1", "x2", "y2"]].to_numpy(float))[0] if len(lab) else np.zeros(0)
        votes.append(str(lab["type"].iloc[int(iou.argmax())]) if len(iou) and iou.max() >= 0.5 else "none")
    return max(set(votes), key=votes.count)


def test_heights_that_fit_no_class_leave_the_class_to_the_box_shape(kitti_root):
    """A track whose bottom edges imply a height far from every candidate class's (the road under it or the
    horizon off) carries no class evidence in its heights (``MonoConfig.class_free_height_cost``): on training
    sequence 0009 the wide-boxed labelled cars 35-70 m away that read 2.4-3.8 m tall are typed car instead of van
    (MOTA 65.0 against 60.7 without; chosen on the 18 training sequences: 65.37 -> 65.92 combined); only van ->
    car flips, mostly onto labelled cars, and every flipped track's heights lie far above the van's. Only where the
    camera's height is measured (the KITTI camera's is)."""
    from deepcrashtest.eval.kitti_mono import quick_mota

    prep = prepare_mono(kitti_root, 9)
    off_cfg = dataclasses.replace(DEFAULT_MONO.mono, class_free_height_cost=None)
    _, on, off, _ = _rows_added_by(prep, class_free_height_cost=None)
    cls_on, cls_off = (s.groupby("track_id")["category"].first() for s in (on, off))
    flipped = cls_on.index[cls_on != cls_off]
    assert len(flipped) >= 5 and (cls_off[flipped] == "van").all() and (cls_on[flipped] == "car").all()
    labels = read_labels(KittiSequence(kitti_root, 9).labels)
    cars, implied = 0, []
    for tid in flipped:
        rows = on[(on["track_id"] == tid) & on["detected"]]
        cars += _label_type(rows, labels) == "Car"
        below = (rows["y2"] - rows["horizon_v"]).to_numpy(float)
        implied.append(float(np.median((rows["y2"] - rows["y1"]).to_numpy(float) / below * prep.camera.height_m)))
    assert cars >= 0.7 * len(flipped), (cars, len(flipped))
    assert min(implied) > 2.1 * 1.1, implied  # above the van prior's 2.1 m, far above the car's 1.5 m
    # the MOTA with the standing vehicles' class choice off on both sides (it types some of those cars too: 68.5
    # against 65.6 with it on)
    moving = dataclasses.replace(DEFAULT_MONO.mono, static_class=False)
    mota_on = quick_mota([prep], dataclasses.replace(DEFAULT_MONO, mono=moving))[0]
    off_moving = dataclasses.replace(off_cfg, static_class=False)
    mota_off = quick_mota([prep], dataclasses.replace(DEFAULT_MONO, mono=off_moving))[0]
    assert mota_on >= 63.0 and mota_on - mota_off > 3.0, (mota_on, mota_off)
    # a self-calibrated camera height (every dashcam clip without a calibration) keeps the classes as they were
    from deepcrashtest.eval.kitti_mono import ego_of
    from deepcrashtest.geometry.mono3d import localize_tracks

    tracks, cam = image_tracks(prep, DEFAULT_MONO), prep.camera.model_copy(update={"height_source": "self_calibration"})
    on_s, off_s = (
        localize_tracks(tracks, cam, ego_of(prep.world), prep.size, 10.0, c) for c in (DEFAULT_MONO.mono, off_cfg)
    )
    assert on_s["category"].equals(off_s["category"]) and on_s["x"].equals(off_s["x"])


def test_box_edge_width_where_vehicles_head_along_the_axis_brings_near_cars_closer(kitti_root):
    """The width cue reads the box's edges (``MonoConfig.width_box_edges``' geometry) for the rows where a first
    pass of the track heads along the camera's axis or against it within 20 degrees, or stands
    (``width_edges_along_deg``, on by default; crossing and turning vehicles keep the centre-bearing geometry, so
    the dashcam crash clips keep their reprojection IoU). Training sequence 0001 (parked cars beside the ego's
    path), KITTI camera: the median position error of matched cars 0-20 m away falls (measured 4.16 -> 3.97 %,
    the 18 training sequences' n-weighted mean 4.57 -> 4.39 %, unknown camera 5.10 -> 4.87 %). The standing-vehicle
    fit is off on both sides: it places most of those parked cars by the ego's parallax (3.41 against 3.48 %)."""
    moving = dataclasses.replace(DEFAULT_MONO.mono, static_fit=False)
    on = dataclasses.replace(DEFAULT_MONO, mono=moving)
    off = dataclasses.replace(DEFAULT_MONO, mono=dataclasses.replace(moving, width_edges_along_deg=0.0))
    near = [evaluate_mono(kitti_root, [1], config=cfg)["sequences"]["0001"]["position_error"]["0-20 m"] for cfg in (
        on, off)]  # fmt: skip
    assert near[0]["n"] > 500
    assert near[0]["median_pct"] < near[1]["median_pct"] - 0.1  # 3.97 against 4.16


def _width_cue_centre_error(kitti_root, seq_no: int, turned: bool) -> np.ndarray:
    """Log error of the centre depth the width cue gives for a KITTI sequence's unoccluded, untruncated cars turned
    more than 20 degrees against the camera's axis (centre 5-40 m), from the label box and size, with the label's
    heading (``turned``: :func:`~deepcrashtest.geometry.mono_size.oblique_width`) or the centre-bearing geometry."""
    camera, c = _clean_cars(kitti_root, seq_no)
    fx = camera.fx
    rel = -c["ry"].to_numpy() - np.pi / 2  # heading left of the optical axis (KITTI ry: about camera y)
    keep = (np.abs(np.sin(rel)) > np.sin(np.radians(20))) & (c["z"] > 5).to_numpy() & (c["z"] < 40).to_numpy()
    c, rel = c[keep], rel[keep]
    box_w, bearing, cues = _label_cues(c, camera, c["z"].to_numpy())
    a = np.arctan(bearing)
    off = 0.5 * (c["l"].to_numpy() * np.abs(np.cos(a)) + c["w"].to_numpy() * np.abs(np.sin(a))) * np.cos(a)
    z = np.array([
        fx * width_m(ln, w, cues, np.array([i]), camera, MonoConfig(), None, rel[i : i + 1] if turned else None)[0]
        / box_w[i] for i, (ln, w) in enumerate(zip(c["l"], c["w"], strict=True))
    ])  # fmt: skip
    return np.log((z + off) / c["z"].to_numpy())


def test_oblique_width_reads_the_depth_of_cars_turned_against_the_axis(kitti_root):
    """A car turned against the camera's axis spans its footprint's corners in the image, not its extent across
    the line of sight as if parallel to the axis. KITTI 0001 and 0011 labels (unoccluded, untruncated cars turned
    more than 20 degrees, centre 5-40 m): the centre depth the width cue gives from the label box, size and heading
    with :func:`~deepcrashtest.geometry.mono_size.oblique_width` (``MonoConfig.width_oblique``) is within 1 % on
    median (measured 0.3 / 0.4 %), where the centre-bearing geometry misses it by more than 20 % (measured 26 /
    25 %)."""
    for s in (1, 11):
        new, old = (_width_cue_centre_error(kitti_root, s, turned) for turned in (True, False))
        assert len(new) > 150
        assert np.median(np.abs(new)) < 0.01 < 0.2 < np.median(np.abs(old))
    one = oblique_width(4.0, 1.8, np.array([0.25]), np.array([0.3]), np.array([1.0]))
    assert one.shape == (1,) and 0.5 < float(one[0]) < 10.0


def test_forward_axis_column_from_standing_vehicles(kitti_root):
    """Training sequence 0011: parked cars seen from the moving ego, each fitted as one standing point with a
    bearing offset common to its boxes, measure the column of the camera's forward axis (KITTI P2: 609.6 px;
    measured 609.2 px from 22 tracks) where the road users beside the ego path read it 15 px off (624.8 +- 14.8),
    and the self-calibrated camera keeps it within a few pixels (609.4; the unknown camera's MOTA on 0011 59.6 ->
    85.0, on the 18 training sequences 61.15 -> 64.10)."""
    from deepcrashtest.geometry.selfcalib import BOX_HEIGHT_EXCESS, _usable
    from deepcrashtest.geometry.selfcalib_axis import axis_column_from_path, axis_column_from_standing

    prep = prepare_mono(kitti_root, 11)
    tracks = image_tracks(prep, DEFAULT_MONO)
    ego = EgoMotion.from_poses(prep.world.poses, 10.0)
    boxes, fy, centre, true_cx = _usable(tracks, prep.size), prep.camera.fy, prep.size[0] / 2, prep.camera.cx
    standing = axis_column_from_standing(boxes, fy, fy, centre, ego)
    assert standing is not None and abs(standing[0] - true_cx) < 3.0 and standing[2] >= 10, standing
    path = axis_column_from_path(boxes, fy, centre, ego, BOX_HEIGHT_EXCESS)
    assert path is not None and abs(path[0] - true_cx) > 10.0  # what the standing vehicles mend here
    start = Camera(fx=621.0, fy=621.0, cx=centre, cy=prep.size[1] / 2, height_m=1.3)
    cal = self_calibrate(tracks, start, prep.size, ego)
    assert abs(cal.camera.cx - true_cx) < 4.0 and any("standing vehicles" in n for n in cal.notes), cal.camera.cx


def test_standing_cars_are_placed_by_the_parallax_of_the_ego_motion(kitti_root):
    """Training sequence 0000 drives past parked cars: the tracks the standing-vehicle fit places
    (``MonoConfig.static_fit``; 5 tracks) stand still, lie nearer their labelled cars than the moving-filter
    estimate (median 0.51 m against 1.08 m over 213 matched rows), and lift the sequence's MOTA (76.7 against
    38.6 without; gates chosen on the 18 training sequences: 65.75 -> 69.86 combined, unknown camera 60.87 ->
    61.15)."""
    from deepcrashtest.eval.boxes import iou_2d
    from deepcrashtest.eval.kitti_mono import quick_mota

    prep = prepare_mono(kitti_root, 0)
    _, on, off, _ = _rows_added_by(prep, static_fit=False)
    standing = on.groupby("track_id")["speed"].max() == 0.0
    placed = standing[standing].index
    assert len(placed) >= 3
    err_on, err_off = [], []
    for states, errs in ((on, err_on), (off, err_off)):
        rows = states[states["track_id"].isin(placed) & states["detected"]]
        for f, g in rows.groupby("frame"):
            gt = prep.ground_truth[int(f)].objects  # labelled cars and vans: image boxes, world centres
            if not len(gt.ids):
                continue
            iou = iou_2d(g[["x1", "y1", "x2", "y2"]].to_numpy(float), gt.boxes2d.astype(float))
            xy = g[["x", "y"]].to_numpy(float)
            errs += [
                float(np.hypot(*(xy[k] - gt.world[int(iou[k].argmax()), :2])))
                for k in range(len(g))
                if iou[k].max() >= 0.5
            ]
    assert len(err_on) >= 50 and np.median(err_on) < 0.8 * np.median(err_off), (np.median(err_on), np.median(err_off))
    mota_on = quick_mota([prep], DEFAULT_MONO)[0]
    mota_off = quick_mota(
        [prep], dataclasses.replace(DEFAULT_MONO, mono=dataclasses.replace(DEFAULT_MONO.mono, static_fit=False))
    )[0]
    assert mota_on >= 70.0 and mota_on - mota_off > 20.0, (mota_on, mota_off)


def test_standing_vehicles_take_the_class_their_parallax_height_fits(kitti_root):
    """A standing vehicle's height measured by the ego's parallax (the standing fit with a loose size prior,
    ``MonoConfig.static_class``) chooses between car and van: on training sequence 0001 the track it retypes (a
    labelled car the bottom edges typed van) is typed as its label says, and the sequence's MOTA rises (69.9
    against 66.6 without; 18 training sequences: 69.86 -> 70.20, unknown camera 64.10 -> 64.33)."""
    from deepcrashtest.eval.kitti_mono import quick_mota

    prep = prepare_mono(kitti_root, 1)
    _, on, off, _ = _rows_added_by(prep, static_class=False)
    cls_on, cls_off = (s.groupby("track_id")["category"].first() for s in (on, off))
    common = cls_on.index.intersection(cls_off.index)
    flipped = common[cls_on[common] != cls_off[common]]
    labels = read_labels(KittiSequence(kitti_root, 1).labels)
    right = 0
    for tid in flipped:
        right += _label_type(on[(on["track_id"] == tid) & on["detected"]], labels).lower() == cls_on[tid]
    assert len(flipped) >= 1 and right == len(flipped), (right, len(flipped))
    off_cfg = dataclasses.replace(DEFAULT_MONO, mono=dataclasses.replace(DEFAULT_MONO.mono, static_class=False))
    mota_on, mota_off = quick_mota([prep], DEFAULT_MONO)[0], quick_mota([prep], off_cfg)[0]
    assert mota_on - mota_off > 2.0, (mota_on, mota_off)


def _through_lens(boxes: np.ndarray, camera: Camera, dist: list[float], size: tuple[int, int]) -> np.ndarray:
    """The boxes a detector would give on the image of a lens with OpenCV distortion ``dist`` (same intrinsics):
    around each box's outline mapped through the lens; a side on the frame's border stays there (the road user
    goes on beyond the frame)."""
    import cv2

    t = np.linspace(0.0, 1.0, 9)
    out = np.array(boxes, dtype=np.float32)
    for i, (x1, y1, x2, y2) in enumerate(boxes):
        xs = np.r_[x1 + (x2 - x1) * t, x1 + (x2 - x1) * t, np.full(9, x1), np.full(9, x2)]
        ys = np.r_[np.full(9, y1), np.full(9, y2), y1 + (y2 - y1) * t, y1 + (y2 - y1) * t]
        rays = np.stack([(xs - camera.cx) / camera.fx, (ys - camera.cy) / camera.fy, np.ones_like(xs)], 1)
        p, _ = cv2.projectPoints(rays, np.zeros(3), np.zeros(3), camera.matrix(), np.array(dist))
        p = p.reshape(-1, 2)
        out[i] = [p[:, 0].min(), p[:, 1].min(), p[:, 0].max(), p[:, 1].max()]
    w, h = size
    at = np.array(boxes) <= 1, np.array(boxes) >= np.array([w, h, w, h]) - 2
    out[:, :2] = np.where(at[0][:, :2], 0.0, out[:, :2])
    out[:, 2:] = np.where(at[1][:, 2:], np.array([w - 1, h - 1]), out[:, 2:])
    return out


def test_a_wide_angle_lens_given_with_the_camera_is_taken_out_of_the_boxes_before_they_are_placed(kitti_root):
    """KITTI 0001's PointRCNN boxes as a barrel-distorting wide-angle lens (k1 -0.3, k2 0.08: ~140 px at the
    frame's sides) would show them. Placed as pinhole boxes the road users land metres off (MOTA 72.8 -> 33.1);
    with the lens in the camera (a chessboard calibration's distortion) every box is measured in the pinhole
    image first (``camera.undistort_boxes``) and the monocular path scores within 3 points of the undistorted
    boxes (70.3). Before, a given distortion was used by the ego-motion and the drawings but not by localisation."""
    from deepcrashtest.eval.kitti_mono import quick_mota
    from deepcrashtest.perception.detections import Detections

    dist = [-0.3, 0.08, 0.0, 0.0, 0.0]
    prep = prepare_mono(kitti_root, 1)
    lensed = dataclasses.replace(
        prep,
        detections=[
            Detections(_through_lens(d.boxes, prep.camera, dist, prep.size), d.scores, d.categories)
            for d in prep.detections
        ],
    )
    pinhole = quick_mota([prep], DEFAULT_MONO)[0]
    ignored = quick_mota([lensed], DEFAULT_MONO)[0]
    with_lens = quick_mota([dataclasses.replace(lensed, camera=prep.camera.model_copy(update={"distortion": dist}))],
                           DEFAULT_MONO)[0]  # fmt: skip
    assert ignored < pinhole - 20
    assert with_lens > pinhole - 4


def test_box_headings_of_a_street_of_parked_cars_follow_the_labels(kitti_root):
    """KITTI 0001 (training; a street lined with parked cars seen obliquely, cars driving through): the monocular
    path's box-fitted headings of the matched cars come within a few degrees of the labels'. A box's span IoU
    counts only as far as the box fits at all (a Gaussian in its shortfall, its own best fit the noise): before
    round boxfit28 a reward linear in the IoU let a box a few per cent narrower turn a car 30 deg off the road
    and off its direction of motion (median 20.1 deg, 50 % over 20 deg)."""
    heading = evaluate_mono(kitti_root, [1])["sequences"]["0001"]["heading_error"]
    assert heading["n"] > 1000
    assert heading["median_deg"] < 10.0  # measured 6.6
    assert heading["share_over_20_deg"] < 0.3  # measured 0.18


def test_frame_size_of_a_sequence_whose_boxes_never_reach_the_bottom(kitti_root):
    """0012's label and PointRCNN boxes end at row 272 of its 375: the frame's size (an unknown camera's principal
    point is its centre) comes from the boxes' width and KITTI's frame aspect, as for every other sequence's boxes."""
    assert prepare_mono(kitti_root, 12).size == (1242, 375)
    assert prepare_mono(kitti_root, 16).size == (1224, 370)


def test_the_per_frame_horizon_follows_the_boxes_at_a_videos_detector_cadence():
    """``frame_horizon`` where the detector ran on every 3rd frame only (a video's cadence) and the camera pitched
    steadily (its horizon rising 1.5 px a frame): the horizon of the frames with boxes follows it, and the frames
    between take it linearly; a gap longer than ``HORIZON_GAP_FRAMES`` (no road user in view) keeps the camera's.
    Before, the frames between counted as measured offsets of 0 and the 3-frame median erased every measured one:
    the horizon never moved on a video."""
    from deepcrashtest.geometry.mono3d import HORIZON_GAP_FRAMES, frame_horizon

    cam = Camera(fx=700.0, fy=700.0, cx=600.0, cy=180.0, height_m=1.5)
    frames = np.arange(40)
    true_h = 180.0 - 1.5 * frames  # the camera's horizon row at each frame, px
    z = 20.0 + 0.5 * frames  # one car's depth, m
    seen = (frames % 3 == 0) & (frames < 30)
    v_bottom = true_h + cam.fy * cam.height_m / z
    z_size = np.where(seen, z, np.nan)  # the boxes' depths from their size, where the detector saw them
    rows = frame_horizon(frames, v_bottom, z_size, cam, 180.0, shrink=0.0)
    inside = frames < 28
    assert np.allclose(rows[inside], true_h[inside], atol=1e-6)  # measured and between: the camera's pitching
    assert np.allclose(rows[frames >= 28 + HORIZON_GAP_FRAMES], 180.0)  # long after the last box: the clip's


def test_the_monocular_path_at_a_videos_detector_cadence(kitti_root):
    """KITTI 0018 (training) with PointRCNN's boxes of every 2nd frame only, as ``extract``'s detector runs at 10
    fps (``evaluate kitti --mono --detect-every 2``): close to the path fed every frame (measured 79.5 against
    79.3). Before the per-frame horizon worked at a video's cadence it scored 8.6: the cars placed by a horizon
    that never followed the camera's pitch."""
    every = evaluate_mono(kitti_root, [18], detect_every=2)
    assert "one frame in 2" in every["hypotheses"] and every["tracker"]["detect_every"] == 2
    assert every["sequences"]["0018"]["MOTA"] >= 72.0


def test_a_track_needs_the_same_time_seen_at_a_videos_detector_cadence(kitti_root):
    """``min_detected`` counts detected frames at every frame (0.8 s at 10 fps): with the boxes of every 2nd frame a
    track needs half as many, the same time span. KITTI 0000 (training) at that cadence: measured 76.3 (66.0 while
    a track needed 8 detected frames, 1.6 s: its short tracks of cars passed at close range dropped)."""
    assert dataclasses.replace(DEFAULT_MONO, detect_every=2).min_detected_frames == 4
    assert dataclasses.replace(DEFAULT_MONO, detect_every=3).min_detected_frames == 3
    every = evaluate_mono(kitti_root, [0], detect_every=2)
    assert every["sequences"]["0000"]["MOTA"] >= 72.0


def test_boxes_carried_between_detections_turn_with_the_camera(kitti_root):
    """Without pixels the image tracker carries a box between detections by its own image velocity; the camera's
    rotation between frames, read from the poses (``MonoTracking.camera_motion``), moves it first. KITTI 0004
    (training; the ego turns 98 deg) with the boxes of every 2nd frame: MOTA measured 38.0 against 9.5 with constant
    image velocity alone (18 training sequences at that cadence: combined 64.79 -> 67.34 with the KITTI camera,
    48.30 -> 52.56 unknown; at every frame 70.44 -> 70.87 and 64.27 -> 64.52)."""
    from deepcrashtest.eval.kitti_mono import quick_mota

    prep = prepare_mono(kitti_root, 4)
    video = dataclasses.replace(DEFAULT_MONO, detect_every=2)
    mota_on = quick_mota([prep], video)[0]
    mota_off = quick_mota([prep], dataclasses.replace(video, camera_motion=False))[0]
    assert mota_on >= 33.0 and mota_on - mota_off > 20.0, (mota_on, mota_off)


def test_turns_and_bounce_calibrate_the_focal_at_a_videos_detector_cadence(kitti_root, prep):
    """With boxes of every 2nd frame only (a video's detector at 10 fps) the turn estimate of sequence 0014 and the
    pitch-bounce estimate of 0004 read the detections at their cadence (measured 728 px against the true 707, 91
    box pairs; 0004's bounce 722 px against 721.5): before, both needed detections in consecutive frames and
    measured nothing, and the unknown camera's focal length rested on parked and moving vehicles alone (18 training
    sequences at this cadence: combined MOTA 38.7 -> 47.7)."""
    from deepcrashtest.geometry.selfcalib import focal_from_pitch, focal_from_rotation

    video = dataclasses.replace(DEFAULT_MONO, detect_every=2)
    tracks = image_tracks(prep, video)
    assert set(tracks.loc[tracks["state"] == "detected", "frame"] % 2) == {0}
    ego = EgoMotion.from_poses(prep.world.poses, 10.0)
    turn = focal_from_rotation(tracks, prep.size, prep.size[0] / 2, ego, prep.camera.fy)
    assert turn is not None and turn[2] >= 50 and abs(turn[0] / prep.camera.fy - 1.0) < 0.06, turn
    p4 = prepare_mono(kitti_root, 4)
    bounce = focal_from_pitch(image_tracks(p4, video), p4.size, EgoMotion.from_poses(p4.world.poses, 10.0))
    assert bounce is not None and abs(bounce[0] / p4.camera.fy - 1.0) < 0.05, bounce
