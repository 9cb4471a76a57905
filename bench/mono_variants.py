"""One setting of the monocular path against the training sequences, both cameras, on two processes.

    PYTHONPATH=src nice -n 10 python bench/mono_variants.py --cache DIR [--mono k=v,...] [--tracker k=v,...]
        [--cameras kitti,unknown] [--kitti-height M] [--errors] [--detect-every N] [--sequences 0,1,2]

Prints, per camera, the combined CLEAR-MOT MOTA (summed FN, FP, IDSW over summed ground truth) of the 18
training sequences other than 3, 8, 10 (never the held-out ones), its FN / FP, each sequence's MOTA, and with
``--errors`` the median position error / median signed range error (percent of the range) and the matched count
per sequence in each distance bin (``kitti_mono.ERROR_BINS``), and the matched cars' median heading error / share
over 20 deg (``kitti_mono.heading_errors``). ``--mono`` / ``--tracker`` override
``MonoConfig`` / ``MonoTracking`` fields (Python literals); ``--kitti-height`` replaces the KITTI camera's
1.65 m. ``--detect-every N`` gives the image tracker the boxes of every N-th frame only, as ``extract``'s detector
runs on a video (every 2nd frame at KITTI's 10 fps), the frames between carried by the tracker (their own cache
files). The image tracks and the unknown camera's self-calibration are cached per sequence and tracker setting
under ``--cache`` (``selfcalib_diag.tracks_tag``; use a fresh directory after a change to the image tracker's or the
self-calibration's code).
Where ``bench/tune_mono.py`` walks a grid on the KITTI camera, this scores one setting on both cameras at
once (what a round must not lower: the unknown camera's figure as well).
"""

from __future__ import annotations

import argparse
import pickle
from dataclasses import replace
from multiprocessing import Pool
from pathlib import Path
from typing import Any

from selfcalib_diag import _combined, load_sequence, tracking_config, tracks_tag, training_args

from deepcrashtest.eval.clear_mot import clear_only
from deepcrashtest.eval.kitti import match_rule
from deepcrashtest.eval.kitti_mono import MonoTracking, ego_of, score_sequence
from deepcrashtest.geometry.selfcalib import self_calibrate
from deepcrashtest.geometry.world_tracks import raw_scenario_from_tracks
from deepcrashtest.scenario import Camera, VideoSource

BIN_KEYS = ("0-20 m", "20-40 m", "40-60 m")


def _calibrated(s: int, cache: Path, prep, tracks, ego, start: Camera) -> Camera:
    """The unknown camera's self-calibration of sequence ``s`` (cached)."""
    f = cache / f"calibrated_{s:04d}.pkl"
    if f.exists():
        return pickle.loads(f.read_bytes())
    cam = self_calibrate(tracks, start, prep.size, ego).camera
    f.write_bytes(pickle.dumps(cam))
    return cam


def _score(job: tuple[int, Path, MonoTracking, tuple[str, ...], float | None]) -> tuple[int, dict[str, Any]]:
    """CLEAR-MOT row and position-error table of one sequence per camera."""
    s, cache, cfg, cameras, kitti_height = job
    prep, tracks, ego, start = load_sequence(s, cache, cfg)
    cache = cache / f"calibrated_{tracks_tag(cfg)}"  # the self-calibration of these tracks
    cache.mkdir(exist_ok=True)
    meta = VideoSource(
        kind="image_folder", path=prep.name, fps=10.0, frame_count=prep.world.n_frames,
        width=prep.size[0], height=prep.size[1],
    )  # fmt: skip
    rule = match_rule("distance")
    out: dict[str, Any] = {}
    for which in cameras:
        if which == "kitti":
            cam = prep.camera if kitti_height is None else prep.camera.model_copy(update={"height_m": kitti_height})
        else:
            cam = _calibrated(s, cache, prep, tracks, ego, start)
        sc = raw_scenario_from_tracks(
            tracks, meta, cam, ego_of(prep.world), name=prep.name, mono=cfg.mono, min_detected=cfg.min_detected_frames,
            min_confidence=cfg.min_confidence,
        )  # fmt: skip
        ev, err = score_sequence(prep, sc, rule, not cfg.report_predicted)
        out[which] = (clear_only([ev], rule)[prep.name], err)
    return s, out


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--mono", default="", help="MonoConfig overrides, e.g. class_switch_cost=2.0")
    ap.add_argument("--tracker", default="", help="MonoTracking overrides, e.g. min_confidence=0.85")
    ap.add_argument("--cameras", default="kitti,unknown")
    ap.add_argument("--kitti-height", type=float, default=None, help="the KITTI camera's height (m)")
    ap.add_argument("--errors", action="store_true", help="position errors by distance bin per sequence")
    ap.add_argument("--processes", type=int, default=2)
    ap.add_argument("--detect-every", type=int, default=1, help="boxes of every N-th frame only (a video's cadence)")
    args, seqs, cache = training_args(ap, None)
    cfg = replace(tracking_config(args.mono, args.tracker), detect_every=args.detect_every)
    cameras = tuple(args.cameras.split(","))
    jobs = [(s, cache, cfg, cameras, args.kitti_height) for s in seqs]
    with Pool(args.processes) as pool:
        rows = dict(pool.map(_score, jobs, chunksize=1))
    for which in cameras:
        res = [rows[s][which][0] for s in seqs]
        if args.errors:
            for key in BIN_KEYS:
                cells = [(s, rows[s][which][1][key]) for s in seqs if rows[s][which][1][key]["n"]]
                text = " ".join(f"{s}:{e['median_pct']}/{e['range_bias_pct']}({e['n']})" for s, e in cells)
                print(f"{which} {key} median % / bias % (n): {text}")
            cells = [(s, rows[s][which][1]["heading"]) for s in seqs if rows[s][which][1]["heading"]["n"]]
            text = " ".join(f"{s}:{h['median_deg']}/{round(100 * h['share_over_20_deg'])}({h['n']})" for s, h in cells)
            print(f"{which} heading median deg / % over 20 deg (n): {text}")
        per = " ".join(f"{s}:{100 * float(r['MOTA']):.1f}" for s, r in zip(seqs, res, strict=True))
        fn, fp = (sum(float(r[k]) for r in res) for k in ("CLR_FN", "CLR_FP"))
        print(f"{which} combined MOTA {_combined(res):.2f} FN {fn:.0f} FP {fp:.0f} | {per}", flush=True)


if __name__ == "__main__":
    main()
