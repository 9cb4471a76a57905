"""The world tracker and its parts: lifecycle, Kalman association, offline pass, box geometry."""

from __future__ import annotations

import numpy as np
import pytest

from deepcrashtest.datasets.kitti.boxes import project_box
from deepcrashtest.datasets.kitti.track_smoothing import OfflineConfig, offline_tracks
from deepcrashtest.datasets.kitti.world_tracker import (
    WorldDetections,
    WorldTracker,
    WorldTrackerConfig,
)
from deepcrashtest.eval.boxes import iou_2d, iou_3d
from deepcrashtest.perception.lifecycle import TrackBase, TrackCore, TrackState


def test_lifecycle_is_the_shared_core_with_ids_at_birth():
    core: TrackCore[TrackBase] = TrackCore(min_hits=3, max_misses=2, ids_at_birth=True)
    life = core.spawn(TrackBase())
    assert life.state is TrackState.TENTATIVE and life.track_id == 1  # reported during the warm-up
    for _ in range(2):
        core.hit(life)
    assert life.confirmed and life.track_id == 1
    for _ in range(2):
        core.miss(life)
    assert life.confirmed  # 2 misses allowed
    core.miss(life)
    assert life.state is TrackState.DELETED
    tentative = core.spawn(TrackBase())
    assert tentative.track_id == 2
    core.miss(tentative)
    assert tentative.state is TrackState.DELETED  # a tentative track dies on its first miss


def _dets(points, score=5.0):
    pts = np.array(points, dtype=float).reshape(-1, 2)
    n = len(pts)
    return WorldDetections(pts, np.zeros(n), np.tile([4.0, 1.8, 1.5], (n, 1)), np.zeros(n), np.full(n, score))


def test_two_crossing_cars_keep_their_ids_through_misses():
    """Two cars on crossing straight paths at 10 m/s, one detection missing every 4th frame."""
    cfg = WorldTrackerConfig(min_hits=2, max_age=3, birth_score=0.0)
    tracker = WorldTracker(cfg)
    ids_a, ids_b = set(), set()
    for k in range(60):
        t = k * 0.1
        a, b = (t * 10.0, 0.0), (30.0 - t * 10.0, 1.5 + 0.0 * t)
        pts = [a, b] if k % 4 else [a]
        out = tracker.step(_dets(pts))
        for o in out:
            if o.detected:
                near_a = np.hypot(*(o.box[:2] - a)) < 1.0
                (ids_a if near_a else ids_b).add(o.track_id)
    assert len(ids_a) == 1 and len(ids_b) == 1 and ids_a != ids_b
    hist = {h.track_id: h for h in tracker.histories()}
    v = np.diff(hist[next(iter(ids_a))].boxes[-10:, 0]).mean() / 0.1
    assert v == pytest.approx(10.0, rel=0.05)


def test_weak_detections_extend_but_do_not_start_tracks():
    tracker = WorldTracker(WorldTrackerConfig(min_hits=1, birth_score=2.0, min_score=0.0))
    assert tracker.step(_dets([(0, 0)], score=1.0)) == []
    tracker.step(_dets([(0, 0)], score=3.0))
    out = tracker.step(_dets([(0.5, 0)], score=1.0))
    assert len(out) == 1 and out[0].detected


def test_offline_pass_fills_gaps_extends_and_drops_short_tracks():
    """A car at 10 m/s seen with weak detections for its first 5 frames, a 10-frame hole, and a
    2-frame false alarm."""
    frames = []
    for k in range(40):
        pts, scores = [], []
        if not 15 <= k < 25:
            pts.append((k * 1.0, 0.0))
            scores.append(0.5 if k < 5 else 5.0)
        if k in (30, 31):
            pts.append((0.0, 20.0))
            scores.append(5.0)
        d = _dets(pts) if pts else _dets(np.zeros((0, 2)))
        frames.append(WorldDetections(d.xy, d.z, d.size, d.yaw, np.array(scores)))
    tracker = WorldTracker(WorldTrackerConfig(min_hits=2, max_age=2, birth_score=2.0, min_score=1.0))
    for d in frames:
        tracker.step(d)
    assert len(tracker.histories()) == 3  # before the hole, after it, the false alarm
    cfg = OfflineConfig(min_detections=3, max_gap=15, extend_max_gap=3, extend_min_score=0.0)
    out = offline_tracks(tracker.histories(), cfg, frames)
    assert len(out) == 1
    (t,) = out
    np.testing.assert_array_equal(t.frames, np.arange(40))
    np.testing.assert_allclose(t.boxes[:, 0], np.arange(40.0), atol=0.2)


def test_iou_2d_matches_trackeval():
    from deepcrashtest.eval.compat import trackeval_metrics

    trackeval_metrics()  # quiet import
    from trackeval.datasets._base_dataset import _BaseDataset

    rng = np.random.default_rng(0)
    a = np.sort(rng.uniform(0, 100, (20, 2, 2)), axis=1).transpose(0, 2, 1).reshape(20, 4)[:, [0, 2, 1, 3]]
    b = np.sort(rng.uniform(0, 100, (15, 2, 2)), axis=1).transpose(0, 2, 1).reshape(15, 4)[:, [0, 2, 1, 3]]
    want = _BaseDataset._calculate_box_ious(a, b, box_format="x0y0x1y1")
    np.testing.assert_allclose(iou_2d(a, b), want, atol=1e-12)


def test_iou_3d_analytic():
    box = np.array([[0.0, 0.0, 0.0, 2.0, 2.0, 1.0, 0.0]])
    assert iou_3d(box, box)[0, 0] == pytest.approx(1.0)
    turned = box.copy()
    turned[0, 6] = np.pi / 4  # a square and itself turned 45 degrees: a regular octagon overlap
    inter = 8 * (np.sqrt(2) - 1)  # octagon area for side-2 squares
    assert iou_3d(box, turned)[0, 0] == pytest.approx(inter / (8 - inter), rel=1e-9)
    half_up = box.copy()
    half_up[0, 2] = 0.5  # same footprint, half the height overlapping
    assert iou_3d(box, half_up)[0, 0] == pytest.approx(1 / 3)
    far = box.copy()
    far[0, 0] = 10.0
    assert iou_3d(box, far)[0, 0] == 0.0
    assert iou_3d(box, np.full((1, 7), np.nan))[0, 0] == 0.0


def test_project_box_behind_camera_and_in_front():
    P = np.array([[700.0, 0, 600, 0], [0, 700, 180, 0], [0, 0, 1, 0]])
    box = project_box(P, np.array([0.0, 1.6, 20.0]), 4.0, 1.8, 1.5, 0.0, (1242, 375))
    assert box[0] < 600 < box[2] and box[1] < 180 + 700 * 1.6 / 20 <= box[3] + 1e-9
    assert np.isnan(project_box(P, np.array([0.0, 1.6, -5.0]), 4.0, 1.8, 1.5, 0.0, (1242, 375))).all()
