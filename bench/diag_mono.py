"""Where the monocular path loses MOTA: FN / FP / IDSW broken down by cause and by distance.

    PYTHONPATH=src nice -n 10 python bench/diag_mono.py [--sequences 0,1,2] [--camera kitti|unknown] [--classes]

Default: the 18 training sequences other than 3, 8, 10 (never the held-out ones unless asked).
Per frame, an evaluated ground-truth car left unmatched (2 m world gate) is a *localisation* miss
when a kept hypothesis covers its image box (IoU >= 0.5), a *tracker* miss when a PointRCNN box
(score kept or not) covers it but no track does, else a *detector* miss. An unmatched kept
hypothesis is a *localisation* FP when its image box covers an evaluated car, else it is named by
the label class it covers (Van, Truck, Pedestrian...; distractor cars: occluded/truncated), or
*ghost*. Counts by the camera-to-object range bin.

``--lifecycle``: where each unmatched evaluated car under a detector box is lost along the path (box under
``min_score``; no image-track row on it; its image track dropped by ``min_detected`` / ``min_confidence``; its
agent typed other than Car; its agent 2-6 m or > 6 m off), by range bin; and the FP by the agent's age
(detected frames) and whether it is a never-matched / mostly-FP / mostly-TP track.

``--standing``: per range bin, the evaluated label rows of standing cars (labelled world speed < 0.5 m/s over
+-0.5 s) and of moving ones, how many were missed, and how many have their nearest kept hypothesis 2-6 m off (the
standing-vehicle fit's target, ``MonoConfig.static_fit``).

``--classes``: the class choice per track instead (KITTI camera): each kept track's typed class
against the label type its detected boxes cover (2D IoU >= 0.5, majority), in detected frames, and
per label type and range bin the median height its bottom edges imply (``box_h (v_bottom -
v_horizon)^-1 h_camera``, m) and the median log box height/width against the car prior's (the class
choice's aspect term): what the car/van choice has to go by.
"""

from __future__ import annotations

import argparse
from collections import Counter
from pathlib import Path

import numpy as np
import pandas as pd
from scipy.optimize import linear_sum_assignment
from selfcalib_diag import tracking_config

from deepcrashtest.datasets.kitti.files import KITTI_FPS, KittiSequence, read_labels
from deepcrashtest.datasets.kitti.results import scenario_result_table
from deepcrashtest.datasets.kitti.world import world_table
from deepcrashtest.eval.boxes import iou_2d
from deepcrashtest.eval.clear_mot import clear_only
from deepcrashtest.eval.kitti import hypotheses_from_table, match_rule
from deepcrashtest.eval.kitti_mono import (
    DEFAULT_MONO,
    MonoTracking,
    ego_of,
    image_tracks,
    mono_scenario,
    prepare_mono,
    score_sequence,
)
from deepcrashtest.eval.kitti_rules import apply_kitti_rules
from deepcrashtest.geometry.mono3d import localize_tracks
from deepcrashtest.geometry.mono_config import class_size
from deepcrashtest.geometry.mono_size import hull_factor

DATA = Path(__file__).resolve().parents[1].parent / "shared" / "data" / "kitti_tracking"
TUNING = [s for s in range(21) if s not in (3, 8, 10)]
BINS = (0, 20, 40, 60, 1000)
ERR: list = []


def _bin(r: float) -> str:
    for lo, hi in zip(BINS[:-1], BINS[1:], strict=True):
        if lo <= r < hi:
            return f"{lo}-{hi}"
    return "?"


