"""``deepcrashtest extract`` end to end as a whole process: wall fps, CPU seconds, peak memory.

Each variant runs the CLI in a fresh process (imports, decode, detection, tracking, ego-motion, lanes,
localisation, stage 2, annotated H.264 video, report). Variants alternate run by run, so a load
spike on a shared machine hits them alike; the load average is printed with the figures. CPU seconds
(user + sys of the process) depend much less on other load than wall time: on an idle 2-core machine
a pipelined run's wall time approaches CPU / 2.

Run: PYTHONPATH=src python bench/extract_e2e.py [VIDEO] [--baseline-src ../main/src] [--repeat 1]
  ``--baseline-src DIR`` adds the code in DIR (e.g. an older checkout's src) with its own defaults.
  ``--variant NAME=ARGS`` (repeatable) adds runs of this checkout with extra CLI arguments.
  ``--env-variant NAME=VAR=VALUE[,VAR=VALUE...]`` (repeatable) adds runs of this checkout with those environment
  variables set (thread pools, allocator: e.g. ``blas1=OPENBLAS_NUM_THREADS=1``).
  ``--pingpong N``: the runs take a long single-shot clip made of the video played forward, backward, forward ...
  N times (no cut at the joins; ``--pingpong 4`` of the 50 s highway clip: 200 s, 5,040 frames): how time and
  memory grow with the length of a recording.
"""

from __future__ import annotations

import argparse
import json
import os
import shlex
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
DEFAULT = ROOT.parent / "shared" / "data" / "dashcam_udacity" / "highway_lane_challenge.mp4"


def run_once(src: Path, video: str, extra: list[str], out: Path, env_extra: dict[str, str]) -> dict[str, float]:
    """One extract process (``env_extra`` added to its environment); returns wall s, CPU s, peak RSS MB, frames,
    and the process's own fps."""
    env = dict(os.environ, PYTHONPATH=str(src), **env_extra)
    cmd = [sys.executable, "-m", "deepcrashtest.cli", "extract", video, "-o", str(out), "--force", "--json", *extra]
    t = time.perf_counter()
    proc = subprocess.Popen(cmd, env=env, stdout=subprocess.PIPE, stderr=subprocess.PIPE)
    _, status, usage = os.wait4(proc.pid, 0)
    wall = time.perf_counter() - t
    stdout, stderr = proc.stdout.read(), proc.stderr.read()  # type: ignore[union-attr]
    if status != 0:
        raise SystemExit(f"{' '.join(cmd)} failed:\n{stderr.decode()[-2000:]}")
    result = json.loads(stdout)
    return {
        "wall": wall,
        "cpu": usage.ru_utime + usage.ru_stime,
        "rss_mb": usage.ru_maxrss / 1024,
        "frames": result["frames"],
        "inner_fps": result["fps_achieved"],
    }


def pingpong(video: str, times: int, out: Path) -> str:
    """``video`` played forward, backward, forward ... ``times`` times into ``out`` (H.264, crf 18): one shot."""
    import av

    with av.open(video) as src:
        stream = src.streams.video[0]
        rate = stream.average_rate
        frames = [f.to_ndarray(format="rgb24") for f in src.decode(stream)]
    with av.open(str(out), "w") as dst:
        enc = dst.add_stream("libx264", rate=rate)
        enc.height, enc.width = frames[0].shape[:2]
        enc.pix_fmt, enc.options = "yuv420p", {"crf": "18", "preset": "ultrafast"}
        for k in range(times):
            for img in frames if k % 2 == 0 else frames[::-1]:
                dst.mux(enc.encode(av.VideoFrame.from_ndarray(img, format="rgb24")))
        dst.mux(enc.encode())
    return str(out)


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("video", nargs="?", default=str(DEFAULT))
    ap.add_argument("--baseline-src", type=Path, default=None)
    ap.add_argument("--baseline-args", default="", help="extra CLI arguments of the baseline runs")
    ap.add_argument("--variant", action="append", default=[], help="NAME=EXTRA CLI ARGS (this checkout)")
    ap.add_argument("--repeat", type=int, default=1)
    ap.add_argument("--env-variant", action="append", default=[], help="NAME=VAR=VALUE[,VAR=VALUE] (this checkout)")
    ap.add_argument("--pingpong", type=int, default=1, help="play the video forward/backward N times (long clip)")
    ap.add_argument("--common", default="", help="extra CLI arguments of every run (e.g. '--max-frames 100')")
    args = ap.parse_args()
    variants: list[tuple[str, Path, list[str], dict[str, str]]] = []
    if args.baseline_src is not None:
        variants.append(("baseline", args.baseline_src, shlex.split(args.baseline_args), {}))
    variants.append(("this checkout", ROOT / "src", [], {}))
    for v in args.variant:
        name, _, extra = v.partition("=")
        variants.append((name, ROOT / "src", shlex.split(extra), {}))
    for v in args.env_variant:
        name, _, assignments = v.partition("=")
        env = dict(kv.split("=", 1) for kv in assignments.split(",") if "=" in kv)
        variants.append((name, ROOT / "src", [], env))
    runs: dict[str, list[dict[str, float]]] = {name: [] for name, _, _, _ in variants}
    loads = []
    with tempfile.TemporaryDirectory() as tmp:
        if args.pingpong > 1:
            args.video = pingpong(args.video, args.pingpong, Path(tmp) / "pingpong.mp4")
        for _ in range(args.repeat):
            for name, src, extra, env in variants:
                loads.append(os.getloadavg()[0])
                out = Path(tmp) / "out"
                runs[name].append(run_once(src, args.video, shlex.split(args.common) + extra, out, env))
    print(f"{args.video}: {runs[variants[0][0]][0]['frames']} frames, {os.cpu_count()} cores")
    print(f"load average during the runs: {min(loads):.1f}-{max(loads):.1f} (1 min)")
    print("| variant | wall fps (process) | wall s | CPU s | CPU s / frame | fps inside | peak RSS MB |")
    print("|---|---|---|---|---|---|---|")
    for name, _, _, _ in variants:
        r = min(runs[name], key=lambda x: x["wall"])
        print(
            f"| {name} | {r['frames'] / r['wall']:.2f} | {r['wall']:.1f} | {r['cpu']:.1f} | "
            f"{r['cpu'] / r['frames'] * 1000:.0f} ms | {r['inner_fps']:.2f} | {r['rss_mb']:.0f} |"
        )
    if args.repeat > 1:  # CPU seconds vary by ~10 % run to run under load: every run's, in order
        for name, _, _, _ in variants:
            cpus = ", ".join(f"{r['cpu']:.1f}" for r in runs[name])
            walls = ", ".join(f"{r['wall']:.1f}" for r in runs[name])
            med = np.median([r["cpu"] for r in runs[name]])
            print(f"{name}: CPU s per run {cpus} (median {med:.1f}); wall s {walls}")
    if len(variants) > 1:
        a, b = (min(runs[n], key=lambda x: x["wall"]) for n in (variants[0][0], variants[1][0]))
        print(
            f"{variants[1][0]} vs {variants[0][0]}: wall {a['wall'] / b['wall']:.2f}x, CPU {a['cpu'] / b['cpu']:.2f}x"
        )


if __name__ == "__main__":
    main()
