"""`deepcrashtest search` speed through the CLI against the simulator it drives, measured in one run.

1. KITTI tracking 0003 (ground-truth labels -> stage 2, 9 agents, 14.3 s simulated) is written as a Scenario;
2. ``deepcrashtest search SCENARIO --method random --starts 500 --noise-variants 4 --no-video`` runs as a
   whole process (imports, set-up, 2,001 simulations, results.csv, summary.json, starts.png, variant files),
   ``--workers`` left at its default (the cores): variants/s = simulations / process wall time;
3. ``simulate_batch`` simulates the same 2,000 variants (same paths) in-process with the same workers
   (chunks of 1,024, one per worker): the simulator's own variants/s, and the ratio simulator / search (the
   goal: <= 2), in wall time and in CPU seconds (the search's whole process and its children against the
   simulator's; the CPU ratio is the one a loaded machine does not blur);
4. the first ``--stepwise`` variants (default 256) once more in one process, through the replay batch
   mode (``sim.replay_batch``, the default) and through the per-step loop (``stepwise=True``, what
   the search used before): the simulator's speed-up, and a check that both give the same outcomes.

Prints one JSON line. The figures are wall times of a machine that may be shared: the ratio, measured in
one run, is the robust figure; ``search_cpu_s`` is the CPU time the search process and its workers used;
``load_average`` (1-minute, before and after) says how shared the machine was. The CLI runs with Python's
bytecode cache on (``PYTHONDONTWRITEBYTECODE`` dropped, the modules compiled once before the timed runs), as
an installed package runs: without it every run compiles each module again (~0.2 s of CPU here).
Usage: python bench/search_speed.py [--sequence 3] [--starts 500] [--noise-variants 4] [--workers N] [--stepwise 256]
       [--baseline-src OTHER_CHECKOUT/src] [--repeat 1]  (before/after: both CLIs alternately, same run)
"""

from __future__ import annotations

import argparse
import filecmp
import json
import os
import resource
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "src"))

from deepcrashtest.scenario import Scenario  # noqa: E402
from deepcrashtest.search.space import SearchSpace  # noqa: E402
from deepcrashtest.sim import prepare, simulate_batch  # noqa: E402

KITTI = ROOT.parent / "shared" / "data" / "kitti_tracking"


def _cli(*args: str) -> list[str]:
    """The console command (``cli.run``; ``cli.main`` in a checkout without it)."""
    code = "import sys, deepcrashtest.cli as c; r = getattr(c, 'run', None); sys.exit(r() if r else c.main())"
    return [sys.executable, "-c", code, *args]


def _env(src: Path) -> dict[str, str]:
    """The CLI's environment: ``src`` first on the path, bytecode cached (as an installed package)."""
    env = {k: v for k, v in os.environ.items() if k != "PYTHONDONTWRITEBYTECODE"}
    return {**env, "PYTHONPATH": str(src)}


def _compile(src: Path) -> None:
    """Compile the search's modules of ``src`` once (their bytecode cached beside them), untimed."""
    imports = "import deepcrashtest.cli, deepcrashtest.config, deepcrashtest.search.run, deepcrashtest.search.plot"
    subprocess.run([sys.executable, "-c", imports], check=True, env=_env(src))


def _time_cli(cmd: list[str], src: Path) -> tuple[dict, float, float]:
    """Run the CLI with ``src`` first on the path: its JSON summary, wall seconds, CPU seconds (with children)."""
    env = _env(src)
    before = resource.getrusage(resource.RUSAGE_CHILDREN)
    t0 = time.perf_counter()
    proc = subprocess.run(_cli(*cmd), check=True, env=env, capture_output=True, text=True)
    wall = time.perf_counter() - t0
    after = resource.getrusage(resource.RUSAGE_CHILDREN)
    cpu = after.ru_utime + after.ru_stime - before.ru_utime - before.ru_stime
    return json.loads(proc.stdout), wall, cpu


