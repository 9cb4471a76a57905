"""KITTI tracking evaluation: ground truth and hypotheses in the Scenario's world frame.

Hypotheses are either a tracker's results in KITTI tracking format (``--tracks DIR``) or the output of
this project's world-frame tracker run on 3D detections in AB3DMOT format (``--detections``). Both are
scored with the KITTI rules of :mod:`deepcrashtest.eval.kitti_rules` and the metrics of
:mod:`deepcrashtest.eval.clear_mot`.
"""

from __future__ import annotations

from collections.abc import Iterable
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd

from deepcrashtest.datasets.kitti.boxes import WORLD_BOX_COLUMNS
from deepcrashtest.datasets.kitti.files import (
    KittiCalib,
    KittiSequence,
    read_ab3dmot_detections,
    read_calib,
    read_labels,
    read_poses,
)
from deepcrashtest.datasets.kitti.scenario import labels_frame_table
from deepcrashtest.datasets.kitti.track_smoothing import OfflineConfig, offline_tracks
from deepcrashtest.datasets.kitti.world import KittiWorld, frame_index, world_table
from deepcrashtest.datasets.kitti.world_tracker import WorldDetections, WorldTracker, WorldTrackerConfig
from deepcrashtest.errors import UserError
from deepcrashtest.eval.clear_mot import EvalSequence, evaluate_sequences
from deepcrashtest.eval.kitti_rules import (
    KITTI_CLASSES,
    MATCH_RULES,
    MAX_OCCLUSION,
    MAX_TRUNCATION,
    FrameObjects,
    GroundTruthFrame,
    KittiClass,
    MatchRule,
    apply_kitti_rules,
)
from deepcrashtest.ui import track

#: The reference paper's table (world-frame CLEAR-MOT of its trajectory extraction), percentages.
PAPER_TABLE: dict[int, dict[str, float]] = {
    3: dict(MOTA=58.08, MOTP=80.35, MODA=59.28, MODP=83.33, recall=78.17, precision=81.03, F1=79.75,
            TP=265, FP=62, FN=74, FAR=42.75, MT=37.5, PT=62.5, ML=0.0),
    8: dict(MOTA=67.36, MOTP=79.55, MODA=67.36, MODP=84.54, recall=72.08, precision=94.35, F1=81.73,
            TP=736, FP=44, FN=285, FAR=11.25, MT=47.61, PT=38.09, ML=14.28),
    10: dict(MOTA=77.75, MOTP=85.04, MODA=78.44, MODP=86.96, recall=83.01, precision=94.90, F1=88.56,
             TP=484, FP=26, FN=99, FAR=8.81, MT=23.07, PT=76.92, ML=0.0),
}  # fmt: skip
TABLE_COLUMNS = ["MOTA", "MOTP", "MODA", "MODP", "recall", "precision", "F1", "TP", "FP", "FN", "FAR", "MT", "PT", "ML"]
ALL_SEQUENCES = list(range(21))
#: Tuned (coordinate descent, 2 rounds, combined world-frame MOTA with 2 m matching) on the 18
#: training sequences other than 3, 8 and 10, which were held out: ``bench/tune_world_tracker.py``.
DEFAULT_TRACKER = WorldTrackerConfig(min_score=1.0, birth_score=4.0, gate_m=2.0, min_hits=5, max_age=10)
DEFAULT_OFFLINE = OfflineConfig(min_detections=6, max_gap=30, extend_max_gap=10, extend_min_score=-10.0)


def parse_sequences(text: str) -> list[int]:
    """``"3,8,10"`` or ``"all"`` -> sequence numbers."""
    if text.strip().lower() == "all":
        return list(ALL_SEQUENCES)
    try:
        seqs = [int(s) for s in text.split(",") if s.strip()]
    except ValueError:
        raise UserError(f"--sequences: expected numbers like 3,8,10 or 'all', got {text!r}") from None
    if not seqs or any(s < 0 for s in seqs):
        raise UserError(f"--sequences: expected non-negative numbers like 3,8,10, got {text!r}")
    return seqs