def diagnose(seq: int, camera: str, config: MonoTracking = DEFAULT_MONO) -> tuple[dict, Counter, Counter]:
    prep = prepare_mono(DATA, seq, camera=camera)
    sc, _ = mono_scenario(prep, config, camera)
    rule = match_rule("distance")
    table = scenario_result_table(sc, prep.world, prep.P2, True, image_size=prep.size)
    allh = world_table(prep.world, table)
    hyps = hypotheses_from_table(table, prep.world)
    ev, _ = score_sequence(prep, sc, rule)
    res = clear_only([ev], rule)[prep.name]
    labels = world_table(prep.world, read_labels(KittiSequence(DATA, seq).labels))
    lab_by = dict(iter(labels.groupby("frame")))
    hyp_by = dict(iter(allh.groupby("frame")))
    fn, fp = Counter(), Counter()
    for f, (g, h) in enumerate(zip(prep.ground_truth, hyps, strict=True)):
        fr = apply_kitti_rules(g, h, rule)
        keep = np.isin(h.ids, fr.hyp_ids)
        sim = fr.similarity
        matched_g = np.zeros(len(fr.gt_ids), bool)
        matched_h = np.zeros(sim.shape[1], bool)
        if sim.size:
            rows, cols = linear_sum_assignment(-sim)
            ok = sim[rows, cols] > 1e-9
            matched_g[rows[ok]] = True
            matched_h[cols[ok]] = True
        ev_mask = g.evaluated
        gxy = g.objects.world[ev_mask, :2]
        gboxes = g.objects.boxes2d[ev_mask]
        grange = prep.gt_range[f][ev_mask]
        ah = hyp_by.get(f)
        det = prep.detections[f]
        for i in np.nonzero(~matched_g)[0]:
            why = None
            if ah is not None and len(ah):
                d = np.hypot(ah["wx"].to_numpy() - gxy[i, 0], ah["wy"].to_numpy() - gxy[i, 1])
                k = int(np.nanargmin(d)) if np.isfinite(d).any() else -1
                if k >= 0 and d[k] < 2 and ah["type"].iloc[k] != "Car":
                    why = f"classed {ah['type'].iloc[k]}"
                elif k >= 0 and d[k] < 6:
                    why = "localisation 2-6 m"
            if why is None:
                dcov = iou_2d(gboxes[i : i + 1], det.boxes.astype(float))[0] if len(det.boxes) else np.zeros(0)
                why = (
                    f"no track (box score {float(det.scores[dcov.argmax()]):.1f})"
                    if (dcov >= 0.5).any()
                    else "detector"
                )
            fn[(why, _bin(float(grange[i])))] += 1
        lab = lab_by.get(f)
        hk = h.world[keep]
        if len(gxy) and len(h):
            d = np.hypot(gxy[:, None, 0] - h.world[None, :, 0], gxy[:, None, 1] - h.world[None, :, 1])
            d = np.where(np.isfinite(d) & (d < 6), d, 1e6)
            rr, cc = linear_sum_assignment(d)
            for a, b in zip(rr, cc, strict=True):
                if d[a, b] < 1e6:
                    gc = prep.world.world_to_camera(f, g.objects.world[ev_mask][a : a + 1, :3])[0]
                    hc2 = prep.world.world_to_camera(f, h.world[b : b + 1, :3])[0]
                    rg, rh = np.hypot(gc[0], gc[2]), np.hypot(hc2[0], hc2[2])
                    lat = (hc2[0] * gc[2] - hc2[2] * gc[0]) / max(rg, 1e-6)
                    ERR.append((rg, rh - rg, lat))
        for j in np.nonzero(~matched_h)[0]:
            hc = prep.world.world_to_camera(f, hk[j : j + 1, :3])
            rng = _bin(float(np.hypot(hc[0, 0], hc[0, 2])))
            name = "ghost"
            if lab is not None and len(lab):
                d = np.hypot(lab["wx"].to_numpy() - hk[j, 0], lab["wy"].to_numpy() - hk[j, 1])
                k = int(np.nanargmin(d)) if np.isfinite(d).any() else -1
                if k >= 0 and d[k] < 6:
                    row = lab.iloc[k]
                    name = str(row["type"])
                    if name == "Car":
                        evald = row["occluded"] <= 2 and row["truncated"] <= 0
                        name = "localisation 2-6 m" if evald else "Car(distractor)"
            fp[(name, rng)] += 1
    out = {k: res[k] for k in ("MOTA", "CLR_FP", "CLR_FN", "IDSW", "CLR_TP")}
    return out, fn, fp