def _stepwise(world, paths: np.ndarray) -> dict:
    """Replay batch mode against the per-step loop on the same variants, one process, alternating."""
    zero = np.zeros((len(paths), 2))
    times: dict[bool, float] = {False: 0.0, True: 0.0}
    res = {}
    for stepwise in (False, True, False, True):
        t0 = time.process_time()
        res[stepwise] = simulate_batch(world, zero, ego_paths=paths, stepwise=stepwise)
        times[stepwise] += time.process_time() - t0
    same = all(
        np.allclose(getattr(res[False], k), getattr(res[True], k), rtol=0, atol=1e-9, equal_nan=True)
        for k in res[False].__dataclass_fields__
    )
    return {
        "stepwise_variants": len(paths),
        "replay_batch_cpu_ms_per_variant": round(1000 * times[False] / (2 * len(paths)), 2),
        "stepwise_loop_cpu_ms_per_variant": round(1000 * times[True] / (2 * len(paths)), 2),
        "simulator_speedup": round(times[True] / times[False], 2),
        "same_outcomes": bool(same),
    }


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--sequence", type=int, default=3)
    ap.add_argument("--starts", type=int, default=500)
    ap.add_argument("--noise-variants", type=int, default=4)
    ap.add_argument("--workers", type=int, default=None, help="default: the cores (as the CLI)")
    ap.add_argument("--stepwise", type=int, default=256, help="variants compared with the per-step loop (0: none)")
    ap.add_argument("--baseline-src", default=None, help="another checkout's src/: its CLI timed alternately")
    ap.add_argument("--repeat", type=int, default=1, help="CLI runs per side (the fastest counts)")
    args = ap.parse_args()
    if not KITTI.exists():
        print(json.dumps({"skipped": f"real data not found: {KITTI}"}))
        return
    workers = args.workers or len(os.sched_getaffinity(0))
    env = {**os.environ, "PYTHONPATH": str(ROOT / "src")}
    with tempfile.TemporaryDirectory() as tmp:
        scen_dir = Path(tmp) / "scenario"
        subprocess.run(
            _cli("scenario", "from-kitti", "--data", str(KITTI), "--sequence", str(args.sequence), "-o", str(scen_dir)),
            check=True,
            env=env,
            stdout=subprocess.DEVNULL,
        )
        scen = scen_dir / "scenario.json"
        cmd = ["search", str(scen), "--method", "random", "--no-video"]
        cmd += ["--starts", str(args.starts), "--noise-variants", str(args.noise_variants), "--json"]
        if args.workers:
            cmd += ["--workers", str(args.workers)]
        srcs = {"search": ROOT / "src"}
        if args.baseline_src:
            srcs["baseline"] = Path(args.baseline_src).resolve()
        for src in srcs.values():
            _compile(src)
        load_before = os.getloadavg()[0]
        runs: dict[str, list[tuple[float, float]]] = {k: [] for k in srcs}
        summaries: dict[str, dict] = {}
        for rep in range(args.repeat):
            for name, src in srcs.items():  # alternating, so that both see the same load
                out_dir = Path(tmp) / f"{name}{rep}"
                summaries[name], wall, cpu = _time_cli(cmd + ["-o", str(out_dir)], src)
                runs[name].append((wall, cpu))
        summary = summaries["search"]
        written = sorted(p.name for p in (Path(tmp) / "search0").iterdir())
        same_csv = (
            filecmp.cmp(Path(tmp) / "search0" / "results.csv", Path(tmp) / "baseline0" / "results.csv", shallow=False)
            if "baseline" in srcs
            else None
        )
        sc = Scenario.load(scen)
        space = SearchSpace.for_scenario(sc)
        theta = space.reference_grid(np.random.default_rng([0, 1]), args.starts, args.noise_variants)
        world = prepare(sc)
        simulate_batch(world, np.zeros((2, 2)), ego_paths=space.paths(theta[:2]))  # warm-up: imports, agents
        paths = space.paths(theta)
        c0, kids0 = time.process_time(), resource.getrusage(resource.RUSAGE_CHILDREN)
        t0 = time.perf_counter()
        simulate_batch(world, np.zeros((len(theta), 2)), ego_paths=paths, workers=workers, chunk_size=1024)
        sim_s = time.perf_counter() - t0
        kids1 = resource.getrusage(resource.RUSAGE_CHILDREN)
        sim_cpu = time.process_time() - c0 + kids1.ru_utime + kids1.ru_stime - kids0.ru_utime - kids0.ru_stime
        steps = _stepwise(world, paths[: args.stepwise]) if args.stepwise else {}
    n = int(summary["simulations"])
    search_s = min(w for w, _ in runs["search"])
    base: dict = {}
    if "baseline" in runs:
        b_wall, b_cpu = min(w for w, _ in runs["baseline"]), min(c for _, c in runs["baseline"])
        base = {
            "baseline_src": str(srcs["baseline"]),
            "baseline_wall_s": round(b_wall, 2),
            "baseline_cpu_s": round(b_cpu, 2),
            "baseline_variants_per_s": round(n / b_wall, 1),
            "speedup_wall": round(b_wall / search_s, 2),
            "speedup_cpu": round(b_cpu / min(c for _, c in runs["search"]), 2),
            "same_results_csv_as_baseline": same_csv,
        }
    print(
        json.dumps(
            {
                "scenario": f"kitti_{args.sequence:04d}",
                "agents": len(sc.agents),
                "variants": n,
                "workers": summary["workers"],
                "search_wall_s": round(search_s, 2),
                "search_cpu_s": round(min(c for _, c in runs["search"]), 2),
                "search_variants_per_s": round(n / search_s, 1),
                **base,
                "search_inner_variants_per_s": summary["variants_per_s"],
                "simulate_batch_variants_per_s": round(len(theta) / sim_s, 1),
                "ratio_simulator_to_search": round((len(theta) / sim_s) / (n / search_s), 2),
                "simulate_batch_cpu_s": round(sim_cpu, 2),
                "ratio_cpu_search_to_simulator": round(min(c for _, c in runs["search"]) / sim_cpu, 2),
                **steps,
                "outputs": written,
                "cpus": os.cpu_count(),
                "load_average": [round(load_before, 1), round(os.getloadavg()[0], 1)],
                "note": "wall times on a possibly shared machine; the ratio is measured in one run",
            }
        )
    )


if __name__ == "__main__":
    main()
