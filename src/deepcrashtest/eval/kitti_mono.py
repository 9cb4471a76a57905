"""KITTI tracking through the monocular video path: 2D boxes in, world-frame tracks out, scored.

What runs is the code ``extract`` runs on a video, minus the pixels: the image tracker
(:func:`~deepcrashtest.perception.track.track_boxes`, the :class:`BoxTracker` of ``extract`` without
optical flow), self-calibration when the camera is unknown
(:func:`~deepcrashtest.geometry.selfcalib.self_calibrate`), and
:func:`~deepcrashtest.geometry.world_tracks.raw_scenario_from_tracks` (the monocular 3D tracker of
:mod:`deepcrashtest.geometry.mono3d`). The raw Scenario's agents become KITTI result rows
(:mod:`deepcrashtest.datasets.kitti.results`), scored with the KITTI rules in the world frame
(:mod:`deepcrashtest.eval.kitti_rules`, :mod:`deepcrashtest.eval.clear_mot`).

Inputs per sequence:

* boxes: ``pointrcnn`` - the image-plane columns ``x1 y1 x2 y2 score`` of the PointRCNN detections
  (their 3D columns are never read; score -> ``1 / (1 + exp(-score))``); or ``labels-noisy`` - the
  label boxes of every road user (Car/Van/Truck, Pedestrian/Person, Cyclist: a detector reports them all, whatever
  class is scored) through :class:`LabelNoise` (seeded): each box is missed with
  probability ``miss_rate`` (x ``miss_growth`` per occlusion level), its corners moved by an offset held over the
  object's track (``offset_rel`` x its height, 1 sigma) and jittered frame by frame by ``jitter_rel`` x its height,
  and ``false_per_frame`` false boxes per frame on
  average (Poisson), each the box of a road user of the scored class at a random place on the road; the scores of both
  drawn from PointRCNN's measured scores of boxes on and off a label (:data:`TRUE_BOX_SCORES`).
  PointRCNN's detections are cars only: with ``--class pedestrian`` or ``cyclist`` and ``pointrcnn`` the other road
  users' label boxes (:data:`NON_VEHICLE_TYPES`) go through the noise model beside PointRCNN's cars.
* ego: the sequence's ORB-SLAM3 poses (:meth:`EgoMotion.from_poses`);
* camera: ``kitti`` - intrinsics from ``P2`` and the KITTI camera height (1.65 m), level; or
  ``unknown`` - the unknown-dashcam default (90 deg field of view, 1.3 m), then self-calibrated.
"""

from __future__ import annotations

import math
from collections.abc import Iterable
from dataclasses import asdict, dataclass, field, replace
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd
from scipy.optimize import linear_sum_assignment

from deepcrashtest.datasets.kitti.files import (
    KITTI_CAMERA_HEIGHT_M,
    KITTI_FPS,
    KITTI_IMAGE_SIZE,
    KittiSequence,
    read_ab3dmot_detections,
    read_calib,
    read_labels,
    read_poses,
)
from deepcrashtest.datasets.kitti.results import scenario_result_table
from deepcrashtest.datasets.kitti.scenario import KITTI_CAMERA_FORWARD_OFFSET_M
from deepcrashtest.datasets.kitti.world import KittiWorld
from deepcrashtest.errors import UserError
from deepcrashtest.eval.clear_mot import EvalSequence, clear_only, evaluate_sequences
from deepcrashtest.eval.kitti import (
    PAPER_TABLE,
    ground_truth_frames,
    hypotheses_from_table,
    kitti_class,
    match_rule,
)
from deepcrashtest.eval.kitti_rules import KITTI_CLASSES, GroundTruthFrame, KittiClass, MatchRule, apply_kitti_rules
from deepcrashtest.geometry.camera import default_camera
from deepcrashtest.geometry.egomotion import EgoMotion
from deepcrashtest.geometry.frames import rotation_homographies
from deepcrashtest.geometry.localize import CLASS_DIMENSIONS
from deepcrashtest.geometry.mono_config import MonoConfig
from deepcrashtest.geometry.selfcalib import SelfCalibration, self_calibrate
from deepcrashtest.geometry.world_tracks import raw_scenario_from_tracks
from deepcrashtest.perception.detections import Detections
from deepcrashtest.perception.track import track_boxes
from deepcrashtest.scenario import Camera, Scenario, VideoSource
from deepcrashtest.ui import track as progress