def match_rule(name: str) -> MatchRule:
    if name not in MATCH_RULES:
        raise UserError(f"--match must be one of {', '.join(MATCH_RULES)} (got {name!r})")
    return MATCH_RULES[name]


def kitti_class(name: str) -> KittiClass:
    """``--class`` -> the evaluated KITTI class (:data:`~deepcrashtest.eval.kitti_rules.KITTI_CLASSES`)."""
    if name not in KITTI_CLASSES:
        raise UserError(f"--class must be one of {', '.join(KITTI_CLASSES)} (got {name!r})")
    return KITTI_CLASSES[name]


def ground_truth_frames(
    root: Path, sequence: int, world: KittiWorld, cls: KittiClass = KITTI_CLASSES["car"]
) -> list[GroundTruthFrame]:
    """Ground truth of class ``cls`` and its distractors (Car/Van by default) and DontCare regions of every frame,
    world positions from :func:`~deepcrashtest.datasets.kitti.scenario.labels_frame_table` (the Scenario's frame)."""
    labels = labels_frame_table(root, sequence)
    boxes = world_table(world, labels)
    # ground-plane positions are labels_frame_table's own (the transform of the Scenario's agents)
    boxes["wx"], boxes["wy"] = labels["wx"], labels["wy"]
    kind = boxes["type"].to_numpy(dtype=str)
    is_vehicle = np.isin(kind, [cls.label_type, *cls.distractors]) & (boxes["track_id"].to_numpy() >= 0)
    evaluated = (
        (kind == cls.label_type)
        & (boxes["occluded"].to_numpy() <= MAX_OCCLUSION)
        & (boxes["truncated"].to_numpy() <= MAX_TRUNCATION)
    )
    objects = _objects(boxes)
    rect = boxes[["x1", "y1", "x2", "y2"]].to_numpy(dtype=float)
    frames = []
    for idx in frame_index(boxes["frame"].to_numpy(), world.n_frames):
        veh = idx[is_vehicle[idx]]
        frames.append(GroundTruthFrame(objects.take(veh), evaluated[veh], rect[idx[kind[idx] == "DontCare"]]))
    return frames


def _objects(table: pd.DataFrame) -> FrameObjects:
    return FrameObjects(
        ids=table["track_id"].to_numpy(dtype=int),
        boxes2d=table[["x1", "y1", "x2", "y2"]].to_numpy(dtype=float),
        world=table[WORLD_BOX_COLUMNS].to_numpy(dtype=float),
    )


def hypotheses_from_results(
    path: Path, world: KittiWorld, cls: KittiClass = KITTI_CLASSES["car"]
) -> list[FrameObjects]:
    """A tracker's results in KITTI tracking format, the rows of class ``cls`` (see :func:`hypotheses_from_table`)."""
    res = read_labels(path)
    if len(res) and (res["frame"].max() >= world.n_frames or res["frame"].min() < 0):
        raise UserError(f"{path}: frame numbers outside 0..{world.n_frames - 1}")
    return hypotheses_from_table(res, world, cls)


def hypotheses_from_table(
    res: pd.DataFrame, world: KittiWorld, cls: KittiClass = KITTI_CLASSES["car"]
) -> list[FrameObjects]:
    """KITTI result rows -> per-frame hypotheses: rows of ``cls``'s type (Car by default); world boxes where the row
    has a valid 3D box (positive size, in front of the camera), NaN otherwise (usable with ``iou2d`` only)."""
    res = res[res["type"].astype(str).str.lower() == cls.label_type.lower()]
    res = world_table(world, res)
    invalid = (res[["h", "w", "l"]].to_numpy(dtype=float) <= 0).any(axis=1) | (res["z"].to_numpy(dtype=float) <= 0)
    res.loc[invalid, WORLD_BOX_COLUMNS] = np.nan
    objects = _objects(res)
    return [objects.take(idx) for idx in frame_index(res["frame"].to_numpy(), world.n_frames)]


