"""Pedestrians and cyclists through the monocular path on real KITTI labels (``evaluate kitti --class``): the KITTI
class rules, the noise model measured on PointRCNN's boxes, a cyclist seen as a detector sees it, walkers side by
side kept apart from the riders of a hidden scooter, and the monocular placement of pedestrians."""

from __future__ import annotations

import numpy as np
import pytest

from deepcrashtest.datasets.kitti.files import KittiSequence, read_ab3dmot_detections, read_labels
from deepcrashtest.datasets.kitti.world import KittiWorld
from deepcrashtest.eval.kitti import ground_truth_frames
from deepcrashtest.eval.kitti_mono import (
    DEFAULT_MONO,
    LabelNoise,
    _detector_view,
    evaluate_mono,
    noisy_label_boxes,
    prepare_mono,
)
from deepcrashtest.eval.kitti_rules import KITTI_CLASSES
from deepcrashtest.perception.boxes import iou_matrix
from deepcrashtest.perception.detections import Detections
from deepcrashtest.perception.roadusers import rider_groups, road_users

#: Training sequences with pedestrians and cyclists, none of the held-out 3, 8, 10, 13, 16.
PEDESTRIANS = 17  # 782 pedestrians and 101 cyclists, no car
CYCLISTS = 12  # 41 cyclist and 64 pedestrian labels, 144 cars: small and quick


def test_pedestrian_ground_truth_keeps_sitting_people_as_distractors(kitti_root):
    """TrackEval's KITTI rules for the pedestrian class: Pedestrians are evaluated (unless occluded beyond 2 or
    truncated), KITTI's sitting people ("Person") are distractors, cars take no part."""
    seq = 19
    labels = read_labels(KittiSequence(kitti_root, seq).labels)
    from deepcrashtest.datasets.kitti.files import read_poses

    world = KittiWorld(read_poses(KittiSequence(kitti_root, seq).poses))
    frames = ground_truth_frames(kitti_root, seq, world, KITTI_CLASSES["pedestrian"])
    n_objects = sum(len(g.objects) for g in frames)
    n_evaluated = sum(int(g.evaluated.sum()) for g in frames)
    kinds = labels[labels["track_id"] >= 0]["type"]
    assert n_objects == int(kinds.isin(["Pedestrian", "Person"]).sum())
    ped = labels[(labels["type"] == "Pedestrian") & (labels["occluded"] <= 2) & (labels["truncated"] <= 0)]
    assert n_evaluated == len(ped) and 0 < n_evaluated < n_objects


def test_label_noise_scores_follow_pointrcnn_and_cars_are_tracked(kitti_root):
    """The noise model's scores are drawn from PointRCNN's measured ones (its uniform 0.6-1.0 had put every track's
    mean score under the tracker's ``min_confidence`` 0.9: MOTA 0 on every sequence); cars on label boxes are tracked
    again, and a seed makes the boxes."""
    prep = prepare_mono(kitti_root, 1, "labels-noisy")
    scores = np.concatenate([d.scores for d in prep.detections])
    floor = DEFAULT_MONO.min_confidence  # a track's mean detection score must beat it
    assert np.median(scores) >= 0.99 and np.median(scores) > floor
    table = read_ab3dmot_detections(KittiSequence(kitti_root, 1).detections_pointrcnn)
    pointrcnn = 1 / (1 + np.exp(-table["score"].to_numpy(float)))
    assert np.median(pointrcnn) > 0.95 and np.median(pointrcnn) > floor
    row = evaluate_mono(kitti_root, [1], boxes="labels-noisy")["sequences"]["0001"]
    assert row["MOTA"] > 30 and row["TP"] > 1000, row  # 0.0 with TP 6 before
    labels = read_labels(KittiSequence(kitti_root, 1).labels)
    a = noisy_label_boxes(labels, prep.world.n_frames, prep.size, LabelNoise(seed=3), prep.camera)
    b = noisy_label_boxes(labels, prep.world.n_frames, prep.size, LabelNoise(seed=3), prep.camera)
    assert all(np.array_equal(x.boxes, y.boxes) for x, y in zip(a, b, strict=True))


def test_a_cyclist_is_seen_as_its_rider_and_bicycle_and_joined_again(kitti_root):
    """A detector reports a cyclist as a person and a bicycle; ``road_users`` joins them into one ``bicycle`` box,
    which is the label's box again (KITTI 0012's 41 cyclist labels, no noise)."""
    labels = read_labels(KittiSequence(kitti_root, CYCLISTS).labels)
    view = _detector_view(labels)
    cyc = labels[labels["type"] == "Cyclist"]
    assert len(view) == int(labels["type"].isin(["Car", "Van", "Truck", "Pedestrian", "Person"]).sum()) + 2 * len(cyc)
    ious = []
    for f, lab in cyc.groupby("frame"):
        rows = view[view["frame"] == f]
        det = Detections(
            rows[["x1", "y1", "x2", "y2"]].to_numpy(np.float32), np.ones(len(rows), np.float32),
            rows["category"].to_numpy(str),
        )  # fmt: skip
        users = road_users(det, picture=(0, 0, 1242, 375))
        bikes = users.boxes[users.categories == "bicycle"]
        assert not (users.categories == "pedestrian").sum() > (rows["category"] == "pedestrian").sum() - len(lab)
        ious.extend(iou_matrix(lab[["x1", "y1", "x2", "y2"]].to_numpy(float), bikes.astype(float)).max(axis=1))
    assert len(ious) == len(cyc) and np.median(ious) > 0.99 and np.mean(np.array(ious) > 0.9) > 0.95