BOX_SOURCES = ("pointrcnn", "labels-noisy")
CAMERAS = ("kitti", "unknown")
#: Distance bins (m, camera to the labelled car's centre) of the position-error table.
ERROR_BINS = ((0.0, 20.0), (20.0, 40.0), (40.0, 60.0))


#: The scores of PointRCNN's boxes (sigmoid of its score) on the 18 training sequences other than 3, 8 and 10, as
#: quantiles at :data:`SCORE_LEVELS`: of the boxes on a Car/Van/Truck/DontCare label (image IoU >= 0.5; 25,995 boxes)
#: and of those on none (IoU < 0.3; 16,500). ``labels-noisy`` draws its boxes' scores from them (inverse CDF): the
#: tracker's thresholds (:class:`MonoTracking`), chosen on PointRCNN's boxes, see the scores they were chosen on (a
#: uniform 0.6-1.0 put every track's mean under ``min_confidence`` 0.9: MOTA 0 on every sequence until 2026-12-07).
SCORE_LEVELS = (0.0, 0.02, 0.05, 0.1, 0.15, 0.2, 0.25, 0.3, 0.4, 0.5, 1.0)
TRUE_BOX_SCORES = (0.3006, 0.4974, 0.7529, 0.9219, 0.9711, 0.9885, 0.995, 0.9976, 0.9994, 0.9998, 1.0)
FALSE_SCORE_LEVELS = (0.0, 0.1, 0.2, 0.3, 0.4, 0.5, 0.6, 0.7, 0.8, 0.9, 1.0)
FALSE_BOX_SCORES = (0.3, 0.3444, 0.3954, 0.4518, 0.5211, 0.596, 0.6735, 0.7613, 0.8512, 0.9371, 0.9999)


def _draw_scores(rng: np.random.Generator, n: int, levels: tuple[float, ...], scores: tuple[float, ...]) -> np.ndarray:
    """``n`` scores drawn from the distribution with these quantiles (piecewise-linear inverse CDF)."""
    return np.interp(rng.random(n), levels, scores)


@dataclass(frozen=True)
class LabelNoise:
    """Noise model of the ``labels-noisy`` boxes (see the module docstring).

    Measured on PointRCNN's boxes (score >= 0.7) of the untruncated Cars of the 18 training sequences other than 3,
    8 and 10, against their labels (image IoU >= 0.5, corner errors over the label box's height, robust sigmas): a
    per-object offset held over the object's track (x1 y1 x2 y2: 3.5 / 3.0 / 2.9 / 2.7 %) and a frame-to-frame jitter
    (2.9 / 2.3 / 2.7 / 2.0 %; 5.4 / 4.4 / 4.7 / 4.0 % in all); recall by occlusion level 0-3: 0.93 / 0.87 / 0.77 /
    0.66 (a miss rate of 0.07 growing x 1.8 per level). Until 2026-12-07 the whole 5 % was drawn afresh every frame
    and misses doubled per level."""

    jitter_rel: float = 0.025
    offset_rel: float = 0.03
    miss_rate: float = 0.07
    miss_growth: float = 1.8
    false_per_frame: float = 0.3
    seed: int = 0


