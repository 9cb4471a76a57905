"""When ``deepcrashtest extract`` keeps both cores busy: a per-thread CPU timeline of one run, in this process.

A sampler thread reads every thread's CPU (``/proc/self/task/*/stat``, user + system) every ``--every`` s
and names the Python threads (decode, detect, track, lanes, encode, imports, ...; native pools of
onnxruntime / FFmpeg / x264 / OpenCV show as "native"). Phase marks (wall s from the start): the pass
(first to last frame), the end of the pass's geometry, the crash, stage 2, the report. Printed: per
phase its wall time, process CPU and cores busy (CPU / wall), and each thread's CPU in it; then the
pass in bins of ``--bin`` s (cores busy per bin). The bins show idle gaps (a stage waiting for
another) and serial stretches (one core). On a loaded machine "cores busy" is what this process got.

Run: PYTHONPATH=src python bench/extract_timeline.py [VIDEO] [--max-frames N] [--bin 1.0]
"""

from __future__ import annotations

import argparse
import collections
import os
import threading
import time
from pathlib import Path
from typing import Any

ROOT = Path(__file__).resolve().parents[1]
DEFAULT = ROOT.parent / "shared" / "data" / "dashcam_udacity" / "highway_lane_challenge.mp4"
TICK = os.sysconf("SC_CLK_TCK")

#: (module, attribute path, phase name): wall time marks at entry and exit.
MARKS = [
    ("deepcrashtest.pipeline.extract", "_Pass.run", "pass"),
    ("deepcrashtest.geometry.selfcalib", "self_calibrate", "self-calibration"),
    ("deepcrashtest.geometry.world_tracks", "raw_scenario_from_tracks", "world tracks"),
    ("deepcrashtest.pipeline.crash", "crash_for_raw", "crash"),
    ("deepcrashtest.pipeline.stage2", "processed_scenario", "stage 2"),
    ("deepcrashtest.viz.report", "build_report", "report"),
]
marks: list[tuple[str, float, float]] = []


def _thread_cpu() -> dict[int, float]:
    """CPU seconds (user + system) of every thread of this process, by native id."""
    out = {}
    for tid in os.listdir("/proc/self/task"):
        try:
            with open(f"/proc/self/task/{tid}/stat") as fh:
                fields = fh.read().rsplit(")", 1)[1].split()
        except OSError:
            continue
        out[int(tid)] = (int(fields[11]) + int(fields[12])) / TICK
    return out


class Sampler(threading.Thread):
    def __init__(self, every: float, t0: float) -> None:
        super().__init__(name="sampler", daemon=True)
        self.every, self.t0 = every, t0
        self.samples: list[tuple[float, dict[int, float]]] = []
        self.names: dict[int, str] = {}
        self.stop = threading.Event()

    def run(self) -> None:
        while not self.stop.is_set():
            for t in threading.enumerate():
                if t.native_id is not None:
                    self.names[t.native_id] = t.name
            self.samples.append((time.perf_counter() - self.t0, _thread_cpu()))
            time.sleep(self.every)


def _mark(fn: Any, name: str, t0: float) -> Any:
    def wrapper(*args: Any, **kwargs: Any) -> Any:
        start = time.perf_counter() - t0
        try:
            return fn(*args, **kwargs)
        finally:
            marks.append((name, start, time.perf_counter() - t0))

    return wrapper


def _patch(t0: float) -> None:
    import importlib

    for module, attr, name in MARKS:
        mod = importlib.import_module(module)
        owner, _, leaf = attr.rpartition(".")
        target = getattr(mod, owner) if owner else mod
        setattr(target, leaf, _mark(getattr(target, leaf), name, t0))


def _label(name: str) -> str:
    if name.startswith("lanes"):
        return "lanes"
    if name.startswith("Thread-") or name.startswith("report"):
        return "other python"
    return name


def _cpu_between(sampler: Sampler, a: float, b: float) -> dict[str, float]:
    """CPU seconds per thread label between wall times a and b (nearest samples)."""
    out: collections.Counter[str] = collections.Counter()
    for tid, c in _cpu_at(sampler, b).items():
        out[_label(sampler.names.get(tid, "native"))] += c - _cpu_at(sampler, a).get(tid, 0.0)
    return dict(out)


def _cpu_at(sampler: Sampler, t: float) -> dict[int, float]:
    """Each thread's CPU seconds at the last sample at or before wall time ``t`` (an exited thread keeps
    its last value)."""
    out: dict[int, float] = {}
    for when, cpu in sampler.samples:
        if when > t:
            break
        out.update(cpu)
    return out


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("video", nargs="?", default=str(DEFAULT))
    ap.add_argument("--max-frames", type=int, default=None)
    ap.add_argument("--every", type=float, default=0.2, help="sampling period, s")
    ap.add_argument("--bin", type=float, default=1.0, help="timeline bin of the pass, s")
    ap.add_argument("--args", default="", help="extra extract arguments")
    args = ap.parse_args()
    t0 = time.perf_counter()
    sampler = Sampler(args.every, t0)
    sampler.names[threading.main_thread().native_id or 0] = "main"
    sampler.start()
    from extract_stages import run_extract_cli  # bench/ is the script's folder

    from deepcrashtest.cli import app

    _patch(t0)
    n = run_extract_cli(app, args.video, args.max_frames, args.args)["frames"]
    time.sleep(2 * args.every)
    sampler.stop.set()
    sampler.join()
    end = sampler.samples[-1][0]
    print(f"{args.video}: {n} frames; wall {end:.1f} s; load average {os.getloadavg()[0]:.1f}")
    bounds = {name: (a, b) for name, a, b in marks}
    p0, p1 = bounds["pass"]
    phases = [("before the pass", 0.0, p0), ("pass", p0, p1), ("after the pass", p1, end)]
    phases += [(name, a, b) for name, a, b in marks if name != "pass"]
    print("| phase | wall s (from - to) | CPU s | cores busy | CPU s by thread |")
    print("|---|---|---|---|---|")
    for name, a, b in phases:
        by = _cpu_between(sampler, a, b)
        total = sum(by.values())
        top = ", ".join(f"{k} {v:.2f}" for k, v in sorted(by.items(), key=lambda kv: -kv[1]) if v >= 0.05)
        print(f"| {name} | {b - a:.2f} ({a:.2f}-{b:.2f}) | {total:.2f} | {total / max(b - a, 1e-9):.2f} | {top} |")
    print(f"\nthe pass in {args.bin:g} s bins: cores busy (CPU s / wall s) and the busiest threads")
    t = p0
    while t < p1:
        by = _cpu_between(sampler, t, min(t + args.bin, p1))
        total = sum(by.values())
        top = ", ".join(f"{k} {v:.2f}" for k, v in sorted(by.items(), key=lambda kv: -kv[1])[:5])
        print(f"{t - p0:6.1f} s: {total / args.bin:4.2f}  {top}")
        t += args.bin


if __name__ == "__main__":
    main()
