"""Are PointRCNN's image boxes biased with range? Their depth cues against the labels, by label type and range.

    PYTHONPATH=src nice -n 10 python bench/cue_bias_mono.py [--sequences 0,1,2]

Each labelled Car / Van (untruncated, occlusion <= 1) of the training sequences other than 3, 8, 10 (never the
held-out ones) that a PointRCNN box covers (2D IoU >= 0.5) gives, with its near face at ``z - l / 2`` (m): the
box height over ``fy h / z_near`` (``box_h``: the box-height cue's factor, the roof's far edge included), the
bottom row's depth below the principal row over ``fy y / z_near`` (``bottom``: the bottom-edge cue's factor,
``y`` the label's road height below the camera), and the height the mono path's class choice reads from the
box (``box_h y / below``, m) with the label's road (``h_road``) and with the flat 1.65 m road of the KITTI
camera (``h_flat``). Medians per label type and range bin (m), with the labels' median height ``h`` and road ``y``.
"""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np
import pandas as pd

from deepcrashtest.datasets.kitti.files import KittiSequence, read_ab3dmot_detections, read_calib, read_labels
from deepcrashtest.eval.boxes import iou_2d

DATA = Path(__file__).resolve().parents[1].parent / "shared" / "data" / "kitti_tracking"
TUNING = [s for s in range(21) if s not in (3, 8, 10)]
BOX = ["x1", "y1", "x2", "y2"]


def covered(seq: int) -> pd.DataFrame:
    """Labelled Cars / Vans of one sequence with the PointRCNN box covering each (columns of the label
    plus ``bh`` box height px, ``below`` bottom row minus ``cy`` px, ``fy`` px)."""
    files = KittiSequence(DATA, seq)
    lab = read_labels(files.labels)
    P2 = read_calib(files.calib).P2
    det = dict(iter(read_ab3dmot_detections(files.detections_pointrcnn).groupby("frame")))
    lab = lab[lab["type"].isin(["Car", "Van"]) & (lab["truncated"] <= 0) & (lab["occluded"] <= 1)]
    parts = []
    for f, g in lab.groupby("frame"):
        d = det.get(f)
        if d is None:
            continue
        iou = iou_2d(g[BOX].to_numpy(float), d[BOX].to_numpy(float))
        ok = iou.max(axis=1) >= 0.5
        box = d[BOX].to_numpy(float)[iou.argmax(axis=1)[ok]]
        parts.append(g[ok].assign(bh=box[:, 3] - box[:, 1], below=box[:, 3] - P2[1, 2], fy=P2[1, 1]))
    return pd.concat(parts, ignore_index=True) if parts else pd.DataFrame()


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--sequences", default=",".join(map(str, TUNING)))
    seqs = [int(s) for s in ap.parse_args().sequences.split(",")]
    if {3, 8, 10} & set(seqs):
        raise SystemExit("training sequences only (3, 8, 10 are held out)")
    df = pd.concat([covered(s) for s in seqs], ignore_index=True)
    z_near = df["z"] - df["l"] / 2
    df = df.assign(
        bin=pd.cut(df["z"], [0, 15, 25, 35, 45, 60, 80]),
        box_h=df["bh"] * z_near / df["fy"] / df["h"],
        bottom=df["below"] * z_near / df["fy"] / df["y"],
        h_road=df["bh"] * df["y"] / np.maximum(df["below"], 1e-3),
        h_flat=df["bh"] * 1.65 / np.maximum(df["below"], 1e-3),
    )
    table = df.groupby(["type", "bin"], observed=True).agg(
        n=("z", "size"), h=("h", "median"), y=("y", "median"), box_h=("box_h", "median"),
        bottom=("bottom", "median"), h_road=("h_road", "median"), h_flat=("h_flat", "median"),
    )  # fmt: skip
    print(table.round(3).to_string())


if __name__ == "__main__":
    main()