@pytest.mark.parametrize(("picture", "share"), [(None, 0.008), ((0.0, 0.0, 1242.0, 375.0), 0.011)])
def test_walkers_side_by_side_are_not_riders_of_a_hidden_scooter(kitti_root, picture, share):
    """Two walkers at the same distance overlapping side by side stay two pedestrians: only a squat box over another
    or two boxes reaching the picture's lowest rows are riders of a hidden two-wheeler. On the pedestrian labels of
    the 16 training sequences other than 3, 8, 10, 13, 16 the rule without those conditions joined 3.03 % of the
    boxes; with them 0.66 % (a squat box over another), 0.87 % with KITTI's frame size (two side by side at the bottom
    rows and a fifth of the width)."""
    n = joined = 0
    for seq in (0, 1, 2, 4, 5, 6, 7, 9, 11, 12, 14, 15, 17, 18, 19, 20):
        lab = read_labels(KittiSequence(kitti_root, seq).labels)
        ped = lab[lab["type"] == "Pedestrian"]
        n += len(ped)
        for _, g in ped.groupby("frame"):
            if len(g) > 1:
                det = Detections(
                    g[["x1", "y1", "x2", "y2"]].to_numpy(np.float32), np.ones(len(g), np.float32),
                    np.full(len(g), "pedestrian"),
                )  # fmt: skip
                joined += len(det) - len(rider_groups(det, picture))
    assert n > 8000 and joined / n < share, (joined, n)


def test_pedestrians_are_placed_within_a_few_percent_of_their_range(kitti_root):
    """The monocular path on pedestrians (their labels through the noise model, the KITTI camera; 0017, a crowd and
    cyclists at a crossing): tracked (MOTA 66.1) and placed on the ground within a few percent of their range (median
    5.7 % at 0-20 m, 7.2 % at 20-40 m)."""
    row = evaluate_mono(kitti_root, [PEDESTRIANS], object_class="pedestrian")["sequences"][f"{PEDESTRIANS:04d}"]
    assert row["MOTA"] > 60, row
    for key, most in (("0-20 m", 7.0), ("20-40 m", 8.5)):
        cell = row["position_error"][key]
        assert cell["n"] > 50 and cell["median_pct"] < most, (key, cell)


def test_a_bicycles_box_width_does_not_place_it(kitti_root):
    """A bicycle's box is 0.6-1.9 m wide with its heading, which a standing cyclist does not reveal: on 0015 (a
    cyclist standing 18 m ahead, 30 deg right, seen end-on; the road climbs) the width cue read it 47 % far and the
    path put it 15 % far at 20-40 m (MOTA -61.3); with the width cue's sigma for bicycles
    (``MonoConfig.bicycle_width_sigma_rel``) 7.9 % and MOTA 17.2."""
    seq = 15
    row = evaluate_mono(kitti_root, [seq], object_class="cyclist")["sequences"][f"{seq:04d}"]
    cell = row["position_error"]["20-40 m"]
    assert cell["n"] > 300 and cell["range_bias_pct"] < 11.0, cell
    assert row["MOTA"] > 0, row


def test_a_walker_joined_with_a_bicycle_box_once_stays_a_walker(kitti_root):
    """A walker is joined with a bicycle box beside it now and then (a parked bicycle, a false box): on 0019 one such
    detection at a walker's first frame made its track a bicycle for good (106 of 108 frames), 147 of the cyclist
    class's 157 false positives there (MOTA 31.5). A track is a two-wheeler for good only once seen as one twice
    (``track.WHEEL_LATCH_HITS``): MOTA 61.7, FP 73."""
    seq = 19
    row = evaluate_mono(kitti_root, [seq], object_class="cyclist")["sequences"][f"{seq:04d}"]
    assert row["MOTA"] > 50 and row["FP"] < 110, row


def test_class_option_errors_are_one_line(kitti_root):
    from test_cli import assert_one_line_error, run

    base = ("evaluate", "kitti", "--data", str(kitti_root), "--sequences", "12")
    assert_one_line_error(run(*base, "--mono", "--class", "bus"), "--class must be one of")
    assert_one_line_error(run(*base, "--class", "pedestrian"), "the LiDAR tracker runs on the PointRCNN car")


def test_results_name_the_class(kitti_root, tmp_path):
    """``evaluate kitti --class pedestrian -o DIR``: results.md names the class and boxes it scored, as results.json."""
    import json

    from test_cli import run

    out = tmp_path / "res"
    res = run("evaluate", "kitti", "--data", str(kitti_root), "--sequences", str(CYCLISTS), "--mono", "--class",
              "pedestrian", "-o", str(out))  # fmt: skip
    assert res.returncode == 0, res.stderr
    first = (out / "results.md").read_text().splitlines()[0]
    assert "class pedestrian" in first and "noisy labels" in first, first
    assert json.loads((out / "results.json").read_text())["class"] == "pedestrian"
