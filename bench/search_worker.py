"""One search worker's simulation, CPU seconds per chunk, this checkout against another, in fresh processes.

What a ``deepcrashtest search`` worker does with its share of the variants: ``search.evaluate.simulate_variants``
on ``--variants`` (default 1,000) variants of the reference experiment of KITTI tracking 0003 (ground-truth
labels as a Scenario; ``--starts 500 --noise-variants 4``, seed [0, 1], the first ``--variants`` of them): the
ego paths from the search space, the path tables, the roll-out, the contact / distance / TTC geometry and the
Box2D impacts. Each measurement is a fresh Python process (as a forked worker, its arrays are fresh memory: the
page faults count), the world prepared and the first call made before the timed one; the two checkouts alternate
``--pairs`` times, so that both see the same load. Prints one JSON line: per side the CPU seconds of the chunk
(min, median, each run) and its minor page faults (min: fresh memory touched, 4 KiB each), the ratio of the minima
and of the medians, and whether both sides' outcomes are
identical bit for bit (a hash of every outcome array).
Usage: python bench/search_worker.py --baseline-src OTHER_CHECKOUT/src [--pairs 6] [--variants 1000] [--sequence 3]
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import subprocess
import sys
import tempfile
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "src"))

from deepcrashtest.pipeline.kitti import kitti_scenarios  # noqa: E402

KITTI = ROOT.parent / "shared" / "data" / "kitti_tracking"

# Runs in each measured process: prepares the world, times one chunk, prints its CPU seconds and outcome hash.
PROBE = r"""
import hashlib, json, resource, sys, time
import numpy as np
from deepcrashtest.scenario import Scenario
from deepcrashtest.search import evaluate as ev
from deepcrashtest.search.space import SearchSpace
from deepcrashtest.sim.agents import agent_timeline
from deepcrashtest.sim.vehicle import VehicleLimits
sc = Scenario.load(sys.argv[1])
space = SearchSpace.for_scenario(sc)
theta = space.reference_grid(np.random.default_rng([0, 1]), 500, 4)[: int(sys.argv[2])]
js = sc.model_dump_json()
agent_timeline(ev._prepared_world(js, None, sc), VehicleLimits()).record_all()
ev.simulate_variants(js, space, theta[:2], "replay", 0)  # imports, caches
f0, t0 = resource.getrusage(resource.RUSAGE_SELF).ru_minflt, time.process_time()
out = ev.simulate_variants(js, space, theta, "replay", 0)
cpu, faults = time.process_time() - t0, resource.getrusage(resource.RUSAGE_SELF).ru_minflt - f0
h = hashlib.sha256()
for k in sorted(out):
    h.update(np.ascontiguousarray(out[k]).tobytes())
print(json.dumps({"cpu_s": cpu, "page_faults": faults, "hash": h.hexdigest()[:16]}))
"""


def _run(src: Path, scenario: Path, variants: int) -> dict:
    env = {**os.environ, "PYTHONPATH": str(src)}
    cmd = [sys.executable, "-c", PROBE, str(scenario), str(variants)]
    proc = subprocess.run(cmd, check=True, env=env, capture_output=True, text=True)
    return json.loads(proc.stdout.strip().splitlines()[-1])


def _rounded(values: list[float]) -> list[float]:
    return [round(v, 3) for v in values]


def _args() -> argparse.Namespace:
    ap = argparse.ArgumentParser(description="one search worker's chunk, this checkout against another")
    ap.add_argument("--baseline-src", required=True, help="another checkout's src/, measured alternately")
    ap.add_argument("--pairs", type=int, default=6, help="alternating runs per side")
    ap.add_argument("--variants", type=int, default=1000, help="variants in the chunk")
    ap.add_argument("--sequence", type=int, default=3, help="KITTI tracking sequence")
    return ap.parse_args()


def main() -> None:
    args = _args()
    if not KITTI.exists():
        print(json.dumps({"skipped": f"real data not found: {KITTI}"}))
        return
    srcs = {"search": ROOT / "src", "baseline": Path(args.baseline_src).resolve()}
    with tempfile.TemporaryDirectory() as tmp:
        scen = Path(tmp) / "scenario.json"
        # the Scenario ``deepcrashtest scenario from-kitti`` writes (stage 2 on the labels, seed 0), this checkout's
        kitti_scenarios(KITTI, args.sequence, seed=0)[1].save(scen)
        runs: dict[str, list[dict]] = {k: [] for k in srcs}
        load_before = os.getloadavg()[0]
        for _ in range(args.pairs):
            for name, src in srcs.items():
                runs[name].append(_run(src, scen, args.variants))
    cpu = {k: [r["cpu_s"] for r in v] for k, v in runs.items()}
    summary = {
        k: {
            "cpu_s_min": round(min(v), 3),
            "cpu_s_median": round(statistics.median(v), 3),
            "runs": _rounded(v),
            "page_faults_min": min(r["page_faults"] for r in runs[k]),
        }
        for k, v in cpu.items()
    }
    hashes = {r["hash"] for v in runs.values() for r in v}
    print(
        json.dumps(
            {
                "scenario": f"kitti_{args.sequence:04d}",
                "variants": args.variants,
                **summary,
                "less_cpu_min": round(min(cpu["baseline"]) / min(cpu["search"]), 3),
                "less_cpu_median": round(statistics.median(cpu["baseline"]) / statistics.median(cpu["search"]), 3),
                "same_outcomes": len(hashes) == 1,
                "load_average": [round(load_before, 1), round(os.getloadavg()[0], 1)],
            }
        )
    )


if __name__ == "__main__":
    main()