def world_detections(detections: pd.DataFrame, world: KittiWorld) -> list[WorldDetections]:
    """AB3DMOT detections of a sequence -> per-frame world-frame detections (ego motion removed)."""
    dets = world_table(world, detections)
    boxes = dets[WORLD_BOX_COLUMNS].to_numpy(dtype=float)
    scores = dets["score"].to_numpy(dtype=float)
    out = []
    for idx in frame_index(dets["frame"].to_numpy(), world.n_frames):
        b = boxes[idx]
        out.append(WorldDetections(xy=b[:, :2], z=b[:, 2], size=b[:, 3:6], yaw=b[:, 6], score=scores[idx]))
    return out


def run_world_tracker(
    detections: list[WorldDetections],
    world: KittiWorld,
    calib: KittiCalib,
    config: WorldTrackerConfig,
    offline: OfflineConfig | None = None,
) -> list[FrameObjects]:
    """Track a sequence (online, or with the offline pass when ``offline`` is given); each reported
    track's image box is its world box projected with P2."""
    tracker = WorldTracker(config)
    ids: list[list[int]] = [[] for _ in detections]
    boxes: list[list[np.ndarray]] = [[] for _ in detections]
    for f, dets in enumerate(detections):
        for o in tracker.step(dets):
            ids[f].append(o.track_id)
            boxes[f].append(o.box)
    if offline is not None:
        ids = [[] for _ in detections]
        boxes = [[] for _ in detections]
        for t in offline_tracks(tracker.histories(), offline, detections):
            for f, box in zip(t.frames, t.boxes, strict=True):
                ids[f].append(t.track_id)
                boxes[f].append(box)
    frames = []
    for f in range(len(detections)):
        b = np.array(boxes[f], dtype=float).reshape(-1, 7)
        frames.append(FrameObjects(np.array(ids[f], dtype=int), world.image_boxes(f, b, calib.P2), b))
    return frames


def _detection_file(root: Path, sequence: int, detections: str) -> Path:
    if detections == "pointrcnn":
        return KittiSequence(root, sequence).detections_pointrcnn
    folder = Path(detections)
    if not folder.is_dir():
        raise UserError(f"--detections: expected 'pointrcnn' or a folder of NNNN.txt files, got {detections!r}")
    return folder / f"{sequence:04d}.txt"


@dataclass
class PreparedSequence:
    """Everything about one sequence that does not depend on the tracker: world frame, calibration,
    ground truth and (world-frame) detections."""

    name: str
    world: KittiWorld
    calib: KittiCalib
    ground_truth: list[GroundTruthFrame]
    detections: list[WorldDetections]


def prepare_sequence(
    root: str | Path, sequence: int, detections: str | None = "pointrcnn", cls: KittiClass = KITTI_CLASSES["car"]
) -> PreparedSequence:
    """Read one sequence (``detections=None``: no detections needed; ``cls``: the evaluated class)."""
    root = Path(root)
    seq = KittiSequence(root, sequence).check()
    world = KittiWorld(read_poses(seq.poses))
    gt = ground_truth_frames(root, sequence, world, cls)
    dets: list[WorldDetections] = []
    if detections is not None:
        dets = world_detections(read_ab3dmot_detections(_detection_file(root, sequence, detections)), world)
    return PreparedSequence(seq.name, world, read_calib(seq.calib), gt, dets)


def track_and_rule(
    prepared: PreparedSequence, rule: MatchRule, config: WorldTrackerConfig, offline: OfflineConfig | None
) -> EvalSequence:
    """Run the world tracker on a prepared sequence and apply the KITTI rules."""
    hyps = run_world_tracker(prepared.detections, prepared.world, prepared.calib, config, offline)
    frames = [apply_kitti_rules(g, h, rule) for g, h in zip(prepared.ground_truth, hyps, strict=True)]
    return EvalSequence(prepared.name, frames)