@dataclass(frozen=True)
class MonoTracking:
    """Image tracker lifecycle (``BoxTracker``) and track filter of the monocular path.

    Chosen on the 18 KITTI training sequences other than 3, 8 and 10 (``bench/tune_mono.py``)."""

    min_score: float = 0.7
    # a tentative track starts from any kept box and is confirmed once its detections' scores add up to
    # min_evidence in min_hits rounds or more (round mono9, 18 tuning sequences: 63.84 -> 64.55; evidence 3.6 /
    # 3.9 / 4.2 / 4.5: 64.39 / 64.51 / 64.52 / 64.50; min_hits 3 the same; 4 hits without evidence 63.91; birth
    # from 0.85: 64.53; a tentative track surviving one miss 63.09; min_score 0.6 63.31). Was: births from boxes
    # of 0.97 only, 3 hits (round mono4: 0.95 63.06, dropped: 0014 -10, 0002 +10)
    new_track_score: float = 0.7
    min_hits: int = 4
    max_age_s: float = 1.0
    min_iou: float = 0.2
    min_evidence: float = 3.8
    min_detected: int = 8
    min_confidence: float = 0.9  # mean detection score a track must beat (tuning MOTA 60.68; 0: 60.23, 0.95: 60.57)
    report_predicted: bool = True
    # the image tracker gets the boxes of every N-th frame only, as ``extract``'s detector runs on a video (at most
    # MAX_DETECT_GAP_S apart: every 2nd frame at KITTI's 10 fps), the frames between carried by the tracker
    detect_every: int = 1
    # the boxes the tracker carries between detections move with the camera's own rotation, read from the poses
    # (:func:`~deepcrashtest.geometry.frames.rotation_homographies`) through the unknown-dashcam default's
    # intrinsics (90 deg field of view, never the calibration file: the image tracks are the same for both
    # cameras), before their own image velocity; off: constant image velocity alone
    camera_motion: bool = True
    mono: MonoConfig = field(default_factory=MonoConfig)

    @property
    def min_detected_frames(self) -> int:
        """The detected frames a track needs at ``detect_every``: ``min_detected`` is a count at every frame (0.8 s
        at KITTI's 10 fps), the same time span at a video's cadence (the boxes of every 2nd frame: 4; 8 there asked
        for 1.6 s and dropped 313 training rows of cars against 66 at every frame. 18 training sequences, every 2nd
        frame, combined MOTA 64.14 -> 64.79 with the KITTI camera, 47.70 -> 48.30 unknown)."""
        return max(1, math.ceil(self.min_detected / self.detect_every))


DEFAULT_MONO = MonoTracking()


@dataclass
class MonoSequence:
    """One sequence's inputs to the monocular path (no tracker setting in it)."""

    name: str
    world: KittiWorld
    P2: np.ndarray
    size: tuple[int, int]
    ground_truth: list[GroundTruthFrame]
    gt_range: list[np.ndarray]
    detections: list[Detections]
    camera: Camera
    calibration: SelfCalibration | None
    cls: KittiClass = KITTI_CLASSES["car"]


def _image_size(*tables: pd.DataFrame) -> tuple[int, int]:
    """(width, height) px of a sequence's frames from its boxes (KITTI frames differ by a few px): the boxes' extent,
    the height at least the width over the frames' aspect (:data:`KITTI_IMAGE_SIZE`'s, 3.31: 1242 x 375, 1224 x 370,
    1238 x 374 px by recording day). Boxes are clipped to the frame, and cars leaving at its sides touch the right
    edge in every sequence, but where none reaches the bottom their extent alone reads the frame short (0012: 273
    rows of 375, which put an unknown camera's default principal point 51 px above the frame's centre)."""
    w = int(math.ceil(max(float(t["x2"].max()) for t in tables if len(t)))) + 1
    h = int(math.ceil(max(float(t["y2"].max()) for t in tables if len(t)))) + 1
    return w, max(h, round(w * KITTI_IMAGE_SIZE[1] / KITTI_IMAGE_SIZE[0]))


def pointrcnn_boxes(table: pd.DataFrame, n_frames: int) -> list[Detections]:
    """Per-frame 2D detections from AB3DMOT rows: image columns and the score only (sigmoid)."""
    return _per_frame(
        table["frame"].to_numpy(int), table[["x1", "y1", "x2", "y2"]].to_numpy(float),
        1.0 / (1.0 + np.exp(-table["score"].to_numpy(float))), np.full(len(table), "car"), n_frames,
    )  # fmt: skip


