"""Self-calibration against the KITTI calibration, sequence by sequence (training sequences only).

    PYTHONPATH=src nice -n 10 python bench/selfcalib_diag.py [--sequences 0,1,2] [--oracle] [--cache DIR]
        [--detect-every N]

Per sequence: the self-calibrated focal length (and each of its estimates: parked vehicles, vehicles
moving at a steady speed, turns, pitch bounce), forward-axis column, horizon row and camera height
with their 1-sigma, against the KITTI camera (``P2``, level: horizon ``cy``, 1.65 m) and the road the
labels show (a line through the labelled cars' bottom centres, 5-60 m: its horizon row and camera
height); and the MOTA with the KITTI
camera and with the unknown camera. ``--oracle`` adds the unknown camera's MOTA with one quantity at a
time replaced by the KITTI camera's (which one costs the MOTA), then focal length and height together
(``fy+hc``) and all four (``all``: the KITTI camera's values, the sources still ``self_calibration``). Default: the 18
training sequences other than 3, 8, 10 (never the held-out ones). At the end the mean per-sequence and the combined MOTA
(summed FN, FP, IDSW over summed ground truth; with ``--oracle`` for each swapped quantity too).
"""

from __future__ import annotations

import argparse
import ast
import hashlib
import math
import pickle
from dataclasses import replace
from pathlib import Path
from typing import Any

import numpy as np

from deepcrashtest.datasets.kitti.files import KittiSequence, read_labels
from deepcrashtest.datasets.kitti.scenario import KITTI_CAMERA_FORWARD_OFFSET_M
from deepcrashtest.eval.clear_mot import clear_only
from deepcrashtest.eval.kitti import match_rule
from deepcrashtest.eval.kitti_mono import (
    DEFAULT_MONO,
    MonoSequence,
    MonoTracking,
    ego_of,
    image_tracks,
    image_tracks_key,
    prepare_mono,
    score_sequence,
)
from deepcrashtest.geometry import selfcalib as sc_mod
from deepcrashtest.geometry.camera import default_camera
from deepcrashtest.geometry.selfcalib_moving import focal_from_moving
from deepcrashtest.geometry.world_tracks import raw_scenario_from_tracks
from deepcrashtest.scenario import Camera, VideoSource

DATA = Path(__file__).resolve().parents[1].parent / "shared" / "data" / "kitti_tracking"
HELD_OUT = (3, 8, 10)
TUNING = [s for s in range(21) if s not in HELD_OUT]


def _mota(prep: MonoSequence, tracks, cam: Camera, cfg: MonoTracking = DEFAULT_MONO) -> tuple[float, dict]:
    meta = VideoSource(
        kind="image_folder", path=prep.name, fps=10.0, frame_count=prep.world.n_frames,
        width=prep.size[0], height=prep.size[1],
    )  # fmt: skip
    sc = raw_scenario_from_tracks(
        tracks, meta, cam, ego_of(prep.world), name=prep.name, mono=cfg.mono, min_detected=cfg.min_detected_frames,
        min_confidence=cfg.min_confidence,
    )  # fmt: skip
    rule = match_rule("distance")
    ev, err = score_sequence(prep, sc, rule, not cfg.report_predicted)
    res = clear_only([ev], rule)[prep.name]
    return 100 * float(res["MOTA"]), res


def _label_road(seq: int, cam: Camera) -> tuple[float, float]:
    """(horizon row px, camera height m) of the road under the labelled cars: a robust line through their
    bottom centres' height below the camera against depth, ``y = hc + g z`` (horizon ``cy + fy g``)."""
    lab = read_labels(KittiSequence(DATA, seq).labels)
    ok = (lab["type"] == "Car") & (lab["truncated"] <= 0) & (lab["occluded"] <= 1) & lab["z"].between(5, 60)
    if ok.sum() < 10:
        return float("nan"), float("nan")
    hc, g = sc_mod._huber_line(lab["z"][ok].to_numpy(float), lab["y"][ok].to_numpy(float))
    return cam.cy + cam.fy * g, hc


