"""Simulator speed: variants/s of ``simulate_batch`` and the real-time factor of one ``simulate`` run.

Scenario: KITTI tracking 0008 (real ground-truth trajectories, raw) cut to 20 s and 5 vehicles (ego +
4 agents), with agent 11 (oncoming) moved to meet the ego at t = 10 s (sim.testcases.meet_ego), the
AEB controller, and random start offsets (+-15 m longitudinal, +-1.5 m lateral) so that a share of
the variants collide (Box2D impacts included). Prints one JSON line.

Usage: python bench/sim_speed.py [--variants 4096] [--workers 2]
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "src"))

from deepcrashtest.datasets.kitti.scenario import scenario_from_kitti  # noqa: E402
from deepcrashtest.sim import simulate, simulate_batch  # noqa: E402
from deepcrashtest.sim.testcases import meet_ego  # noqa: E402

KITTI = Path(__file__).resolve().parents[2] / "shared" / "data" / "kitti_tracking"


def bench_scenario():
    sc = meet_ego(scenario_from_kitti(KITTI, 8), 11, 10.0)
    keep = {9, 10, 11, 12}  # agents present in the first 20 s near the ego's path
    sc.agents = [a for a in sc.agents if a.id in keep]
    return sc


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--variants", type=int, default=4096)
    ap.add_argument("--workers", type=int, default=2)
    args = ap.parse_args()
    if not KITTI.exists():
        print(json.dumps({"skipped": f"real data not found: {KITTI}"}))
        return
    sc = bench_scenario()
    rng = np.random.default_rng(0)
    off = np.column_stack([rng.uniform(-15, 15, args.variants), rng.uniform(-1.5, 1.5, args.variants)])
    simulate_batch(sc, off[:64], controller="aeb", duration=20.0)  # warm-up (imports, caches)
    t0 = time.perf_counter()
    res = simulate_batch(sc, off, controller="aeb", duration=20.0, workers=args.workers)
    batch_s = time.perf_counter() - t0
    t0 = time.perf_counter()
    single = simulate(sc, controller="aeb", duration=20.0)
    single_s = time.perf_counter() - t0
    print(
        json.dumps(
            {
                "variants": args.variants,
                "workers": args.workers,
                "cpu_count": os.cpu_count(),
                "vehicles": 1 + len(sc.agents),
                "sim_seconds": 20.0,
                "dt": 0.02,
                "batch_wall_s": round(batch_s, 3),
                "variants_per_s": round(args.variants / batch_s, 1),
                "collided_share": round(float(res.collided.mean()), 3),
                "aeb_triggered_share": round(float(np.isfinite(res.aeb_time).mean()), 3),
                "single_run_wall_s": round(single_s, 3),
                "real_time_factor": round(20.0 / single_s, 1),
                "single_run_collided": single.metrics["collided"],
                "note": "timings on a shared 2-core machine (other jobs running) are pessimistic",
            }
        )
    )


if __name__ == "__main__":
    main()
