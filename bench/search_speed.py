"""Variants simulated per second by the search's engines: in-process, process pool, Ray (1 and 2 workers).

512 random variants (128 starts x 4 noisy paths) of a real KITTI crash scenario, 11 s simulated
each, in chunks of 64. Ray's start-up (ray.init) is reported apart from the throughput.
Usage: PYTHONPATH=src python bench/search_speed.py [--variants 512] [--engines local1,local2,ray1,ray2]
"""

from __future__ import annotations

import argparse
import os
import sys
import time

import numpy as np

sys.path.insert(0, os.path.dirname(__file__))
from search_common import DURATION_S, crash_scenario  # noqa: E402

from deepcrashtest.search.evaluate import Evaluator  # noqa: E402
from deepcrashtest.search.space import SearchSpace  # noqa: E402


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--variants", type=int, default=512)
    ap.add_argument("--engines", default="local1,local2,ray1,ray2", help="engine+workers to time, comma separated")
    args = ap.parse_args()
    sc = crash_scenario()
    space = SearchSpace.for_scenario(sc)
    theta = space.reference_grid(np.random.default_rng(0), args.variants // 4, 4)
    print(f"{len(theta)} variants of {sc.name} (crash injected), {DURATION_S} s simulated each, chunks of 64")
    print(f"CPUs visible: {os.cpu_count()} (shared with other processes: timings are contaminated)")
    ref = None
    runs = [(e.rstrip("0123456789"), int(e[len(e.rstrip("0123456789")) :])) for e in args.engines.split(",")]
    for engine, workers in runs:
        if engine == "ray":
            try:
                import ray
            except ImportError:
                print("ray: not installed (pip install deepcrashtest[ray])")
                continue
            t0 = time.perf_counter()
            ray.init(num_cpus=workers, include_dashboard=False, log_to_driver=False)
            print(f"ray.init(num_cpus={workers}): {time.perf_counter() - t0:.1f} s")
        with Evaluator(sc, space, engine=engine, workers=workers, duration=DURATION_S) as ev:
            if engine == "local" and workers > 1:
                ev(theta[:2])  # start the pool's processes outside the timing
                ev.simulations = 0
            t0 = time.perf_counter()
            out = ev(theta)
            dt = time.perf_counter() - t0
        if engine == "ray":
            ray.shutdown()
        same = (
            ""
            if ref is None
            else f"  identical to local x1: {all(np.array_equal(out[k], ref[k], equal_nan=True) for k in ref)}"
        )
        ref = ref or out
        print(f"{engine:5s} x{workers}: {len(theta) / dt:7.1f} variants/s ({dt:.2f} s){same}")


if __name__ == "__main__":
    main()