def _calib_parts(tracks, start: Camera, size, ego) -> dict:
    motion = sc_mod.focal_from_motion(tracks, size, start.cx, ego)
    bounce = sc_mod.focal_from_pitch(tracks, size, ego)
    rot = sc_mod.focal_from_rotation(tracks, size, start.cx, ego, start.fy)
    moving = focal_from_moving(sc_mod._usable(tracks, size), start.cx, ego, start.fy, sc_mod.BOX_HEIGHT_EXCESS)
    return {"motion": motion, "moving": moving, "bounce": bounce, "rotation": rot}


def _combined(results: list[dict]) -> float:
    """Combined CLEAR-MOT MOTA (%) over sequences: 1 - (FN + FP + IDSW) / (TP + FN), summed."""
    fn, fp, sw, tp = (sum(float(r[k]) for r in results) for k in ("CLR_FN", "CLR_FP", "IDSW", "CLR_TP"))
    return 100.0 * (1.0 - (fn + fp + sw) / max(tp + fn, 1.0))


def training_args(ap: argparse.ArgumentParser, cache: str | None) -> tuple[argparse.Namespace, list[int], Path]:
    """Parse ``--sequences`` (training ones only: 3, 8, 10 refused) and ``--cache`` (created) besides ``ap``'s own."""
    ap.add_argument("--sequences", default=",".join(map(str, TUNING)))
    ap.add_argument("--cache", default=cache, required=cache is None)
    args = ap.parse_args()
    seqs = [int(s) for s in args.sequences.split(",")]
    if set(seqs) & set(HELD_OUT):
        raise SystemExit("diagnose on the training sequences only (3, 8, 10 are held out)")
    path = Path(args.cache)
    path.mkdir(parents=True, exist_ok=True)
    return args, seqs, path


def tracks_tag(config: MonoTracking) -> str:
    """A short name of the image tracker's settings (:func:`~deepcrashtest.eval.kitti_mono.image_tracks_key`): the
    cached tracks and what is computed from them are kept apart per setting."""
    return hashlib.sha1(repr(image_tracks_key(config)).encode()).hexdigest()[:10]


def tracking_config(mono: str = "", tracker: str = "") -> MonoTracking:
    """``DEFAULT_MONO`` with ``MonoConfig`` overrides ``mono`` and ``MonoTracking`` overrides ``tracker``
    (``name=literal,...``)."""

    def parsed(spec: str) -> dict[str, Any]:
        return {k: ast.literal_eval(v) for k, v in (p.split("=", 1) for p in spec.split(",") if p)}

    return replace(DEFAULT_MONO, mono=replace(DEFAULT_MONO.mono, **parsed(mono)), **parsed(tracker))


def load_sequence(s: int, cache: Path, config: MonoTracking = DEFAULT_MONO):
    """(prepared sequence, image tracks cached under ``cache`` per tracker setting (:func:`tracks_tag`; with
    ``config.detect_every`` > 1 from the boxes of every N-th frame only, the frames between carried by the image
    tracker: a video's cadence), ego motion, the unknown camera's start)."""
    prep = prepare_mono(DATA, s)
    f = cache / f"tracks_{s:04d}_{tracks_tag(config)}.pkl"
    if f.exists():
        tracks = pickle.loads(f.read_bytes())
    else:
        tracks = image_tracks(prep, config)
        f.write_bytes(pickle.dumps(tracks))
    start = default_camera(*prep.size).model_copy(update={"forward_offset_m": KITTI_CAMERA_FORWARD_OFFSET_M})
    return prep, tracks, ego_of(prep.world), start