#: The label types whose boxes ``labels-noisy`` gives the tracker, whatever class is scored (a detector reports every
#: road user: the unknown camera calibrates itself from the cars beside the pedestrians, as ``extract`` does), and
#: their detector category: a sitting person is a person; a cyclist is two boxes (:func:`_detector_view`).
LABEL_BOX_KINDS: dict[str, str] = {
    "Car": "car", "Van": "van", "Truck": "truck", "Pedestrian": "pedestrian", "Person": "pedestrian",
    "Cyclist": "bicycle",
}  # fmt: skip
#: The road users PointRCNN's car detections leave out: with ``--boxes pointrcnn --class pedestrian|cyclist`` their
#: label boxes go through the noise model beside PointRCNN's cars.
NON_VEHICLE_TYPES = ("Pedestrian", "Person", "Cyclist")
#: A COCO detector sees a cyclist (KITTI's box: the rider's head to the wheels) as a ``person``, the rider (head to
#: the pedals: the top RIDER_BOTTOM of the box, at most RIDER_ASPECT x as wide as it is tall: narrower than the bicycle
#: seen from the side), and a ``bicycle`` (wheels to the handlebars: the bottom BICYCLE_TOP of the box,
#: its whole width); the pipeline joins them again (:func:`~deepcrashtest.perception.roadusers.road_users`) as it
#: does a video's, where a walker beside the cyclist may join too. Each part is missed and jittered on its own.
RIDER_BOTTOM = 0.9
RIDER_ASPECT = 0.5
BICYCLE_TOP = 0.6


def _detector_view(labels: pd.DataFrame) -> pd.DataFrame:
    """The road users' label rows (:data:`LABEL_BOX_KINDS`) as a detector reports them: ``frame``, ``object`` (one id
    per object part), ``category``, ``occluded``, ``x1..y2``; a Cyclist as its rider and its bicycle."""
    lab = labels[labels["type"].isin(list(LABEL_BOX_KINDS))]
    out = lab[["frame", "occluded", "x1", "y1", "x2", "y2"]].copy()
    out["object"] = lab["track_id"].to_numpy(int) * 2
    out["category"] = lab["type"].map(LABEL_BOX_KINDS).to_numpy(dtype=str)
    cyc = lab[lab["type"] == "Cyclist"]
    if not len(cyc):
        return out.reset_index(drop=True)
    x1, y1, x2, y2 = (cyc[c].to_numpy(float) for c in ("x1", "y1", "x2", "y2"))
    h, cx = y2 - y1, 0.5 * (x1 + x2)
    half = 0.5 * np.minimum(x2 - x1, RIDER_ASPECT * RIDER_BOTTOM * h)
    rider = pd.DataFrame(
        {"frame": cyc["frame"].to_numpy(int), "occluded": cyc["occluded"].to_numpy(), "x1": cx - half, "y1": y1,
         "x2": cx + half, "y2": y1 + RIDER_BOTTOM * h, "object": cyc["track_id"].to_numpy(int) * 2 + 1,
         "category": "pedestrian"}
    )  # fmt: skip
    bike = out.loc[cyc.index].copy()
    bike["y1"] = y2 - BICYCLE_TOP * h
    out = pd.concat([out.drop(index=cyc.index), bike, rider], ignore_index=True)
    return out.sort_values(["frame", "object"], kind="stable", ignore_index=True)


def noisy_label_boxes(
    labels: pd.DataFrame,
    n_frames: int,
    size: tuple[int, int],
    noise: LabelNoise,
    camera: Camera,
    cls: KittiClass = KITTI_CLASSES["car"],
    types: tuple[str, ...] = tuple(LABEL_BOX_KINDS),
) -> list[Detections]:
    """The label boxes of the road users of ``types`` (all of :data:`LABEL_BOX_KINDS` by default) through the seeded
    noise model of :class:`LabelNoise`, its false boxes of the scored class ``cls``."""
    rng = np.random.default_rng(noise.seed)
    lab = _detector_view(labels[labels["type"].isin(types)])
    occl = lab["occluded"].to_numpy(float).clip(0, 3)
    keep = rng.random(len(lab)) >= noise.miss_rate * noise.miss_growth**occl
    uniq, which = np.unique(lab["object"].to_numpy(int), return_inverse=True)
    offset = rng.normal(0.0, 1.0, (len(uniq), 4))[which] * noise.offset_rel  # held over each object's track
    lab, offset = lab[keep], offset[keep]
    b = lab[["x1", "y1", "x2", "y2"]].to_numpy(float)
    b += (rng.normal(0.0, 1.0, b.shape) * noise.jitter_rel + offset) * (b[:, 3:4] - b[:, 1:2])
    frames = lab["frame"].to_numpy(int)
    cats = lab["category"].to_numpy(dtype=str)
    scores = _draw_scores(rng, len(lab), SCORE_LEVELS, TRUE_BOX_SCORES)
    n_false = rng.poisson(noise.false_per_frame, n_frames)
    ff = np.repeat(np.arange(n_frames), n_false)
    fb = _random_boxes(len(ff), size, camera, rng, cls.category)
    scores_f = _draw_scores(rng, len(ff), FALSE_SCORE_LEVELS, FALSE_BOX_SCORES)
    w, h = size
    all_b = np.clip(np.vstack([b, fb]), 0, [w - 1, h - 1, w - 1, h - 1])
    ok = (all_b[:, 2] - all_b[:, 0] > 2) & (all_b[:, 3] - all_b[:, 1] > 2)
    return _per_frame(
        np.r_[frames, ff][ok], all_b[ok], np.r_[scores, scores_f][ok],
        np.r_[cats, np.full(len(ff), cls.category)][ok], n_frames,
    )  # fmt: skip


