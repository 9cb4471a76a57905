"""The road's drop below the camera against range: the labels' against the tracks' (``MonoConfig.road_profile``).

    PYTHONPATH=src nice -n 10 python bench/road_profile_mono.py --cache DIR [--sequences 0,1,2] [--sigma 0.1]
        [--horizon-hull]

Per training sequence (never 3, 8, 10; the KITTI camera, image tracks cached under ``--cache`` as in
``bench/mono_variants.py``): the labelled Cars / Vans' road drop as the mono path reads it, ``y + (cy - v_h) z / fy``
(``y`` the label's road under the car below the camera, ``v_h`` the frame's horizon row that the path used, px),
as ``log(drop / camera height)``, median per range bin (12-20, 20-30, 30-45, 45-60, 60-80 m; >= 20 labels) with
the flat road's per-frame horizon (``flat-h``) and the profile's (``prof-h``), and the profile the tracks give at
each bin's middle (``est``, :func:`deepcrashtest.geometry.mono3d.road_profile`: 0 up to ``road_ref_m``). The last
line: mean |log| gap of the flat road and of the profile to the labels, each bin's drop taken relative to
the nearest bin's (the profile's level is the camera's height, which it does not estimate).
"""

from __future__ import annotations

import argparse
from dataclasses import replace
from pathlib import Path

import numpy as np
import pandas as pd
from selfcalib_diag import load_sequence, training_args

import deepcrashtest.geometry.mono3d as m3
from deepcrashtest.datasets.kitti.files import KittiSequence, read_labels
from deepcrashtest.eval.kitti_mono import DEFAULT_MONO

DATA = Path(__file__).resolve().parents[1].parent / "shared" / "data" / "kitti_tracking"
BINS = np.array([12.0, 20.0, 30.0, 45.0, 60.0, 80.0])


def label_drop(labels: pd.DataFrame, states: pd.DataFrame, cy: float, fy: float) -> np.ndarray:
    """Median log(drop / 1.65 m) of the labelled cars per range bin against the horizon rows of ``states``."""
    hv = states.dropna(subset=["horizon_v"]).groupby("frame")["horizon_v"].median()
    lab = labels[labels["frame"].isin(hv.index)]
    z = lab["z"].to_numpy(float)
    drop = lab["y"].to_numpy(float) + (cy - hv.loc[lab["frame"]].to_numpy(float)) * z / fy
    out = []
    for lo, hi in zip(BINS[:-1], BINS[1:], strict=True):
        sel = (z >= lo) & (z < hi) & (drop > 0)
        out.append(float(np.median(np.log(drop[sel] / 1.65))) if sel.sum() >= 20 else np.nan)
    return np.array(out)


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--sigma", type=float, default=0.1, help="MonoConfig.road_knot_sigma")
    ap.add_argument("--horizon-hull", action="store_true", help="MonoConfig.horizon_hull")
    args, seqs, cache = training_args(ap, None)
    cfg = replace(DEFAULT_MONO.mono, road_profile=True, road_knot_sigma=args.sigma, horizon_hull=args.horizon_hull)
    gaps: dict[str, list[float]] = {"flat": [], "profile": []}
    mid = 0.5 * (BINS[:-1] + BINS[1:])
    for s in seqs:
        prep, tracks, ego, _ = load_sequence(s, cache)
        cam = prep.camera
        labels = read_labels(KittiSequence(DATA, s).labels)
        labels = labels[labels["type"].isin(["Car", "Van"]) & (labels["occluded"] <= 1)]
        flat = label_drop(
            labels,
            m3.localize_tracks(tracks, cam, ego, prep.size, 10.0, replace(cfg, road_profile=False)),
            cam.cy,
            cam.fy,
        )
        prof = label_drop(labels, m3.localize_tracks(tracks, cam, ego, prep.size, 10.0, cfg), cam.cy, cam.fy)
        r = m3.road_profile_of(tracks, cam, ego, prep.size, cfg)
        est = np.log(r.ratio(mid)) if r is not None else np.zeros(len(mid))
        ok = np.isfinite(flat) & np.isfinite(prof)
        if ok.sum() >= 2:
            first = int(np.nonzero(ok)[0][0])
            gaps["flat"] += list(np.abs(flat[ok] - flat[first]))
            gaps["profile"] += list(np.abs(prof[ok] - prof[first] - (est[ok] - est[first])))
        print(f"{s:04d} flat-h {np.round(flat, 3)} prof-h {np.round(prof, 3)} est {np.round(est, 3)}", flush=True)
    print(
        f"mean |log gap| to the labels' drop (relative to the nearest bin): flat {np.mean(gaps['flat']):.4f}, "
        f"profile {np.mean(gaps['profile']):.4f} ({len(gaps['flat'])} bins)"
    )


if __name__ == "__main__":
    main()
