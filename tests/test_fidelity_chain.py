"""The extraction chain stays consistent with the projection the fidelity metric uses (real data)."""

from __future__ import annotations

import math

import numpy as np
import pytest
from tests.conftest import KITTI_TRACKING as KITTI
from tests.conftest import need

from deepcrashtest.datasets.kitti.files import read_calib, read_labels
from deepcrashtest.geometry.selfcalib import MIN_BOXES, self_calibrate
from deepcrashtest.scenario import Camera

SIZE = (1242, 375)


@pytest.mark.parametrize("seq", ["0001", "0004", "0005", "0006", "0016"])
def test_a_few_boxes_measure_the_horizon(seq):
    """A short clip (fewer than MIN_BOXES boxes): the horizon comes from its boxes, not a wrong prior.

    KITTI's camera is mounted level (horizon near cy); the prior here is 120 px off, like the lane
    vanishing points that put CCD clips' horizons 100-200 px from their road's."""
    lab = read_labels(need(KITTI / "label_02" / f"{seq}.txt"))
    k = read_calib(KITTI / "calib" / f"{seq}.txt").K
    cars = lab[lab["type"].isin(["Car", "Van"]) & (lab["frame"] < 4)].assign(category="car")
    cam = Camera(fx=k[0, 0], fy=k[1, 1], cx=k[0, 2], cy=k[1, 2], height_m=1.65)
    wrong = cam.model_copy(update={"pitch_rad": math.atan2(120.0, cam.fy), "pitch_source": "vanishing_point"})
    cal = self_calibrate(cars, wrong, SIZE)
    assert 3 <= cal.boxes < MIN_BOXES
    assert cal.camera.pitch_source == "self_calibration" and cal.camera.horizon_sigma_px
    assert abs(cal.camera.horizon_v() - k[1, 2]) < 25.0  # measured 2-22 px
    assert cal.camera.height_m == cam.height_m and cal.camera.fy == cam.fy  # not measurable from so few
    two = self_calibrate(cars.iloc[:2], wrong, SIZE)
    assert two.camera == wrong and any("keeps its priors" in n for n in two.notes)


def test_stage2_views_the_agents_through_the_measured_ego_heading(kitti8_raw, kitti_root):
    """The processed ego's heading is the camera's measured yaw (as when the agents were placed), and
    stage 2 keeps the reprojection of the raw scenario, also when the ego turns while (nearly) at rest."""
    from deepcrashtest.eval.fidelity import evaluate_fidelity
    from deepcrashtest.trajectory.pipeline import process_scenario

    lab = read_labels(kitti_root / "label_02" / "0008.txt")
    lab = lab[lab["type"].isin(["Car", "Van", "Truck"]) & (lab["frame"] < 100)]
    tracks = lab.assign(track_id=lab["track_id"] + 1)[["frame", "track_id", "x1", "y1", "x2", "y2"]]
    raw_iou = evaluate_fidelity(kitti8_raw, tracks).reprojection["processed"]["mean_iou"]

    # the camera turns by 0.3 rad over the clip while the ego creeps (its speed scale unknown)
    e = kitti8_raw.ego.trajectory.arrays()
    turn = np.linspace(0.0, 0.3, len(e["t"]))
    creep = kitti8_raw.ego.trajectory.model_copy(
        update={"x": list(0.01 * e["x"]), "y": list(0.01 * e["y"]), "yaw": list(e["yaw"] + turn)}
    )
    slow = kitti8_raw.evolve(ego=kitti8_raw.ego.model_copy(update={"trajectory": creep}))
    for raw in (kitti8_raw, slow):
        proc = process_scenario(raw)
        r, p = raw.ego.trajectory.arrays(), proc.ego.trajectory.arrays()
        tv, rv = p["t"] - proc.source.time_offset_s, r["t"] - raw.source.time_offset_s  # video time
        video = tv >= rv[0] - 1e-6
        yaw_at = np.interp(tv[video], rv, r["yaw"])
        assert np.abs(p["yaw"][video] - yaw_at).max() < 0.02
    proc_iou = evaluate_fidelity(process_scenario(kitti8_raw), tracks).reprojection["processed"]["mean_iou"]
    assert proc_iou >= raw_iou - 0.05


def _kitti_ego(seq: str = "0001"):
    from deepcrashtest.datasets.kitti.files import read_poses
    from deepcrashtest.geometry.egomotion import EgoMotion

    poses = read_poses(need(KITTI / "orbslam3_poses" / seq / "CameraTrajectory.txt"))[:60]
    return EgoMotion.from_poses(poses, 10.0)


def test_lane_offsets_that_would_slide_the_ego_sideways_are_not_used():
    """Lane offsets replace the ego's lateral drift only while the path stays drivable with the measured
    heading; the lane-detector noise seen on crash clips (offsets jumping ~1 m) is refused, with a warning."""
    from deepcrashtest.geometry.world_tracks import MAX_SIDEWAYS_MPS, corrected_ego_path, sideways_speed
    from deepcrashtest.perception.lanes import LaneTimelineResult

    ego = _kitti_ego()  # real ORB-SLAM3 camera path of KITTI 0001 (6 s)
    n = len(ego.t)
    own = -(ego.y - ego.y[0])  # the lane offset a perfect detector reads off this very path (right of centre)
    consistent = LaneTimelineResult(ego.t, np.full(n, 3.5), -own, np.zeros(n, int), np.ones(n, bool))
    warnings: list[str] = []
    xy = corrected_ego_path(ego, consistent, warnings)
    assert not warnings and np.allclose(xy[:, 1], ego.y - ego.y[0], atol=0.1)
    assert sideways_speed(ego.t, xy, ego.yaw) < 0.1 < MAX_SIDEWAYS_MPS
    jumps = np.where((np.arange(n) // 8) % 2 == 1, 0.9, 0.0)  # the offset flips between two lines every 0.8 s
    noisy = LaneTimelineResult(ego.t, np.full(n, 3.5), -own + jumps, np.zeros(n, int), np.ones(n, bool))
    xy = corrected_ego_path(ego, noisy, warnings)
    assert np.array_equal(xy, np.column_stack([ego.x, ego.y]))
    assert any("sideways" in w for w in warnings)


def test_a_collision_with_an_agent_not_yet_seen_does_not_cut_the_video(kitti8_raw):
    """A detected crash naming a road user first seen at that moment cannot be made to happen; stage 2 must
    then keep every observed second, not end the scenario there and drop the collision afterwards."""
    from deepcrashtest.scenario import Collision
    from deepcrashtest.trajectory.pipeline import process_scenario

    late = max(kitti8_raw.agents, key=lambda a: a.trajectory.t[0])
    t_c = float(late.trajectory.t[0])
    assert t_c > 2.0
    raw = kitti8_raw.evolve(collision=Collision(time_s=t_c, other_id=0, agent_id=late.id, source="video-auto"))
    proc = process_scenario(raw)
    assert proc.collision is None and any("the whole video is kept" in w for w in proc.warnings)
    video_end = raw.video_time(float(raw.ego.trajectory.t[-1]))
    assert proc.video_time(float(proc.ego.trajectory.t[-1])) == pytest.approx(video_end, abs=0.11)