def _random_boxes(
    n: int, size: tuple[int, int], camera: Camera, rng: np.random.Generator, category: str = "car"
) -> np.ndarray:
    """Boxes of an object of ``category``'s size (:data:`~deepcrashtest.geometry.localize.CLASS_DIMENSIONS`, its
    height x 0.6-1.5, its width x 0.6-2) on the road 5-60 m ahead, anywhere across the image."""
    _, width_m, height_m = CLASS_DIMENSIONS[category]
    z = rng.uniform(5.0, 60.0, n)
    v_b = camera.cy + camera.fy * camera.height_m / z
    h = camera.fy * height_m / z * rng.uniform(0.6, 1.5, n)
    w = camera.fx * width_m / z * rng.uniform(0.6, 2.0, n)
    u = rng.uniform(0.0, size[0], n)
    return np.column_stack([u - w / 2, v_b - h, u + w / 2, v_b])


def _per_frame(
    frames: np.ndarray, boxes: np.ndarray, scores: np.ndarray, cats: np.ndarray, n_frames: int
) -> list[Detections]:
    order = np.argsort(frames, kind="stable")
    bounds = np.searchsorted(frames[order], np.arange(n_frames + 1))
    out = []
    for f in range(n_frames):
        idx = order[bounds[f] : bounds[f + 1]]
        out.append(Detections(boxes[idx].astype(np.float32), scores[idx].astype(np.float32), cats[idx].astype(str)))
    return out


def kitti_camera(P2: np.ndarray) -> Camera:
    """The KITTI colour camera: intrinsics from ``P2``, 1.65 m above the road, level."""
    return Camera(
        fx=float(P2[0, 0]), fy=float(P2[1, 1]), cx=float(P2[0, 2]), cy=float(P2[1, 2]),
        height_m=KITTI_CAMERA_HEIGHT_M, forward_offset_m=KITTI_CAMERA_FORWARD_OFFSET_M,
        intrinsics_source="kitti_calib", pitch_source="kitti_calib", height_source="kitti_calib",
    )  # fmt: skip


def prepare_mono(
    root: str | Path,
    sequence: int,
    boxes: str = "pointrcnn",
    camera: str = "kitti",
    noise: LabelNoise | None = None,
    object_class: str = "car",
) -> MonoSequence:
    """Read one sequence's boxes, poses, ground truth (of ``object_class``: car, pedestrian or cyclist); choose (or
    self-calibrate) the camera."""
    if boxes not in BOX_SOURCES:
        raise UserError(f"--boxes must be one of {', '.join(BOX_SOURCES)} (got {boxes!r})")
    if camera not in CAMERAS:
        raise UserError(f"--camera must be one of {', '.join(CAMERAS)} (got {camera!r})")
    cls = kitti_class(object_class)
    root = Path(root)
    seq = KittiSequence(root, sequence).check()
    world = KittiWorld(read_poses(seq.poses))
    P2 = read_calib(seq.calib).P2
    labels = read_labels(seq.labels)
    dets_table = read_ab3dmot_detections(seq.detections_pointrcnn) if boxes == "pointrcnn" else labels.iloc[:0]
    size = _image_size(labels, dets_table)
    cam_true = kitti_camera(P2)
    noise = noise or LabelNoise(seed=sequence)
    if boxes == "pointrcnn":
        dets = pointrcnn_boxes(dets_table, world.n_frames)
        if cls.name != "car":  # PointRCNN's are cars: the other road users from their labels, through the noise
            vru = noisy_label_boxes(labels, world.n_frames, size, noise, cam_true, cls, NON_VEHICLE_TYPES)
            dets = [_joined(a, b) for a, b in zip(dets, vru, strict=True)]
    else:
        dets = noisy_label_boxes(labels, world.n_frames, size, noise, cam_true, cls)
    gt = ground_truth_frames(root, sequence, world, cls)
    gt_range = [_ground_range(g, world, f) for f, g in enumerate(gt)]
    return MonoSequence(seq.name, world, P2, size, gt, gt_range, dets, cam_true, None, cls)


