"""CLEAR-MOT, HOTA and identity metrics of sequences already reduced by the KITTI rules.

The reported CLEAR-MOT, HOTA and IDF1 come from TrackEval's metric classes (whose KITTI numbers this
project reproduces exactly, see ``tests/test_eval_kitti.py``); ``motmetrics`` computes CLEAR-MOT a second
time on the same data (distance = 1 - similarity, pairs the match rule forbids are NaN) and gives
the per-frame matches for MODP. The two differ only in identity switches: motmetrics first re-pairs
an object with the hypothesis it last had even after a gap, TrackEval only across consecutive
frames, so after a gap they may pick different hypotheses. Definitions
(GT = evaluated ground-truth boxes, summed over frames; percentages in the reported table):

* MOTA = 1 - (FN + FP + IDSW) / GT; MODA = 1 - (FN + FP) / GT.
* MOTP = mean similarity of the matched pairs (mean IoU, or 1 - mean(d)/2 m for distance matching).
* MODP = mean over frames of the per-frame mean similarity of the matches, a frame without
  matches counting 1 (the KITTI devkit's ``MODP_t`` convention).
* recall = TP / GT, precision = TP / (TP + FP), F1 = their harmonic mean.
* FAR = false alarms per frame, FP / frames, x 100 (the paper's column).
* MT / PT / ML: share of ground-truth trajectories matched in >= 80 %, 20-80 %, < 20 % of their frames.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from deepcrashtest.eval.compat import motmetrics, trackeval_metrics
from deepcrashtest.eval.kitti_rules import EvalFrame, MatchRule

_MM_METRICS = [
    "num_frames", "num_objects", "num_detections", "num_false_positives", "num_misses", "num_switches",
    "num_fragmentations", "mota", "motp", "mostly_tracked", "partially_tracked", "mostly_lost",
    "num_unique_objects", "precision", "recall",
]  # fmt: skip


@dataclass
class EvalSequence:
    """One sequence after the KITTI rules, frame by frame (frame t of the list is image t)."""

    name: str
    frames: list[EvalFrame]
    extra: dict[str, Any] = field(default_factory=dict)


def accumulate(seq: EvalSequence, rule: MatchRule) -> Any:
    """A ``motmetrics.MOTAccumulator`` fed with every frame of ``seq``."""
    mm = motmetrics()
    acc = mm.MOTAccumulator(auto_id=False)
    for t, f in enumerate(seq.frames):
        dist = 1.0 - f.similarity
        dist[~rule.allows(f.similarity)] = np.nan
        acc.update(f.gt_ids, f.hyp_ids, dist, frameid=t)
    return acc


def _modp_terms(acc: Any, n_frames: int) -> np.ndarray:
    """Per-frame mean similarity of the matches (1 for frames without any), devkit style."""
    ev = acc.mot_events
    hits = ev[ev["Type"].isin(["MATCH", "SWITCH"])]
    per_frame = (1.0 - hits["D"]).groupby(level=0).mean()
    terms = np.ones(n_frames)
    terms[per_frame.index.to_numpy(dtype=int)] = per_frame.to_numpy()
    return terms


def _trackeval_data(seq: EvalSequence) -> dict[str, Any]:
    """The dict TrackEval's metrics expect: ids relabelled 0..n-1 per sequence."""
    gt_all = np.unique(np.concatenate([f.gt_ids for f in seq.frames] + [np.zeros(0, int)]))
    hyp_all = np.unique(np.concatenate([f.hyp_ids for f in seq.frames] + [np.zeros(0, int)]))
    return {
        "gt_ids": [np.searchsorted(gt_all, f.gt_ids) for f in seq.frames],
        "tracker_ids": [np.searchsorted(hyp_all, f.hyp_ids) for f in seq.frames],
        "similarity_scores": [f.similarity for f in seq.frames],
        "num_gt_ids": len(gt_all),
        "num_tracker_ids": len(hyp_all),
        "num_gt_dets": int(sum(len(f.gt_ids) for f in seq.frames)),
        "num_tracker_dets": int(sum(len(f.hyp_ids) for f in seq.frames)),
        "num_timesteps": len(seq.frames),
        "seq": seq.name,
    }


def _trackeval_metrics(rule: MatchRule) -> list[Any]:
    m = trackeval_metrics()
    cfg = {"THRESHOLD": rule.threshold, "PRINT_CONFIG": False}
    return [m.CLEAR(cfg), m.HOTA(), m.Identity(cfg)]