def _fmt(e) -> str:
    return "-" if e is None else f"{e[0]:.0f}({100 * e[1]:.0f}%,{e[2]})"


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--oracle", action="store_true")
    ap.add_argument("--detect-every", type=int, default=1, help="boxes of every N-th frame only (a video's cadence)")
    args, seqs, cache = training_args(ap, "/tmp/selfcalib_diag")
    cfg = replace(DEFAULT_MONO, detect_every=args.detect_every)
    rows = []
    for s in seqs:
        prep, tracks, ego, start = load_sequence(s, cache, cfg)
        cal = sc_mod.self_calibrate(tracks, start, prep.size, ego)
        parts = _calib_parts(tracks, start, prep.size, ego)
        cam, true = cal.camera, prep.camera
        vh_road, hc_road = _label_road(s, true)
        travel = float(np.sum(np.hypot(np.diff(ego.x), np.diff(ego.y))))
        turn = float(np.degrees(np.sum(np.abs(np.diff(np.unwrap(ego.yaw))))))
        m_k, res_k = _mota(prep, tracks, true, cfg)
        m_u, res_u = _mota(prep, tracks, cam, cfg)
        row = {
            "seq": s, "frames": prep.world.n_frames, "travel_m": travel, "turn_deg": turn,
            "fy": cam.fy, "fy_sig": cam.focal_sigma_px or float("nan"), "fy_true": true.fy,
            "cx": cam.cx, "cx_true": true.cx, "vh": cal.horizon_v, "vh_sig": cal.horizon_sigma_px, "cy_true": true.cy,
            "hc": cal.height_m, "hc_sig": cal.height_sigma_m, "vh_road": vh_road, "hc_road": hc_road,
            "mota_k": m_k, "mota_u": m_u, "res_k": res_k, "res_u": res_u,
            "parts": {k: _fmt(v) for k, v in parts.items()}, "notes": cal.notes,
        }  # fmt: skip
        if args.oracle:
            sx = true.fy / cam.fy
            fixes = {
                "fy": cam.model_copy(update={"fy": true.fy, "fx": cam.fx * sx}),
                "cx": cam.model_copy(update={"cx": true.cx}),
                "hc": cam.model_copy(update={"height_m": true.height_m}),
                "vh": cam.model_copy(update={"pitch_rad": math.atan2(cam.cy - true.cy, cam.fy)}),
            }
            both = {"fy": true.fy, "fx": cam.fx * sx, "height_m": true.height_m}
            fixes["fy+hc"] = cam.model_copy(update=both)
            fixes["all"] = cam.model_copy(
                update={k: getattr(true, k) for k in ("fx", "fy", "cx", "cy", "height_m", "pitch_rad")}
            )
            row["oracle_res"] = {k: _mota(prep, tracks, c, cfg)[1] for k, c in fixes.items()}
            row["oracle"] = {k: 100 * float(v["MOTA"]) for k, v in row["oracle_res"].items()}
        rows.append(row)
        print(
            f"{s:04d} n{row['frames']} trav {travel:.0f}m turn {turn:.0f}d | fy {cam.fy:.0f}+-{row['fy_sig']:.0f} "
            f"true {true.fy:.0f} ({100 * (cam.fy / true.fy - 1):+.1f}%) {row['parts']} | cx {cam.cx:.0f} "
            f"true {true.cx:.0f} | vh {cal.horizon_v:.1f}+-{cal.horizon_sigma_px:.1f} cy {true.cy:.0f} "
            f"road {vh_road:.1f} | hc {cal.height_m:.2f}+-{cal.height_sigma_m:.2f} road {hc_road:.2f} | "
            f"MOTA kitti {m_k:.1f} "
            f"unknown {m_u:.1f} gap {m_u - m_k:+.1f}" + (f" oracle {row['oracle']}" if args.oracle else ""),
            flush=True,
        )
    (cache / "rows.pkl").write_bytes(pickle.dumps(rows))
    mk = np.mean([r["mota_k"] for r in rows])
    mu = np.mean([r["mota_u"] for r in rows])
    print(f"mean per-sequence MOTA kitti {mk:.2f} unknown {mu:.2f}")
    ck, cu = _combined([r["res_k"] for r in rows]), _combined([r["res_u"] for r in rows])
    line = f"combined MOTA kitti {ck:.2f} unknown {cu:.2f}"
    if args.oracle:
        line += " oracle " + " ".join(
            f"{k} {_combined([r['oracle_res'][k] for r in rows]):.2f}" for k in rows[0]["oracle_res"]
        )
    print(line)


if __name__ == "__main__":
    main()
