"""Simulations until the first safe variant: random search vs the cross-entropy method, over 20 seeds.

Real KITTI crash scenario (oncoming car 10 of sequence 0008 shifted onto the ego), 128
simulations per method and seed, default search settings (box 8 m x 4 m, noise sigma 0.3 m).
A method that finds nothing in its budget counts as budget + 1 in the mean/median (and is listed).
Usage: PYTHONPATH=src python bench/search_first_safe.py [--seeds 20]
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import time

import numpy as np

sys.path.insert(0, os.path.dirname(__file__))
from search_common import DURATION_S, crash_scenario  # noqa: E402

from deepcrashtest.search.evaluate import Evaluator  # noqa: E402
from deepcrashtest.search.methods import CemConfig, Log, cem_search, first_safe, random_search  # noqa: E402
from deepcrashtest.search.space import SearchSpace  # noqa: E402

BUDGET = 128


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--seeds", type=int, default=20)
    args = ap.parse_args()
    sc = crash_scenario()
    space = SearchSpace.for_scenario(sc)
    found: dict[str, list[int | None]] = {"random": [], "cem": []}
    least: dict[str, list[float]] = {"random": [], "cem": []}
    t0 = time.perf_counter()
    for seed in range(args.seeds):
        with Evaluator(sc, space, seed=seed, duration=DURATION_S) as ev:
            log = Log()
            random_search(ev, log, np.random.default_rng([seed, 1]), 32, 4)
            cem_search(ev, log, np.random.default_rng([seed, 2]), CemConfig(budget=BUDGET, line_search=16))
        _, out = log.arrays()
        safe = ~out["collided"] & (out["robustness"] > 0)
        for m in found:
            found[m].append(first_safe(out, log.method, m))
            mine = np.array([x == m for x in log.method])
            least[m].append(float(out["change"][mine & safe].min()) if (mine & safe).any() else float("nan"))
    print(
        f"{sc.name} (crash injected), {args.seeds} seeds, {BUDGET} simulations per method and seed, "
        f"{time.perf_counter() - t0:.0f} s"
    )
    result = {}
    for m, v in found.items():
        a = np.array([BUDGET + 1 if x is None else x for x in v], dtype=float)
        result[m] = {
            "first_safe_mean": round(float(a.mean()), 2),
            "first_safe_median": float(np.median(a)),
            "not_found": sum(x is None for x in v),
            "least_change_m_median": round(float(np.nanmedian(least[m])), 3),
            "per_seed": v,
        }
        print(
            f"{m:6s} first safe after: mean {a.mean():6.2f}, median {np.median(a):5.1f} simulations "
            f"(not found: {result[m]['not_found']}); least change of a safe variant, median "
            f"{result[m]['least_change_m_median']} m"
        )
    print(json.dumps(result))


if __name__ == "__main__":
    main()