def _joined(a: Detections, b: Detections) -> Detections:
    """One frame's detections of two sources (no masks)."""
    return Detections(
        np.vstack([a.boxes, b.boxes]).astype(np.float32), np.r_[a.scores, b.scores].astype(np.float32),
        np.r_[np.asarray(a.categories, str), np.asarray(b.categories, str)],
    )  # fmt: skip


def _ground_range(g: GroundTruthFrame, world: KittiWorld, frame: int) -> np.ndarray:
    """Camera-to-centre ground distance (m) of a frame's ground-truth objects."""
    cam = world.world_to_camera(frame, g.objects.world[:, :3])
    return np.hypot(cam[:, 0], cam[:, 2])


def ego_of(world: KittiWorld) -> EgoMotion:
    return EgoMotion.from_poses(world.poses, KITTI_FPS)


def image_tracks(prep: MonoSequence, config: MonoTracking) -> pd.DataFrame:
    """The image tracker (``extract``'s :class:`BoxTracker`, no pixels) on a sequence's boxes (those of every
    ``config.detect_every``-th frame)."""
    every = config.detect_every
    dets = prep.detections if every == 1 else [d if k % every == 0 else None for k, d in enumerate(prep.detections)]
    K = default_camera(*prep.size).matrix()
    motion = rotation_homographies(prep.world.poses, K) if config.camera_motion else None
    return track_boxes(
        dets, KITTI_FPS, prep.size, camera_motion=motion, detect_every=every, min_score=config.min_score,
        new_track_score=config.new_track_score, min_hits=config.min_hits, max_age_s=config.max_age_s,
        min_iou=config.min_iou, min_evidence=config.min_evidence,
    )  # fmt: skip


def image_tracks_key(config: MonoTracking) -> tuple[Any, ...]:
    """The settings :func:`image_tracks` depends on: a key to cache a sequence's image tracks under."""
    return (
        config.min_score, config.new_track_score, config.min_hits, config.max_age_s, config.min_iou,
        config.min_evidence, config.detect_every, config.camera_motion,
    )  # fmt: skip


def mono_scenario(
    prep: MonoSequence, config: MonoTracking, camera: str = "kitti", tracks: pd.DataFrame | None = None
) -> tuple[Scenario, Camera]:
    """The raw Scenario of the monocular path on a prepared sequence (and the camera it used);
    ``tracks``: the image tracks when already computed (:func:`image_tracks`)."""
    if tracks is None:
        tracks = image_tracks(prep, config)
    ego = ego_of(prep.world)
    if camera == "kitti":
        cam = prep.camera
    else:
        start = default_camera(*prep.size).model_copy(update={"forward_offset_m": KITTI_CAMERA_FORWARD_OFFSET_M})
        prep.calibration = self_calibrate(tracks, start, prep.size, ego)
        cam = prep.calibration.camera
    meta = VideoSource(
        kind="image_folder", path=prep.name, fps=KITTI_FPS, frame_count=prep.world.n_frames,
        width=prep.size[0], height=prep.size[1],
    )  # fmt: skip
    sc = raw_scenario_from_tracks(
        tracks, meta, cam, ego, name=prep.name, mono=config.mono, min_detected=config.min_detected_frames,
        min_confidence=config.min_confidence,
    )  # fmt: skip
    return sc, cam


