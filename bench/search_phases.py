"""Where the serial time of ``deepcrashtest search`` goes: the parent process's CPU per phase, measured in one run.

The workers simulate in parallel; what the parent does before they start (interpreter, imports, argument
parsing, loading the scenario, preparing the world they share) and after they finish (the results table, the
variant files, the summary) is serial, and bounds the whole process's wall time on 2 cores by about
``serial + (workers' CPU) / 2``. The CLI runs as ``bench/search_speed.py`` runs it (KITTI tracking 0003 as a
Scenario, ``--method random --starts 500 --noise-variants 4 --no-video``, bytecode cached) with timers wrapped
around the search's functions; ``--baseline-src`` times another checkout's CLI alternately in the same run.
CPU seconds (``time.process_time`` of the parent, from the process start; the children's from ``getrusage``)
are the figures a loaded machine blurs least; wall seconds are given for the record.

Each worker reports its own CPU since its fork (its share of the variants plus its cold costs: unpickling the job,
first-touch page faults, per-process caches); ``critical_path_cpu_s`` = the parent's serial CPU before the
workers + the slowest worker's CPU + the parent's serial CPU after them: the whole process's wall time on an
idle machine with a core per worker (~2.5 s for main's measured idle 2.55 s), from figures a load blurs less.

Prints one JSON line: per side, the parent's CPU by phase (the minimum over ``--repeat`` runs), the parent's
and the children's CPU in all, the critical path; the slowest worker's CPU and the wall seconds (in all, before
the workers start, after they finish) per run.
Usage: python bench/search_phases.py [--sequence 3 | --scene SCENARIO.json] [--starts 500]
       [--baseline-src OTHER/src] [--repeat 3]
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
KITTI = ROOT.parent / "shared" / "data" / "kitti_tracking"

# Runs in the timed process: wraps the search's functions with marks (parent CPU from the process start, wall),
# runs the CLI, prints the marks and the children's CPU as one JSON line on stderr.
PROBE = r"""
import json, resource, sys, time
W0 = time.perf_counter()
marks = [("start", 0.0, time.process_time())]
def mark(name):
    marks.append((name, time.perf_counter() - W0, time.process_time()))
def wrap(owner, attr, name):
    f = getattr(owner, attr, None)
    if f is None:
        return
    def g(*a, **k):
        mark(name + ":start")
        try:
            return f(*a, **k)
        finally:
            mark(name + ":end")
    setattr(owner, attr, g)
import deepcrashtest.cli as cli
mark("cli imported")
import deepcrashtest.search.plot as plot
start_helper = plot.start_helper
def helper():
    mark("arguments parsed")
    h = start_helper()
    import deepcrashtest.config, deepcrashtest.scenario as scn
    import deepcrashtest.search.evaluate as ev, deepcrashtest.search.outputs as out, deepcrashtest.search.run as run
    mark("search modules imported")
    wrap(scn.Scenario, "load", "load")
    wrap(run, "_original_and_random", "simulate")
    wrap(ev.Evaluator, "warm", "warm")
    wrap(ev.Evaluator, "_map", "workers")
    wrap(out, "write_variants", "variant files")
    sim = ev.simulate_variants
    def worker(*a, **k):  # in a forked worker: its CPU since the fork, cold costs included
        try:
            return sim(*a, **k)
        finally:
            sys.stderr.write("\nWORKER " + json.dumps(time.process_time()) + "\n")
    worker.__module__, worker.__qualname__ = ev.__name__, "simulate_variants"  # pickled by name, as the original
    ev.simulate_variants = worker
    return h