def evaluate_kitti(
    root: str | Path,
    sequences: Iterable[int],
    *,
    match: str = "distance",
    detections: str = "pointrcnn",
    tracks: str | Path | None = None,
    tracker: WorldTrackerConfig | None = None,
    offline: OfflineConfig | None = DEFAULT_OFFLINE,
    object_class: str = "car",
) -> dict[str, Any]:
    """Evaluate this project's tracker (or the results in ``tracks``) on KITTI tracking sequences.

    ``offline=None`` scores the online tracker's per-frame output alone (no offline pass); ``object_class``: the
    class scored (car; pedestrian or cyclist only for ``tracks``: the PointRCNN detections are cars)."""
    rule = match_rule(match)
    cls = kitti_class(object_class)
    if tracks is None and cls.name != "car":
        raise UserError(
            f"--class {cls.name}: the LiDAR tracker runs on the PointRCNN car detections; score a tracker's results "
            "(--tracks) or the monocular path (--mono)"
        )
    config = tracker or DEFAULT_TRACKER
    seqs = list(sequences)
    evaluated = []
    for s in track(seqs, "evaluating sequences", total=len(seqs)):
        if tracks is not None:
            prep = prepare_sequence(root, s, None, cls)
            hyps = hypotheses_from_results(Path(tracks) / f"{prep.name}.txt", prep.world, cls)
            frames = [apply_kitti_rules(g, h, rule) for g, h in zip(prep.ground_truth, hyps, strict=True)]
            evaluated.append(EvalSequence(prep.name, frames))
        else:
            evaluated.append(track_and_rule(prepare_sequence(root, s, detections), rule, config, offline))
    rows = evaluate_sequences(evaluated, rule)
    notes = []
    for s in seqs:
        images = KittiSequence(Path(root), s).images
        if images.is_dir():
            n = len(list(images.glob("*.png")))
            notes.append(
                f"sequence {s:04d}: only {n} image(s) of the sequence are present, too few to run the monocular "
                "video pipeline; its per-frame 3D localisation error is measured by the geometry stage instead"
            )
    return {
        "match": match,
        "match_rule": rule.describe(),
        "class": cls.name,
        "hypotheses": str(tracks) if tracks is not None else f"world tracker on {detections} detections",
        "tracker": None if tracks is not None else asdict(config),
        "offline": None if tracks is not None or offline is None else asdict(offline),
        "sequences": rows,
        "paper": {f"{s:04d}": PAPER_TABLE[s] for s in seqs if s in PAPER_TABLE and cls.name == "car"},
        "notes": notes,
    }


def results_markdown(result: dict[str, Any]) -> str:
    """The result as a markdown table (our rows, then the paper's rows where it has them), under a line naming the
    class, the hypotheses and the match rule."""
    head = "| seq | " + " | ".join(TABLE_COLUMNS) + " | HOTA | IDSW |"
    title = f"KITTI tracking, class {result.get('class', 'car')}: {result['hypotheses']}; match: {result['match_rule']}"
    lines = [title, "", head, "|" + "---|" * (len(TABLE_COLUMNS) + 3)]
    for name, row in result["sequences"].items():
        lines.append(f"| {name} | " + " | ".join(_fmt(row[c]) for c in [*TABLE_COLUMNS, "HOTA", "IDSW"]) + " |")
    for name, row in result["paper"].items():
        lines.append(f"| paper {name} | " + " | ".join(_fmt(row[c]) for c in TABLE_COLUMNS) + " | - | - |")
    return "\n".join(lines) + "\n"


def _fmt(v: Any) -> str:
    return f"{v:.2f}" if isinstance(v, float) else str(v)
