"""`deepcrashtest search` speed through the CLI against the simulator it drives, measured in one run.

1. KITTI tracking 0003 (ground-truth labels -> stage 2, 9 agents, 14.3 s simulated) is written as a Scenario;
2. ``deepcrashtest search SCENARIO --method random --starts 500 --noise-variants 4 --no-video`` runs as a
   whole process (imports, set-up, 2,001 simulations, results.csv, summary.json, starts.png, variant files),
   ``--workers`` left at its default (the cores): variants/s = simulations / process wall time;
3. ``simulate_batch`` simulates the same 2,000 variants (same paths) in-process with the same workers
   (chunks of 1,024, one per worker; ``--repeat`` times, the fastest counting, as for the search): the simulator's
   own variants/s, and the ratio simulator / search (the
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
``--scene`` (repeatable: ``kitti:N``, ``kitti8crash``, a scenario.json path) measures several scenes, a JSON
line each, and prints the per-scene CPU ratio table (search / simulate_batch; the goal: <= 2 for any scene) on
stderr; with ``--baseline-src`` the outputs (results.csv, variant files, summary.json but its timings) are
compared byte for byte.
Usage: python bench/search_speed.py [--sequence 3] [--scene SPEC ...] [--starts 500] [--noise-variants 4]
       [--workers N] [--stepwise 256]
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


def _scene(spec: str, tmp: Path, env: dict[str, str]) -> tuple[str, Path]:
    """A scene to search: ``kitti:N`` (sequence N from labels, through the CLI), ``kitti8crash`` (KITTI 0008
    with the oncoming car 10 moved to meet the ego, as ``search_common.crash_scenario``) or a scenario.json
    path (e.g. a crash clip's extract). Returns its label and the written scenario file."""
    if spec.startswith("kitti:"):
        seq = int(spec.removeprefix("kitti:"))
        scen_dir = tmp / f"kitti{seq}"
        subprocess.run(
            _cli("scenario", "from-kitti", "--data", str(KITTI), "--sequence", str(seq), "-o", str(scen_dir)),
            check=True,
            env=env,
            stdout=subprocess.DEVNULL,
        )
        return f"kitti_{seq:04d}", scen_dir / "scenario.json"
    if spec == "kitti8crash":
        sys.path.insert(0, str(ROOT / "bench"))
        from search_common import crash_scenario

        return "kitti_0008_crash", crash_scenario().save(tmp / "kitti8crash.json", False)
    path = Path(spec)
    return path.parent.name or path.stem, path


def _measure(label: str, scen: Path, args: argparse.Namespace, tmp: Path, workers: int) -> dict:
    """One scene: the search CLI (and the baseline's, alternately) against ``simulate_batch`` in one run."""
    cmd = ["search", str(scen), "--method", "random", "--no-video"]
    cmd += ["--starts", str(args.starts), "--noise-variants", str(args.noise_variants), "--json"]
    if args.workers:
        cmd += ["--workers", str(args.workers)]
    srcs = {"search": ROOT / "src"}
    if args.baseline_src:
        srcs["baseline"] = Path(args.baseline_src).resolve()
    load_before = os.getloadavg()[0]
    runs: dict[str, list[tuple[float, float]]] = {k: [] for k in srcs}
    summaries: dict[str, dict] = {}
    for rep in range(args.repeat):
        for name, src in srcs.items():  # alternating, so that both see the same load
            out_dir = tmp / f"{label}_{name}{rep}"
            summaries[name], wall, cpu = _time_cli(cmd + ["-o", str(out_dir)], src)
            runs[name].append((wall, cpu))
    summary = summaries["search"]
    written = sorted(p.name for p in (tmp / f"{label}_search0").iterdir())
    same = _same_outputs(tmp / f"{label}_search0", tmp / f"{label}_baseline0") if "baseline" in srcs else None
    sc = Scenario.load(scen)
    space = SearchSpace.for_scenario(sc)
    theta = space.reference_grid(np.random.default_rng([0, 1]), args.starts, args.noise_variants)
    world = prepare(sc)
    simulate_batch(world, np.zeros((2, 2)), ego_paths=space.paths(theta[:2]))  # warm-up: imports, agents
    paths = space.paths(theta)
    sims = [_time_simulator(world, paths, workers) for _ in range(args.repeat)]  # best of as many as the search's
    sim_s, sim_cpu = min(w for w, _ in sims), min(c for _, c in sims)
    steps = _stepwise(world, paths[: args.stepwise]) if args.stepwise else {}
    n = int(summary["simulations"])
    search_s = min(w for w, _ in runs["search"])
    search_cpu = min(c for _, c in runs["search"])
    base: dict = {}
    if "baseline" in runs:
        b_wall, b_cpu = min(w for w, _ in runs["baseline"]), min(c for _, c in runs["baseline"])
        base = {
            "baseline_src": str(srcs["baseline"]),
            "baseline_wall_s": round(b_wall, 2),
            "baseline_cpu_s": round(b_cpu, 2),
            "baseline_variants_per_s": round(n / b_wall, 1),
            "speedup_wall": round(b_wall / search_s, 2),
            "speedup_cpu": round(b_cpu / search_cpu, 2),
            "baseline_ratio_cpu_search_to_simulator": round(b_cpu / sim_cpu, 2),
            "same_outputs_as_baseline": same,
        }
    return {
        "scenario": label,
        "agents": len(sc.agents),
        "variants": n,
        "workers": summary["workers"],
        "search_wall_s": round(search_s, 2),
        "search_cpu_s": round(search_cpu, 2),
        "search_variants_per_s": round(n / search_s, 1),
        **base,
        "search_inner_variants_per_s": summary["variants_per_s"],
        "simulate_batch_variants_per_s": round(len(theta) / sim_s, 1),
        "ratio_simulator_to_search": round((len(theta) / sim_s) / (n / search_s), 2),
        "simulate_batch_cpu_s": round(sim_cpu, 2),
        "ratio_cpu_search_to_simulator": round(search_cpu / sim_cpu, 2),
        **steps,
        "outputs": written,
        "load_average": [round(load_before, 1), round(os.getloadavg()[0], 1)],
    }


def _time_simulator(world, paths: np.ndarray, workers: int) -> tuple[float, float]:
    """``simulate_batch`` of the variants ``paths`` (chunks of 1,024, ``workers`` processes): wall s, CPU s (this
    process and its workers)."""
    c0, kids0 = time.process_time(), resource.getrusage(resource.RUSAGE_CHILDREN)
    t0 = time.perf_counter()
    simulate_batch(world, np.zeros((len(paths), 2)), ego_paths=paths, workers=workers, chunk_size=1024)
    wall = time.perf_counter() - t0
    kids1 = resource.getrusage(resource.RUSAGE_CHILDREN)
    return wall, time.process_time() - c0 + kids1.ru_utime + kids1.ru_stime - kids0.ru_utime - kids0.ru_stime


def _same_outputs(a: Path, b: Path) -> bool:
    """Whether two search output folders hold byte-identical results.csv and variant files, and summary.json
    files equal but for the timings and the output paths."""
    names = ["results.csv"] + [f"safe_variants/{p.name}" for p in sorted((a / "safe_variants").glob("*.json"))]
    same_names = sorted(p.name for p in (a / "safe_variants").glob("*")) == sorted(
        p.name for p in (b / "safe_variants").glob("*")
    )
    same_files = all(filecmp.cmp(a / f, b / f, shallow=False) for f in names)

    def _summary(folder: Path) -> dict:
        s = json.loads((folder / "summary.json").read_text())
        for k in ("elapsed_s", "variants_per_s", "outputs"):
            s.pop(k, None)
        return s

    return same_names and same_files and _summary(a) == _summary(b)


def _table(rows: list[dict]) -> str:
    """The per-scene ratio table (CPU seconds: search's whole process and workers / simulate_batch's)."""
    head = f"{'scene':<20} {'agents':>6} {'variants':>8} {'search cpu s':>12} {'sim cpu s':>9} {'cpu ratio':>9}"
    head += f" {'search /s wall':>14} {'sim /s wall':>11}"
    lines = [head]
    for r in rows:
        lines.append(
            f"{r['scenario']:<20} {r['agents']:>6} {r['variants']:>8} {r['search_cpu_s']:>12.2f} "
            f"{r['simulate_batch_cpu_s']:>9.2f} {r['ratio_cpu_search_to_simulator']:>9.2f} "
            f"{r['search_variants_per_s']:>14.1f} {r['simulate_batch_variants_per_s']:>11.1f}"
            + (f"  baseline cpu ratio {r['baseline_ratio_cpu_search_to_simulator']:.2f}" if "speedup_cpu" in r else "")
        )
    return "\n".join(lines)


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--sequence", type=int, default=3, help="KITTI sequence (without --scene)")
    ap.add_argument(
        "--scene",
        action="append",
        default=None,
        help="kitti:N, kitti8crash or a scenario.json path; repeat for several (a JSON line each and a table)",
    )
    ap.add_argument("--starts", type=int, default=500)
    ap.add_argument("--noise-variants", type=int, default=4)
    ap.add_argument("--workers", type=int, default=None, help="default: the cores (as the CLI)")
    ap.add_argument("--stepwise", type=int, default=256, help="variants compared with the per-step loop (0: none)")
    ap.add_argument("--baseline-src", default=None, help="another checkout's src/: its CLI timed alternately")
    ap.add_argument("--repeat", type=int, default=1, help="CLI runs per side and simulator runs (the fastest counts)")
    args = ap.parse_args()
    if not KITTI.exists():
        print(json.dumps({"skipped": f"real data not found: {KITTI}"}))
        return
    workers = args.workers or len(os.sched_getaffinity(0))
    env = {**os.environ, "PYTHONPATH": str(ROOT / "src")}
    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        _compile(ROOT / "src")
        if args.baseline_src:
            _compile(Path(args.baseline_src).resolve())
        # the scene is written by the baseline's CLI when there is one: a newer checkout reads an older schema
        # (migrated), an older one refuses a newer schema's file
        scene_env = {**env, "PYTHONPATH": str(Path(args.baseline_src).resolve())} if args.baseline_src else env
        for spec in args.scene or [f"kitti:{args.sequence}"]:
            label, scen = _scene(spec, Path(tmp), scene_env)
            row = _measure(label, scen, args, Path(tmp), workers)
            row["cpus"] = os.cpu_count()
            row["note"] = "wall times on a possibly shared machine; the ratio is measured in one run"
            print(json.dumps(row), flush=True)
            rows.append(row)
    if len(rows) > 1:
        print(_table(rows), file=sys.stderr)


if __name__ == "__main__":
    main()
