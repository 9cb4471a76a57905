"""KITTI tracking evaluation rules (class *car*; *pedestrian* and *cyclist* alike, :data:`KITTI_CLASSES`), as
TrackEval's ``Kitti2DBox`` applies them, with a pluggable similarity so the same rules hold for image boxes and for
world-frame boxes.

Per frame:

1. Ground truth of class Car and Van is matched to hypotheses (Hungarian, on the similarity, pairs
   below the match threshold excluded).
2. Hypotheses matched to a *distractor* (a Van, or a Car with occlusion > 2 or truncation > 0) are
   dropped: they are neither true nor false positives. (Class pedestrian: Pedestrian and its distractor
   Person, KITTI's person sitting, as TrackEval; class cyclist: Cyclist, no distractor class.)
3. Unmatched hypotheses are dropped when their image box is 25 px tall or less, or lies more than
   50 % inside a DontCare region (intersection over the hypothesis' own area). A hypothesis that
   does not project into the image at all (a world-frame track outside the camera's view, where
   nothing is labelled) counts as 0 px tall.
4. Distractor ground truth is removed; what is left (visible, untruncated Cars) is evaluated.

Other classes take no part (for cars, a hypothesis on a truck is a false positive).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Literal

import numpy as np
from scipy.optimize import linear_sum_assignment

from deepcrashtest.eval.boxes import bev_distance, ioa_2d, iou_2d, iou_3d

EVAL_CLASS = "Car"
DISTRACTOR_CLASSES = ("Van",)


@dataclass(frozen=True)
class KittiClass:
    """One evaluated KITTI class: its label type, the label types that are its distractors, and the detector
    category of its boxes (the pipeline's road-user category, :mod:`deepcrashtest.perception.roadusers`)."""

    name: str
    label_type: str
    distractors: tuple[str, ...]
    category: str


#: The classes ``evaluate kitti`` scores (``--class``). A KITTI Cyclist box holds the rider and the bicycle, as the
#: pipeline's ``bicycle`` road user does (the rider's box joined to the two-wheeler's).
KITTI_CLASSES: dict[str, KittiClass] = {
    "car": KittiClass("car", EVAL_CLASS, DISTRACTOR_CLASSES, "car"),
    "pedestrian": KittiClass("pedestrian", "Pedestrian", ("Person",), "pedestrian"),
    "cyclist": KittiClass("cyclist", "Cyclist", (), "bicycle"),
}
MAX_OCCLUSION = 2
MAX_TRUNCATION = 0
MIN_HEIGHT_PX = 25.0
DONTCARE_MAX_IOA = 0.5
_EPS = float(np.finfo(float).eps)

MatchName = Literal["iou2d", "iou3d", "distance"]


@dataclass(frozen=True)
class FrameObjects:
    """Objects of one frame: ids (n,), image boxes (n, 4) ``x1 y1 x2 y2`` pixels (NaN: not in the
    image), world boxes (n, 7) ``x y z l w h yaw`` (see :mod:`deepcrashtest.eval.boxes`; NaN: unknown)."""

    ids: np.ndarray
    boxes2d: np.ndarray
    world: np.ndarray

    def __len__(self) -> int:
        return len(self.ids)

    @staticmethod
    def empty() -> FrameObjects:
        return FrameObjects(np.zeros(0, int), np.zeros((0, 4)), np.zeros((0, 7)))

    def take(self, index: np.ndarray) -> FrameObjects:
        """The objects at ``index`` (integer positions or a boolean mask)."""
        return FrameObjects(self.ids[index], self.boxes2d[index], self.world[index])


@dataclass(frozen=True)
class GroundTruthFrame:
    """Ground truth of one frame: Car and Van objects, which of them are evaluated (the rest are
    distractors), and the DontCare regions (k, 4) in pixels."""

    objects: FrameObjects
    evaluated: np.ndarray
    dontcare: np.ndarray


@dataclass(frozen=True)
class MatchRule:
    """How a ground-truth object and a hypothesis are compared.

    * ``iou2d``: image-box IoU, match at IoU >= 0.5 (KITTI / TrackEval CLEAR).
    * ``iou3d``: 3D IoU of the world boxes, match at IoU >= 0.25 (the KITTI 3D / AB3DMOT criterion).
    * ``distance``: bird's-eye distance d between box centres in the world frame; similarity
      ``s = max(0, 1 - d / max_distance_m)``, a match needs d < ``max_distance_m`` (2 m), so MOTP
      (the mean similarity of matches) is ``1 - mean(d) / 2 m``.
    """

    name: MatchName
    threshold: float
    max_distance_m: float = 2.0

    def similarity(self, gt: FrameObjects, hyp: FrameObjects) -> np.ndarray:
        if self.name == "iou2d":
            return iou_2d(gt.boxes2d, hyp.boxes2d)
        if self.name == "iou3d":
            return iou_3d(gt.world, hyp.world)
        d = bev_distance(gt.world, hyp.world)
        return np.nan_to_num(np.clip(1.0 - d / self.max_distance_m, 0.0, 1.0), nan=0.0)

    def allows(self, similarity: np.ndarray) -> np.ndarray:
        """Which pairs may be matched."""
        return (similarity >= self.threshold - _EPS) & (similarity > _EPS)

    def describe(self) -> str:
        if self.name == "distance":
            return f"bird's-eye distance < {self.max_distance_m:g} m, MOTP = 1 - mean(d)/{self.max_distance_m:g} m"
        return f"{'image-box' if self.name == 'iou2d' else '3D'} IoU >= {self.threshold:g}, MOTP = mean IoU"


MATCH_RULES: dict[str, MatchRule] = {
    "iou2d": MatchRule("iou2d", 0.5),
    "iou3d": MatchRule("iou3d", 0.25),
    "distance": MatchRule("distance", 1e-6, 2.0),
}


@dataclass(frozen=True)
class EvalFrame:
    """One frame after the KITTI rules: evaluated ground truth, kept hypotheses, similarity (n, m)."""

    gt_ids: np.ndarray
    hyp_ids: np.ndarray
    similarity: np.ndarray


def apply_kitti_rules(gt: GroundTruthFrame, hyp: FrameObjects, rule: MatchRule) -> EvalFrame:
    """Steps 1-4 of the module docstring for one frame."""
    sim = rule.similarity(gt.objects, hyp)
    remove = np.zeros(len(hyp), bool)
    matched = np.zeros(len(hyp), bool)
    if len(gt.objects) and len(hyp):
        scores = np.where(rule.allows(sim), sim, 0.0)
        rows, cols = linear_sum_assignment(-scores)
        ok = scores[rows, cols] > _EPS
        rows, cols = rows[ok], cols[ok]
        matched[cols] = True
        remove[cols[~gt.evaluated[rows]]] = True
    unmatched = ~matched
    heights = hyp.boxes2d[:, 3] - hyp.boxes2d[:, 1]
    too_small = ~(heights > MIN_HEIGHT_PX + _EPS)  # NaN (not in the image) counts as too small
    in_dontcare = np.zeros(len(hyp), bool)
    if len(gt.dontcare) and len(hyp):
        boxes = np.nan_to_num(hyp.boxes2d, nan=0.0)
        in_dontcare = np.any(ioa_2d(boxes, gt.dontcare) > DONTCARE_MAX_IOA + _EPS, axis=1)
    remove |= unmatched & (too_small | in_dontcare)
    keep_hyp = ~remove
    return EvalFrame(
        gt_ids=gt.objects.ids[gt.evaluated],
        hyp_ids=hyp.ids[keep_hyp],
        similarity=sim[gt.evaluated][:, keep_hyp],
    )