plot.start_helper = helper
code = cli.main(sys.argv[1:])
mark("end")
kids = resource.getrusage(resource.RUSAGE_CHILDREN)
sys.stderr.write("\nPHASES " + json.dumps({"marks": marks, "children_cpu": kids.ru_utime + kids.ru_stime}) + "\n")
sys.exit(code)
"""

# (phase, first mark, last mark): the parent's CPU between them
PHASES = (
    ("interpreter", "start", "start"),
    ("import cli (typer, numpy)", "start", "cli imported"),
    ("parse arguments (typer, pydantic)", "cli imported", "arguments parsed"),
    ("import search (scenario models, simulator)", "arguments parsed", "search modules imported"),
    ("load scenario, search space, variants", "search modules imported", "warm:start"),
    ("prepare the shared world (warm)", "warm:start", "warm:end"),
    ("start and wait for the workers", "workers:start", "workers:end"),
    ("results table", "simulate:end", "variant files:start"),
    ("variant files", "variant files:start", "variant files:end"),
    ("summary, exit", "variant files:end", "end"),
)


def _env(src: Path) -> dict[str, str]:
    env = {k: v for k, v in os.environ.items() if k != "PYTHONDONTWRITEBYTECODE"}
    return {**env, "PYTHONPATH": str(src)}


def _run(src: Path, cmd: list[str]) -> dict:
    """One CLI run with the probe: the parent's CPU per phase, its CPU and wall in all, the children's CPU."""
    proc = subprocess.run(
        [sys.executable, "-c", PROBE, *cmd], env=_env(src), capture_output=True, text=True, check=True
    )
    line = next(ln for ln in proc.stderr.splitlines() if ln.startswith("PHASES "))
    data = json.loads(line.removeprefix("PHASES "))
    cpu = {name: c for name, _, c in data["marks"]}
    wall = {name: w for name, w, _ in data["marks"]}
    phases = {}
    for label, a, b in PHASES:
        if a in cpu and b in cpu:
            phases[label] = cpu[b] - (0.0 if label == "interpreter" else cpu[a])
    serial_before = cpu["workers:start"]
    serial_after = cpu["end"] - cpu["workers:end"]
    workers = [json.loads(ln.removeprefix("WORKER ")) for ln in proc.stderr.splitlines() if ln.startswith("WORKER ")]
    return {
        "workers_cpu_s": workers,
        # the critical path on an idle machine with a core per worker: serial start, the slowest worker, serial end
        "critical_path_cpu_s": serial_before + max(workers, default=0.0) + serial_after,
        "phases_cpu_s": phases,
        "parent_cpu_s": cpu["end"],
        "serial_before_workers_cpu_s": serial_before,
        "serial_after_workers_cpu_s": serial_after,
        "children_cpu_s": data["children_cpu"],
        "wall_s": wall["end"],
        "wall_before_workers_s": wall["workers:start"],
        "wall_after_workers_s": wall["end"] - wall["workers:end"],
    }


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--baseline-src", default=None, help="another checkout's src/: its CLI timed alternately")
    ap.add_argument("--repeat", type=int, default=3, help="runs per side (the minimum of each figure counts)")
    ap.add_argument("--sequence", type=int, default=3, help="KITTI tracking sequence")
    ap.add_argument("--scene", default=None, help="a scenario.json to search instead (e.g. a crash clip's extract)")
    ap.add_argument("--starts", type=int, default=500, help="random starts (as search_speed.py)")
    ap.add_argument("--noise-variants", type=int, default=4, help="noisy paths per start")
    args = ap.parse_args()
    if not KITTI.exists():
        print(json.dumps({"skipped": f"real data not found: {KITTI}"}))
        return
    srcs = {"search": ROOT / "src"}
    if args.baseline_src:
        srcs["baseline"] = Path(args.baseline_src).resolve()
    with tempfile.TemporaryDirectory() as tmp:
        scen = Path(args.scene) if args.scene else Path(tmp) / "scenario" / "scenario.json"
        if not args.scene:
            make = "import sys, deepcrashtest.cli as c; sys.exit(c.main())"
            subprocess.run(
                [sys.executable, "-c", make, "scenario", "from-kitti", "--data", str(KITTI)]
                + ["--sequence", str(args.sequence), "-o", str(scen.parent)],
                check=True,
                env=_env(ROOT / "src"),
                stdout=subprocess.DEVNULL,
            )
        cmd = ["search", str(scen), "--method", "random", "--no-video", "--json"]
        cmd += ["--starts", str(args.starts), "--noise-variants", str(args.noise_variants)]
        for name, src in srcs.items():  # compile once (bytecode cached), untimed
            _run(src, [*cmd, "-o", str(Path(tmp) / f"warm_{name}")])
        load_before = os.getloadavg()[0]
        runs: dict[str, list[dict]] = {k: [] for k in srcs}
        for rep in range(args.repeat):
            for name, src in srcs.items():  # alternating: both sides see the same load
                runs[name].append(_run(src, [*cmd, "-o", str(Path(tmp) / f"{name}{rep}")]))
    label = Path(args.scene).parent.name if args.scene else f"kitti_{args.sequence:04d}"
    out: dict = {"scenario": label, "variants": args.starts * args.noise_variants + 1}
    for name, rs in runs.items():
        out[name] = {
            "phases_cpu_s": {
                k: round(min(r["phases_cpu_s"].get(k, 0.0) for r in rs), 3) for k in rs[0]["phases_cpu_s"]
            },
            **{
                k: round(min(r[k] for r in rs), 3)
                for k in (
                    "parent_cpu_s",
                    "serial_before_workers_cpu_s",
                    "serial_after_workers_cpu_s",
                    "children_cpu_s",
                    "critical_path_cpu_s",
                )
            },
            "slowest_worker_cpu_s_runs": [round(max(r["workers_cpu_s"], default=0.0), 3) for r in rs],
            "wall_s_runs": [round(r["wall_s"], 2) for r in rs],
            # the serial stretches' wall (the output helper works beside the parent after the workers)
            **{f"{k}_runs": [round(r[k], 3) for r in rs] for k in ("wall_before_workers_s", "wall_after_workers_s")},
        }
    out["load_average"] = [round(load_before, 1), round(os.getloadavg()[0], 1)]
    out["note"] = "CPU seconds of the parent by phase (minimum over runs); wall times depend on the machine's load"
    print(json.dumps(out))


if __name__ == "__main__":
    main()