def score_sequence(
    prep: MonoSequence, scenario: Scenario, rule: MatchRule, observed_only: bool = True
) -> tuple[EvalSequence, dict[str, Any]]:
    """KITTI rules applied to the scenario's tracks, and the position-error-by-distance table
    (``observed_only``: only the frames where a track was detected, else its predicted ones too)."""
    table = scenario_result_table(scenario, prep.world, prep.P2, observed_only, image_size=prep.size)
    hyps = hypotheses_from_table(table, prep.world, prep.cls)
    frames = [apply_kitti_rules(g, h, rule) for g, h in zip(prep.ground_truth, hyps, strict=True)]
    errors = _position_errors(prep, hyps)
    return EvalSequence(prep.name, frames), errors


def _position_errors(prep: MonoSequence, hyps: list) -> dict[str, Any]:
    """Ground-position error of evaluated cars matched to a track (Hungarian on distance, gate
    max(2 m, 25 % of the range)), by the car's range: median and 90th percentile (m), and the
    median as a percentage of the range; the median signed range error (percent, > 0: too far); and under
    ``heading`` the matched cars' heading error (:func:`heading_errors`)."""
    err: list[np.ndarray] = []
    rng: list[np.ndarray] = []
    bias: list[np.ndarray] = []
    turn: list[np.ndarray] = []
    for f, (g, h, r) in enumerate(zip(prep.ground_truth, hyps, prep.gt_range, strict=True)):
        ev = g.evaluated
        if not ev.any() or len(h) == 0:
            continue
        gw, hw, gr = g.objects.world[ev, :2], h.world[:, :2], r[ev]
        d = np.hypot(gw[:, None, 0] - hw[None, :, 0], gw[:, None, 1] - hw[None, :, 1])
        gate = np.maximum(2.0, 0.25 * gr)[:, None]
        d = np.where(np.isfinite(d) & (d < gate), d, 1e6)
        rows, cols = linear_sum_assignment(d)
        ok = d[rows, cols] < 1e6
        err.append(d[rows[ok], cols[ok]])
        rng.append(gr[rows[ok]])
        hc = prep.world.world_to_camera(f, h.world[cols[ok], :3])
        bias.append(np.hypot(hc[:, 0], hc[:, 2]) - gr[rows[ok]])
        turn.append(h.world[cols[ok], 6] - g.objects.world[ev, 6][rows[ok]])
    e = np.concatenate(err) if err else np.zeros(0)
    rr = np.concatenate(rng) if rng else np.zeros(0)
    bb = np.concatenate(bias) if bias else np.zeros(0)
    out: dict[str, Any] = {}
    for lo, hi in ERROR_BINS:
        m = (rr >= lo) & (rr < hi)
        key = f"{lo:g}-{hi:g} m"
        if not m.any():
            out[key] = {"n": 0, "median_m": None, "p90_m": None, "median_pct": None, "range_bias_pct": None}
            continue
        out[key] = {
            "n": int(m.sum()),
            "median_m": round(float(np.median(e[m])), 3),
            "p90_m": round(float(np.percentile(e[m], 90)), 3),
            "median_pct": round(float(np.median(e[m] / np.maximum(rr[m], 1e-6))) * 100, 2),
            "range_bias_pct": round(float(np.median(bb[m] / np.maximum(rr[m], 1e-6))) * 100, 2),
        }
    out["heading"] = heading_errors(np.concatenate(turn) if turn else np.zeros(0))
    return out


def heading_errors(diff: np.ndarray) -> dict[str, Any]:
    """Heading error of matched cars from the differences ``diff`` (rad, hypothesis minus label): median and 90th
    percentile (deg) of the box's error (modulo a half turn: a box fits both ways round), the share above 20 deg,
    and the share facing the other way round (full-turn error above 90 deg)."""
    diff = diff[np.isfinite(diff)]
    if not len(diff):
        return {"n": 0, "median_deg": None, "p90_deg": None, "share_over_20_deg": None, "share_reversed": None}
    box = np.degrees(np.abs((diff + 0.5 * np.pi) % np.pi - 0.5 * np.pi))
    full = np.degrees(np.abs((diff + np.pi) % (2 * np.pi) - np.pi))
    return {
        "n": len(diff),
        "median_deg": round(float(np.median(box)), 2),
        "p90_deg": round(float(np.percentile(box, 90)), 2),
        "share_over_20_deg": round(float(np.mean(box > 20.0)), 3),
        "share_reversed": round(float(np.mean(full > 90.0)), 3),
    }


