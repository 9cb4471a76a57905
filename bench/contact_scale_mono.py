"""Per-track range factor against the near ground contacts (KITTI camera, training sequences only).

    PYTHONPATH=src nice -n 10 python bench/contact_scale_mono.py [--sequences 0,1,2] [--min-below 150]

For every kept track's detected frame whose image box covers an evaluated labelled car (2D IoU >= 0.5),
the log range error ``log(range_track / range_label)`` (camera to centre, ground plane). Tracks are split
by whether any of their uncut detected boxes has its bottom edge ``--min-below`` px or more below the
horizon (a near ground contact, ``MonoConfig.contact_min_below_px``), and the errors are summarised by
range bin: rows, the spread across tracks of each track's mean log error (the per-track range factor),
the spread within tracks, and the share of rows within 2 m. Says how much of the 2-6 m loss lies in
tracks that have near contacts (which ``_contact_height`` already uses) and how much in tracks without.
"""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np
import pandas as pd

from deepcrashtest.datasets.kitti.results import scenario_result_table
from deepcrashtest.eval.boxes import iou_2d
from deepcrashtest.eval.kitti_mono import DEFAULT_MONO, image_tracks, mono_scenario, prepare_mono

DATA = Path(__file__).resolve().parents[1].parent / "shared" / "data" / "kitti_tracking"
TUNING = [s for s in range(21) if s not in (3, 8, 10)]
BINS = (0, 20, 40, 60, 1000)


def rows_of(seq: int, min_below: float) -> pd.DataFrame:
    """One row per (track, detected frame) matched to an evaluated labelled car."""
    prep = prepare_mono(DATA, seq)
    tracks = image_tracks(prep, DEFAULT_MONO)
    sc, cam = mono_scenario(prep, DEFAULT_MONO, "kitti", tracks)
    table = scenario_result_table(sc, prep.world, prep.P2, True, image_size=prep.size)
    det = tracks[tracks["state"] == "detected"]
    vh = cam.horizon_v()
    uncut = (det["y2"] < prep.size[1] - 2) & (det["y1"] > 1)
    near = det[uncut & (det["y2"] - vh >= min_below)].groupby("track_id").size()
    out = []
    for f, tf in table.groupby("frame"):
        g = prep.ground_truth[int(f)]
        ev = g.evaluated
        if not ev.any():
            continue
        gboxes, grange = g.objects.boxes2d[ev], prep.gt_range[int(f)][ev]
        tf = tf.merge(det[["track_id", "frame", "x1", "y1", "x2", "y2"]], on=["track_id", "frame"], suffixes=("_p", ""))
        hb = tf[["x1", "y1", "x2", "y2"]].to_numpy(float)
        iou = iou_2d(hb, gboxes.astype(float))
        cam_xyz = tf[["x", "z"]].to_numpy(float)
        for j in range(len(tf)):
            k = int(np.argmax(iou[j])) if iou.shape[1] else -1
            if k < 0 or iou[j, k] < 0.5:
                continue
            r = float(np.hypot(cam_xyz[j, 0], cam_xyz[j, 1]))
            tid = int(tf["track_id"].iloc[j])
            out.append((seq, tid, r, float(grange[k]), int(near.get(tid, 0))))
    return pd.DataFrame(out, columns=["seq", "track", "range", "gt_range", "near"])


def summary(df: pd.DataFrame) -> None:
    df = df.assign(err=np.log(df["range"] / df["gt_range"]), off=(df["range"] - df["gt_range"]).abs())
    df["bin"] = pd.cut(df["gt_range"], BINS, right=False)
    for has, part in df.groupby(df["near"] > 0):
        n_tracks = part[["seq", "track"]].drop_duplicates().shape[0]
        print(f"tracks {'with' if has else 'without'} near contacts: {n_tracks}")
        for b, p in part.groupby("bin", observed=True):
            tm = p.groupby(["seq", "track"])["err"].transform("mean")
            per_track = p.groupby(["seq", "track"])["err"].mean()
            print(
                f"  {b}: rows {len(p):5d}  median log err {p['err'].median():+.3f}  track-mean spread "
                f"{per_track.std():.3f}  within {(p['err'] - tm).std():.3f}  <2 m {100 * (p['off'] < 2).mean():.1f} %  "
                f"2-6 m {int(((p['off'] >= 2) & (p['off'] < 6)).sum())}"
            )


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--sequences", default=",".join(map(str, TUNING)))
    ap.add_argument("--min-below", type=float, default=150.0)
    args = ap.parse_args()
    seqs = [int(s) for s in args.sequences.split(",")]
    if set(seqs) & {3, 8, 10}:
        raise SystemExit("training sequences only (3, 8, 10 are held out)")
    parts = [p for p in (rows_of(s, args.min_below) for s in seqs) if len(p)]
    summary(pd.concat(parts, ignore_index=True))


if __name__ == "__main__":
    main()
