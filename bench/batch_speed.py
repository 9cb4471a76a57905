"""`deepcrashtest batch` throughput on a folder of crash clips: one input at a time against several at once.

Runs ``deepcrashtest batch FOLDER -o OUT --jobs 1`` and ``--jobs N`` (default: the batch's own default,
``pipeline.batch.default_jobs``) alternately ``--repeat`` times as whole processes, the default search on each
input, and prints one JSON line: wall seconds per input for each (the fastest run counting), their ratio (the
figure: measured in one run, it holds on a shared machine), the CPU seconds of each (the process and its
children), the load average before and after, and whether the two wrote the same outputs (every ``*.json`` /
``*.csv`` but the manifest, the search's timings and paths compared).

Usage: python bench/batch_speed.py [FOLDER] [--jobs N] [--repeat 1]
FOLDER defaults to six crash clips of ``../shared/data`` (linked into a temporary folder).
"""

from __future__ import annotations

import argparse
import json
import os
import resource
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
DATA = ROOT.parent / "shared" / "data"
CLIPS = ("crash_ccd/ccd_000031", "crash_ccd/ccd_000080", "crash_ccd/ccd_000330", "crash_ccd/ccd_000721",
         "crash_dad/dad_000478", "crash_dad/dad_000550")  # fmt: skip
#: Fields of a search's summary.json that say how it ran, not what it found.
RUN_FIELDS = ("workers", "elapsed_s", "variants_per_s")


def _children_cpu() -> float:
    r = resource.getrusage(resource.RUSAGE_CHILDREN)
    return r.ru_utime + r.ru_stime


def _run(folder: Path, out: Path, jobs: int) -> tuple[float, float]:
    """(wall s, CPU s) of one whole ``batch`` process (``--quiet``, outputs into ``out``)."""
    cmd = [sys.executable, "-m", "deepcrashtest.cli", "--quiet", "batch", str(folder), "-o", str(out), "--jobs",
           str(jobs), "--force"]  # fmt: skip
    env = {**os.environ, "PYTHONPATH": str(ROOT / "src")}
    cpu0, t0 = _children_cpu(), time.perf_counter()
    proc = subprocess.run(cmd, env=env, capture_output=True, text=True, check=False)
    wall, cpu = time.perf_counter() - t0, _children_cpu() - cpu0
    if proc.returncode not in (0, 1):
        raise SystemExit(f"batch failed ({proc.returncode}): {proc.stderr.strip()[-500:]}")
    return wall, cpu


def _outputs(out: Path) -> dict[str, object]:
    """Every json / csv an input wrote, by path relative to ``out`` (the search's run fields and paths dropped)."""
    found: dict[str, object] = {}
    for path in sorted(out.rglob("*")):
        if path.suffix not in (".json", ".csv") or path.name == "manifest.json":
            continue
        rel = str(path.relative_to(out))
        if path.name == "summary.json":
            data = json.loads(path.read_text())
            found[rel] = json.loads(json.dumps({k: v for k, v in data.items() if k not in RUN_FIELDS})
                                    .replace(str(out), "OUT"))  # fmt: skip
        else:
            found[rel] = path.read_bytes()
    return found


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("folder", nargs="?", type=Path)
    ap.add_argument("--jobs", type=int, default=None, help="the parallel run's --jobs [the batch's default]")
    ap.add_argument("--repeat", type=int, default=1)
    args = ap.parse_args()
    sys.path.insert(0, str(ROOT / "src"))
    from deepcrashtest.pipeline.batch import default_jobs, list_inputs

    jobs = args.jobs or default_jobs()
    with tempfile.TemporaryDirectory(prefix="batch_speed_") as tmp:
        folder = args.folder
        if folder is None:
            folder = Path(tmp) / "clips"
            folder.mkdir()
            for clip in CLIPS:
                (folder / Path(clip).name).with_suffix(".mp4").symlink_to(DATA / f"{clip}.mp4")
        inputs = len(list_inputs(folder))
        load0 = os.getloadavg()[0]
        best: dict[int, tuple[float, float]] = {}
        for _ in range(args.repeat):
            for n in (1, jobs):
                wall, cpu = _run(folder, Path(tmp) / f"out{n}", n)
                if n not in best or wall < best[n][0]:
                    best[n] = (wall, cpu)
        same = _outputs(Path(tmp) / "out1") == _outputs(Path(tmp) / f"out{jobs}")
        row = {
            "inputs": inputs,
            "jobs": jobs,
            "s_per_input_jobs1": round(best[1][0] / inputs, 2),
            f"s_per_input_jobs{jobs}": round(best[jobs][0] / inputs, 2),
            "speedup": round(best[1][0] / best[jobs][0], 2),
            "cpu_s_jobs1": round(best[1][1], 1),
            f"cpu_s_jobs{jobs}": round(best[jobs][1], 1),
            "same_outputs": same,
            "load_average": [round(load0, 2), round(os.getloadavg()[0], 2)],
            "repeat": args.repeat,
        }
        print(json.dumps(row))


if __name__ == "__main__":
    main()
