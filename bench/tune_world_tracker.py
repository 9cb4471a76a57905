"""Tune the world tracker on KITTI tracking: coordinate descent on combined world-frame MOTA
(2 m bird's-eye matching, KITTI rules) over the TUNING sequences only: the 18 training sequences
other than 3, 8 and 10, which stay held out for the reported table.

    PYTHONPATH=src python bench/tune_world_tracker.py [--rounds 2]

Prints every configuration tried with its tuning-set MOTA, then the best one and its MOTA on the
held-out sequences 3, 8, 10. Takes a few minutes on 2 cores.
"""

from __future__ import annotations

import argparse
import time
from dataclasses import asdict, replace
from pathlib import Path

from deepcrashtest.eval.clear_mot import clear_only
from deepcrashtest.eval.kitti import DEFAULT_OFFLINE, DEFAULT_TRACKER, prepare_sequence, track_and_rule
from deepcrashtest.eval.kitti_rules import MATCH_RULES

DATA = Path(__file__).resolve().parents[1].parent / "shared" / "data" / "kitti_tracking"
HELD_OUT = [3, 8, 10]
TUNING = [s for s in range(21) if s not in HELD_OUT]
GRID = {
    ("tracker", "min_score"): [-10.0, -0.5, 0.0, 1.0],
    ("tracker", "birth_score"): [1.0, 2.0, 3.0, 4.0, 5.0],
    ("tracker", "min_hits"): [1, 2, 3, 5],
    ("tracker", "max_age"): [1, 3, 5, 10],
    ("tracker", "gate_m"): [1.5, 2.0, 3.0],
    ("offline", "min_detections"): [3, 6, 10, 15],
    ("offline", "extend_max_gap"): [0, 3, 5, 10, 20],
    ("offline", "extend_min_score"): [-10.0, -0.5, 0.0, 1.0],
    ("offline", "max_gap"): [0, 10, 30, 60],
}


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--rounds", type=int, default=2)
    args = ap.parse_args()
    rule = MATCH_RULES["distance"]
    t0 = time.time()
    tuning = [prepare_sequence(DATA, s) for s in TUNING]
    held = [prepare_sequence(DATA, s) for s in HELD_OUT]
    print(f"prepared {len(tuning)} tuning + {len(held)} held-out sequences in {time.time() - t0:.1f} s")

    def mota(cfgs: dict, seqs: list) -> tuple[float, dict]:
        res = clear_only([track_and_rule(p, rule, cfgs["tracker"], cfgs["offline"]) for p in seqs], rule)
        return 100 * float(res["combined"]["MOTA"]), res

    best = {"tracker": DEFAULT_TRACKER, "offline": DEFAULT_OFFLINE}
    best_mota, _ = mota(best, tuning)
    print(f"start: tuning MOTA {best_mota:.2f}")
    for r in range(args.rounds):
        for (part, name), values in GRID.items():
            for v in values:
                trial = dict(best)
                trial[part] = replace(best[part], **{name: v})
                m, _ = mota(trial, tuning)
                print(f"round {r} {part}.{name}={v}: tuning MOTA {m:.2f}", flush=True)
                if m > best_mota + 1e-9:
                    best, best_mota = trial, m
    print(f"best tuning MOTA {best_mota:.2f} ({time.time() - t0:.0f} s)")
    print("tracker:", asdict(best["tracker"]))
    print("offline:", asdict(best["offline"]))
    _, res = mota(best, held)
    for name, c in res.items():
        print(f"held-out {name}: MOTA {100 * c['MOTA']:.2f} TP {c['CLR_TP']} FP {c['CLR_FP']} FN {c['CLR_FN']}")


if __name__ == "__main__":
    main()