def evaluate_mono(
    root: str | Path,
    sequences: Iterable[int],
    *,
    boxes: str = "pointrcnn",
    camera: str = "kitti",
    match: str = "distance",
    config: MonoTracking | None = None,
    noise: LabelNoise | None = None,
    detect_every: int | None = None,
    object_class: str = "car",
) -> dict[str, Any]:
    """Evaluate the monocular path on KITTI tracking sequences (see the module docstring) for one class
    (``object_class``: car, pedestrian or cyclist); ``detect_every`` replaces ``config``'s
    (:attr:`MonoTracking.detect_every`)."""
    rule = match_rule(match)
    cfg = config or DEFAULT_MONO
    if detect_every is not None:
        if detect_every < 1:
            raise UserError(f"--detect-every must be >= 1 (got {detect_every})")
        cfg = replace(cfg, detect_every=int(detect_every))
    seqs = list(sequences)
    evaluated, errors, cameras = [], {}, {}
    for s in progress(seqs, "evaluating sequences (monocular)", total=len(seqs)):
        prep = prepare_mono(root, s, boxes, camera, noise, object_class)
        sc, cam = mono_scenario(prep, cfg, camera)
        ev, err = score_sequence(prep, sc, rule, not cfg.report_predicted)
        evaluated.append(ev)
        errors[prep.name] = err
        cameras[prep.name] = _camera_summary(cam, prep)
    rows = evaluate_sequences(evaluated, rule)
    for name, row in rows.items():
        if name in errors:
            row["heading_error"] = errors[name].pop("heading")
            row["position_error"] = errors[name]
            row["camera"] = cameras[name]
    return {
        "match": match,
        "match_rule": rule.describe(),
        "class": object_class,
        "hypotheses": f"monocular path on {boxes} 2D boxes"
        + (" (cars; pedestrians and cyclists: noisy labels)" if boxes == "pointrcnn" and object_class != "car" else "")
        + (f" of one frame in {cfg.detect_every}" if cfg.detect_every > 1 else "")
        + f", camera {camera}",
        "tracker": asdict(cfg),
        "noise": asdict(noise or LabelNoise()) if boxes == "labels-noisy" else None,
        "sequences": rows,
        "paper": {f"{s:04d}": PAPER_TABLE[s] for s in seqs if s in PAPER_TABLE and object_class == "car"},
        "notes": [],
    }


def _camera_summary(cam: Camera, prep: MonoSequence) -> dict[str, Any]:
    true = prep.camera
    out: dict[str, Any] = {
        "fy": round(cam.fy, 1), "fy_true": round(true.fy, 1), "height_m": round(cam.height_m, 3),
        "horizon_v": round(cam.cy - cam.fy * math.tan(cam.pitch_rad), 1),
        "sources": [cam.intrinsics_source, cam.pitch_source, cam.height_source],
    }  # fmt: skip
    if prep.calibration is not None:
        out["self_calibration"] = prep.calibration.summary()
    return out


def quick_mota(
    preps: list[MonoSequence], config: MonoTracking, camera: str = "kitti", cache: dict | None = None
) -> tuple[float, dict]:
    """Combined MOTA (percent) of ``config`` over prepared sequences, CLEAR only (for tuning);
    ``cache`` (a dict) keeps image tracks per sequence and tracker setting between calls."""
    rule = match_rule("distance")
    key = image_tracks_key(config)
    evs = []
    for p in preps:
        tracks = None
        if cache is not None:
            tracks = cache.get((p.name, key))
            if tracks is None:
                tracks = cache[(p.name, key)] = image_tracks(p, config)
        sc = mono_scenario(p, config, camera, tracks)[0]
        evs.append(score_sequence(p, sc, rule, not config.report_predicted)[0])
    res = clear_only(evs, rule)
    return 100 * float(res["combined"]["MOTA"]), res
