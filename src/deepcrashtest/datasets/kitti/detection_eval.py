"""Detection recall/precision against KITTI 2D labels (one-to-one matching at an IoU threshold).

Ground truth counted ("care"), like KITTI's "moderate" level: ``Car`` labels at most partly occluded
(``occluded <= 1``), at most partly truncated (tracking labels' level ``truncated <= 1``), box at least
``min_height`` = 25 px tall. Labels that are neither care nor irrelevant (other cars, ``Van``, ``Truck``,
``DontCare``) are "ignore" regions: a detection matching one (IoU >= threshold, or lying >= 50 %
inside a ``DontCare`` box) is neither a true nor a false positive, as in KITTI's own evaluation.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import pandas as pd
from scipy.optimize import linear_sum_assignment

from deepcrashtest.perception.boxes import intersection_over_smaller, iou_matrix


@dataclass
class MatchCounts:
    """True positives, false positives, false negatives summed over images."""

    tp: int = 0
    fp: int = 0
    fn: int = 0

    @property
    def recall(self) -> float:
        return self.tp / (self.tp + self.fn) if self.tp + self.fn else float("nan")

    @property
    def precision(self) -> float:
        return self.tp / (self.tp + self.fp) if self.tp + self.fp else float("nan")

    def __iadd__(self, other: MatchCounts) -> MatchCounts:
        self.tp += other.tp
        self.fp += other.fp
        self.fn += other.fn
        return self


def split_kitti_cars(labels: pd.DataFrame, min_height: float = 25.0) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Labels of one frame -> (care boxes, ignore boxes, dontcare boxes), each (N, 4) pixels."""
    box = labels[["x1", "y1", "x2", "y2"]].to_numpy(dtype=np.float64)
    tall = (labels["y2"] - labels["y1"]).to_numpy() >= min_height
    is_car = (labels["type"] == "Car").to_numpy()
    visible = (labels["occluded"].to_numpy() <= 1) & (labels["truncated"].to_numpy() <= 1)
    care = is_car & visible & tall
    vehicle = labels["type"].isin(["Car", "Van", "Truck"]).to_numpy()
    dontcare = (labels["type"] == "DontCare").to_numpy()
    return box[care], box[vehicle & ~care], box[dontcare]


def match_frame(
    pred: np.ndarray,
    care: np.ndarray,
    ignore: np.ndarray | None = None,
    dontcare: np.ndarray | None = None,
    iou_threshold: float = 0.5,
) -> MatchCounts:
    """Count TP/FP/FN of one image with an optimal one-to-one IoU matching (SciPy Hungarian)."""
    pred = np.asarray(pred, dtype=np.float64).reshape(-1, 4)
    care = np.asarray(care, dtype=np.float64).reshape(-1, 4)
    matched = np.zeros(len(pred), dtype=bool)
    tp = 0
    if len(pred) and len(care):
        iou = iou_matrix(care, pred)
        rows, cols = linear_sum_assignment(-iou)
        good = iou[rows, cols] >= iou_threshold
        tp = int(good.sum())
        matched[cols[good]] = True
    rest = ~matched
    if ignore is not None and len(ignore) and rest.any():
        rest &= ~(iou_matrix(pred, ignore).max(axis=1) >= iou_threshold)
    if dontcare is not None and len(dontcare) and rest.any():
        inside = intersection_over_smaller(pred, dontcare)
        area_p = (pred[:, 2] - pred[:, 0]) * (pred[:, 3] - pred[:, 1])
        area_d = (dontcare[:, 2] - dontcare[:, 0]) * (dontcare[:, 3] - dontcare[:, 1])
        # share of the detection inside a DontCare region (intersection / detection area)
        frac = inside * np.minimum(area_p[:, None], area_d[None, :]) / np.maximum(area_p[:, None], 1e-9)
        rest &= ~(frac.max(axis=1) >= 0.5)
    return MatchCounts(tp=tp, fp=int(rest.sum()), fn=int(len(care) - tp))