def evaluate_sequences(seqs: Sequence[EvalSequence], rule: MatchRule) -> dict[str, dict[str, Any]]:
    """Metrics of every sequence and of all of them together (key ``"combined"``)."""
    mm = motmetrics()
    accs = [accumulate(s, rule) for s in seqs]
    names = [s.name for s in seqs]
    summary = mm.metrics.create().compute_many(accs, metrics=_MM_METRICS, names=names, generate_overall=len(seqs) > 1)
    metrics = _trackeval_metrics(rule)
    te: dict[str, dict[str, dict[str, Any]]] = {m.get_name(): {} for m in metrics}
    for s in seqs:
        data = _trackeval_data(s)
        for m in metrics:
            te[m.get_name()][s.name] = m.eval_sequence(data)
    modp = {s.name: _modp_terms(a, len(s.frames)) for s, a in zip(seqs, accs, strict=True)}
    rows: dict[str, dict[str, Any]] = {}
    for s in seqs:
        rows[s.name] = _row(summary.loc[s.name], {k: v[s.name] for k, v in te.items()}, modp[s.name], rule)
        rows[s.name].update(s.extra)
    if len(seqs) > 1:
        combined = {k: m.combine_sequences(te[k]) for k, m in zip(te, metrics, strict=True)}
        rows["combined"] = _row(summary.loc["OVERALL"], combined, np.concatenate(list(modp.values())), rule)
    return rows


def _pct(x: float) -> float:
    return round(100.0 * float(x), 2)


def _row(mm_row: Any, te: dict[str, dict[str, Any]], modp_terms: np.ndarray, rule: MatchRule) -> dict[str, Any]:
    clear, hota, ident = te["CLEAR"], te["HOTA"], te["Identity"]
    tp, fp, fn = int(clear["CLR_TP"]), int(clear["CLR_FP"]), int(clear["CLR_FN"])
    gt = tp + fn
    frames = int(clear["CLR_Frames"])
    tracks = int(clear["MT"] + clear["PT"] + clear["ML"])
    recall = tp / gt if gt else 0.0
    precision = tp / (tp + fp) if tp + fp else 0.0
    f1 = 2 * recall * precision / (recall + precision) if recall + precision else 0.0
    mm_mean_dist = float(mm_row["motp"]) if int(mm_row["num_detections"]) else float("nan")
    row: dict[str, Any] = {
        "MOTA": _pct(clear["MOTA"]),
        "MOTP": _pct(clear["MOTP"]),
        "MODA": _pct(clear["MODA"]),
        "MODP": _pct(modp_terms.mean()) if len(modp_terms) else 0.0,
        "recall": _pct(recall),
        "precision": _pct(precision),
        "F1": _pct(f1),
        "TP": tp,
        "FP": fp,
        "FN": fn,
        "FAR": _pct(fp / frames) if frames else 0.0,
        "MT": _pct(clear["MT"] / tracks) if tracks else 0.0,
        "PT": _pct(clear["PT"] / tracks) if tracks else 0.0,
        "ML": _pct(clear["ML"] / tracks) if tracks else 0.0,
        "IDSW": int(clear["IDSW"]),
        "Frag": int(clear["Frag"]),
        "GT": gt,
        "GT_tracks": tracks,
        "frames": frames,
        "HOTA": _pct(np.mean(hota["HOTA"])),
        "DetA": _pct(np.mean(hota["DetA"])),
        "AssA": _pct(np.mean(hota["AssA"])),
        "IDF1": _pct(ident["IDF1"]),
        # the same CLEAR-MOT from motmetrics (its matching keeps a pair across gaps, so IDSW can differ)
        "MOTA_motmetrics": _pct(mm_row["mota"]) if int(mm_row["num_objects"]) else 0.0,
        "MOTP_motmetrics": _pct(1.0 - mm_mean_dist) if np.isfinite(mm_mean_dist) else 0.0,
        "IDSW_motmetrics": int(mm_row["num_switches"]),
        "TP_motmetrics": int(mm_row["num_detections"]),
        "FP_motmetrics": int(mm_row["num_false_positives"]),
    }
    if rule.name == "distance":
        mean_sim = float(clear["MOTP"])
        row["mean_distance_m"] = round((1.0 - mean_sim) * rule.max_distance_m, 3) if tp else None
    return row


def clear_only(seqs: Sequence[EvalSequence], rule: MatchRule) -> dict[str, dict[str, Any]]:
    """TrackEval's CLEAR-MOT alone (fast; for tuning): raw TrackEval fields per sequence and
    ``"combined"``."""
    clear = trackeval_metrics().CLEAR({"THRESHOLD": rule.threshold, "PRINT_CONFIG": False})
    res = {s.name: clear.eval_sequence(_trackeval_data(s)) for s in seqs}
    res["combined"] = clear.combine_sequences(res)
    return res