def _frame_matches(g, h, rule) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(evaluated gt matched, kept hypotheses matched, kept hypotheses' ids) of one frame (KITTI rules)."""
    fr = apply_kitti_rules(g, h, rule)
    mg, mh = np.zeros(len(fr.gt_ids), bool), np.zeros(fr.similarity.shape[1], bool)
    if fr.similarity.size:
        r, c = linear_sum_assignment(-fr.similarity)
        ok = fr.similarity[r, c] > 1e-9
        mg[r[ok]], mh[c[ok]] = True, True
    return mg, mh, h.ids[np.isin(h.ids, fr.hyp_ids)]


def _lost_where(gbox, gxy, f, prep, cfg, rows, agents, ndet, ah) -> str:
    """Where an unmatched evaluated car (image box ``gbox``, world ``gxy``) is lost along the path."""
    det = prep.detections[f]
    cover = iou_2d(gbox[None], det.boxes.astype(float))[0] if len(det.boxes) else np.zeros(0)
    if not (cover >= 0.5).any():
        return "detector"
    if float(det.scores[cover.argmax()]) < cfg.min_score:
        return "box under min_score"
    t_cover = iou_2d(gbox[None], rows[["x1", "y1", "x2", "y2"]].to_numpy(float))[0] if rows is not None else []
    if not len(t_cover) or max(t_cover) < 0.5:
        return "no image-track row"
    tid = int(rows["track_id"].iloc[int(np.argmax(t_cover))])
    if tid not in agents:
        return "dropped (min_detected)" if ndet[tid] < cfg.min_detected_frames else "dropped (min_confidence)"
    mine = ah[ah["track_id"] == tid] if ah is not None else ah
    if mine is None or not len(mine):
        return "agent without this frame"
    if mine["type"].iloc[0] != "Car":
        return f"agent typed {mine['type'].iloc[0]}"
    d = float(np.hypot(mine["wx"].iloc[0] - gxy[0], mine["wy"].iloc[0] - gxy[1]))
    return "agent 2-6 m off" if d < 6 else "agent > 6 m off"


def lifecycle(seq: int, config: MonoTracking = DEFAULT_MONO) -> tuple[Counter, Counter]:
    """FN by where the car is lost (:func:`_lost_where`) and range bin; FP by agent age and kind (KITTI camera)."""
    prep = prepare_mono(DATA, seq)
    tracks = image_tracks(prep, config)
    sc, _ = mono_scenario(prep, config, "kitti", tracks)
    rule = match_rule("distance")
    table = scenario_result_table(sc, prep.world, prep.P2, not config.report_predicted, image_size=prep.size)
    hyp_by = dict(iter(world_table(prep.world, table).groupby("frame")))
    det_rows = tracks[tracks["state"] == "detected"]
    rows_by, ndet = dict(iter(det_rows.groupby("frame"))), det_rows.groupby("track_id").size()
    agents = {a.id: a for a in sc.agents}
    fn, fp, tp_of, fp_of = Counter(), Counter(), Counter(), Counter()
    for f, (g, h) in enumerate(zip(prep.ground_truth, hypotheses_from_table(table, prep.world), strict=True)):
        mg, mh, ids = _frame_matches(g, h, rule)
        tp_of.update(int(i) for i in ids[mh])
        fp_of.update(int(i) for i in ids[~mh])
        ev = g.evaluated
        for i in np.nonzero(~mg)[0]:
            gbox, gxy = g.objects.boxes2d[ev][i], g.objects.world[ev][i, :2]
            why = _lost_where(gbox, gxy, f, prep, config, rows_by.get(f), agents, ndet, hyp_by.get(f))
            fn[(why, _bin(float(prep.gt_range[f][ev][i])))] += 1
    for tid, n in fp_of.items():
        nd = int(np.sum(agents[tid].trajectory.observed))
        age = "8-14" if nd < 15 else "15-29" if nd < 30 else "30+"
        kind = "never matched" if not tp_of[tid] else "mostly FP" if tp_of[tid] < n else "mostly TP"
        fp[(kind, f"{age} detected frames")] += n
    return fn, fp


def class_rows(seq: int, config: MonoTracking = DEFAULT_MONO) -> pd.DataFrame:
    """One row per kept track of a sequence: typed class, covered label type, detected frames,
    median range (m), implied height (m) and log box aspect (KITTI camera; ``localize_tracks`` on the
    poses' path without ``raw_scenario_from_tracks``' per-frame pitch, so a class may differ)."""
    prep = prepare_mono(DATA, seq)
    tracks = image_tracks(prep, config)
    states = localize_tracks(tracks, prep.camera, ego_of(prep.world), prep.size, KITTI_FPS, config.mono)
    labels = read_labels(KittiSequence(DATA, seq).labels)
    lab_by = dict(iter(labels.groupby("frame")))
    cam = prep.camera
    out = []
    for tid, g in states[states["detected"].astype(bool)].groupby("track_id"):
        if len(g) < config.min_detected_frames or g["score"].mean() <= config.min_confidence:
            continue
        types: Counter = Counter()
        for f, box in zip(g["frame"], g[["x1", "y1", "x2", "y2"]].to_numpy(float), strict=True):
            lab = lab_by.get(int(f))
            iou = iou_2d(box[None], lab[["x1", "y1", "x2", "y2"]].to_numpy(float))[0] if lab is not None else []
            types[str(lab["type"].iloc[int(np.argmax(iou))]) if len(iou) and max(iou) >= 0.5 else "none"] += 1
        below = (g["y2"] - g["horizon_v"]).to_numpy(float)
        ok = (below > 2.0) & (g["y2"].to_numpy(float) < prep.size[1] - 2)
        h = ((g["y2"] - g["y1"]).to_numpy(float) * cam.height_m / np.where(ok, below, np.nan))[ok]
        bh, bw = (g["y2"] - g["y1"]).to_numpy(float), (g["x2"] - g["x1"]).to_numpy(float)
        ln, wd, ht = class_size("car")  # the car prior's box shape (as the class choice's aspect term)
        a = np.arctan((0.5 * (g["x1"] + g["x2"]).to_numpy(float) - cam.cx) / cam.fx)
        shape = ht * hull_factor(ht, ln, wd, cam.height_m, cam.fy * ht / bh, np.tan(a))
        aspect = np.log(bh / bw) - np.log(shape / (ln * np.abs(np.sin(a)) + wd * np.abs(np.cos(a))))
        out.append({
            "seq": seq, "track": tid, "typed": g["category"].iloc[0], "label": types.most_common(1)[0][0],
            "frames": len(g), "range": float(np.nanmedian(g["range"])),
            "height": float(np.median(h)) if len(h) else np.nan, "aspect": float(np.median(aspect)),
        })  # fmt: skip
    return pd.DataFrame(out)


def print_classes(seqs: list[int]) -> None:
    """The class-choice tables of :func:`class_rows` over ``seqs``."""
    df = pd.concat([class_rows(s) for s in seqs], ignore_index=True)
    df["label"] = df["label"].where(df["label"].isin(["Car", "Van", "none"]), "other")
    print("detected frames by label type (rows) and typed class (columns):")
    print(pd.crosstab(df["label"], df["typed"], values=df["frames"], aggfunc="sum").fillna(0).astype(int))
    df["bin"] = pd.cut(df["range"], [0, 15, 25, 35, 45, 60, 1000])
    tab = df[df["label"].isin(["Car", "Van"])].groupby(["label", "bin"], observed=True)
    print("per label type and median range (m): tracks, typed van, implied height q50/q75 (m), log aspect - car's:")
    print(
        tab.agg(
            tracks=("frames", "size"), typed_van=("typed", lambda t: int((t == "van").sum())),
            h50=("height", "median"), h75=("height", lambda h: h.quantile(0.75)), aspect=("aspect", "median"),
        ).round(2)
    )  # fmt: skip


def _label_speeds(prep) -> dict[tuple[int, int], float]:
    """(label track id, frame) -> the labelled car's world speed (m/s) over the frames within 0.5 s of it."""
    pos: dict[int, dict[int, np.ndarray]] = {}
    for f, g in enumerate(prep.ground_truth):
        for i, tid in enumerate(g.objects.ids):
            pos.setdefault(int(tid), {})[f] = g.objects.world[i, :2]
    out = {}
    for tid, d in pos.items():
        frames = sorted(d)
        for f in frames:
            near = [x for x in frames if abs(x - f) <= 5]
            a, b = near[0], near[-1]
            out[(tid, f)] = float(np.linalg.norm(d[b] - d[a]) / (b - a) * KITTI_FPS) if b > a else float("nan")
    return out


def standing_split(seq: int, camera: str, config: MonoTracking = DEFAULT_MONO) -> Counter:
    """Per (standing|moving, range bin): evaluated label rows (``gt``), missed ones (``fn``) and those whose nearest
    kept hypothesis lies more than 2 m off (``off``; within 6 m); standing: the labelled car slower than 0.5 m/s."""
    prep = prepare_mono(DATA, seq, camera=camera)
    sc, _ = mono_scenario(prep, config, camera)
    rule = match_rule("distance")
    table = scenario_result_table(sc, prep.world, prep.P2, True, image_size=prep.size)
    speeds = _label_speeds(prep)
    c: Counter = Counter()
    for f, (g, h) in enumerate(zip(prep.ground_truth, hypotheses_from_table(table, prep.world), strict=True)):
        fr = apply_kitti_rules(g, h, rule)
        matched = np.zeros(len(fr.gt_ids), bool)
        if fr.similarity.size:
            rows, cols = linear_sum_assignment(-fr.similarity)
            matched[rows[fr.similarity[rows, cols] > 1e-9]] = True
        ev = g.evaluated
        hyp = h.world[np.isin(h.ids, fr.hyp_ids)][:, :2]
        labelled = zip(g.objects.ids[ev], g.objects.world[ev, :2], prep.gt_range[f][ev], strict=True)
        for i, (tid, xy, rng) in enumerate(labelled):
            kind = "standing" if speeds.get((int(tid), f), np.nan) < 0.5 else "moving"
            key = (kind, _bin(float(rng)))
            c[key + ("gt",)] += 1
            c[key + ("fn",)] += int(not matched[i])
            d = np.hypot(*(hyp - xy).T) if len(hyp) else np.zeros(0)
            c[key + ("near",)] += int(len(d) > 0 and d.min() < 6)
            c[key + ("off",)] += int(len(d) > 0 and 2 <= d.min() < 6)
    return c


def print_standing(seqs: list[int], camera: str, config: MonoTracking) -> None:
    total: Counter = Counter()
    for s in seqs:
        total.update(standing_split(s, camera, config))
    for kind in ("standing", "moving"):
        for lo, hi in zip(BINS[:-1], BINS[1:], strict=True):
            k = (kind, f"{lo}-{hi}")
            near = max(total[k + ("near",)], 1)
            print(
                f"{kind:8s} {lo}-{hi} m: labelled {total[k + ('gt',)]} missed {total[k + ('fn',)]} nearest hypothesis "
                f"2-6 m off {total[k + ('off',)]} ({100 * total[k + ('off',)] / near:.0f} % of those within 6 m)"
            )


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--sequences", default=",".join(map(str, TUNING)))
    ap.add_argument("--camera", default="kitti")
    ap.add_argument("--classes", action="store_true", help="the class choice per track (KITTI camera)")
    ap.add_argument("--lifecycle", action="store_true", help="FN by where lost, FP by track age (KITTI camera)")
    ap.add_argument("--standing", action="store_true", help="misses split by the labelled car standing or moving")
    ap.add_argument("--mono", default="", help="MonoConfig overrides, e.g. hull_height=False,prior_scale=1.02")
    ap.add_argument("--tracker", default="", help="MonoTracking overrides, e.g. detect_every=2 (a video's cadence)")
    args = ap.parse_args()
    if args.standing:
        print_standing(
            [int(x) for x in args.sequences.split(",")], args.camera, tracking_config(args.mono, args.tracker)
        )
        return
    if args.classes:
        print_classes([int(x) for x in args.sequences.split(",")])
        return
    if args.lifecycle:
        fn_all, fp_all = Counter(), Counter()
        for s in [int(x) for x in args.sequences.split(",")]:
            fn, fp = lifecycle(s, tracking_config(args.mono, args.tracker))
            fn_all.update(fn)
            fp_all.update(fp)
            print(f"{s:04d} FN {dict(fn.most_common(4))} FP {dict(fp.most_common(3))}", flush=True)
        for title, c in (("FN by where lost / range:", fn_all), ("FP by agent kind / age:", fp_all)):
            print(title)
            for k, v in sorted(c.items()):
                print("  ", k, v)
        return
    FN, FP = Counter(), Counter()
    n_err = 0
    for s in [int(x) for x in args.sequences.split(",")]:
        out, fn, fp = diagnose(s, args.camera, tracking_config(args.mono, args.tracker))
        FN.update(fn)
        FP.update(fp)
        e = np.array(ERR[n_err:]) if len(ERR) > n_err else np.zeros((0, 3))
        n_err = len(ERR)
        far = (e[:, 0] >= 20) & (e[:, 0] < 60) if len(e) else np.zeros(0, bool)
        bias = float(np.median(e[far, 1] / e[far, 0]) * 100) if far.any() else float("nan")
        print(f"{s:04d} range bias 20-60 m {bias:+.1f} %", end="  ")
        print(
            f"{s:04d} MOTA {100 * out['MOTA']:.1f} TP {out['CLR_TP']} FP {out['CLR_FP']} FN {out['CLR_FN']} "
            f"IDSW {out['IDSW']}  FN:{dict(fn.most_common(4))} FP:{dict(fp.most_common(4))}",
            flush=True,
        )
    e = np.array(ERR)
    for lo, hi in ((0, 10), (10, 20), (20, 30), (30, 40), (40, 50), (50, 60), (60, 80)):
        m = (e[:, 0] >= lo) & (e[:, 0] < hi)
        if m.any():
            q = np.percentile(e[m, 1] / e[m, 0] * 100, [25, 50, 75])
            print(
                f"range {lo}-{hi} m: n {m.sum()} range error % q25/50/75 {q.round(1)} lateral |m| median "
                f"{np.median(np.abs(e[m, 2])):.2f} within 2 m {np.mean(np.hypot(e[m, 1], e[m, 2]) < 2) * 100:.0f} %"
            )
    print("FN total by cause/range:")
    for k, v in sorted(FN.items()):
        print("  ", k, v)
    print("FP total by cause/range:")
    for k, v in sorted(FP.items()):
        print("  ", k, v)


if __name__ == "__main__":
    main()
