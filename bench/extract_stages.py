"""Where ``deepcrashtest extract`` spends its CPU: per-stage CPU milliseconds per frame, one process.

Runs the CLI's ``extract`` inside this process with a CPU timer (``time.thread_time``, the calling
thread's CPU) around each stage: decode, detector, tracker (without the detector), ego-motion, lanes,
global motion, annotation + encode, the per-frame tables, camera estimation, self-calibration + world
tracks, the crash, stage 2, the report, the shot scan. ``--native-threads 1`` runs OpenCV and
onnxruntime single-threaded so each stage's CPU is all in its calling thread (the default, like the
CLI, lets them use their own thread pools, whose CPU then shows only in the process total). The rest
of the process CPU (imports, codec threads, native pools, the GIL) is printed as "other".

Run: PYTHONPATH=src python bench/extract_stages.py [VIDEO] [--max-frames N] [--native-threads 1]
"""

from __future__ import annotations

import argparse
import collections
import functools
import importlib
import resource
import sys
import tempfile
import threading
import time
from pathlib import Path
from typing import Any

ROOT = Path(__file__).resolve().parents[1]
DEFAULT = ROOT.parent / "shared" / "data" / "dashcam_udacity" / "highway_lane_challenge.mp4"

#: (module, attribute path, stage name); a method is patched on its class, a function where it is used.
STAGES = [
    ("deepcrashtest.video.source", "PyAVSource._next_raw", "decode"),
    ("deepcrashtest.perception.yolo_onnx", "OnnxYoloDetector.__call__", "detector"),
    ("deepcrashtest.perception.track", "BoxTracker.update_boxes", "tracker (flow, association)"),
    ("deepcrashtest.geometry.egomotion", "EgoMotionEstimator.update", "ego-motion"),
    ("deepcrashtest.perception.lanes", "ClassicalLaneDetector.update", "lanes"),
    ("deepcrashtest.perception.global_motion", "GlobalMotion.update", "global motion"),
    ("deepcrashtest.perception.annotate", "Annotator.draw", "annotate"),
    ("deepcrashtest.video.writer", "VideoWriter.write", "encode (calling thread)"),
    ("deepcrashtest.pipeline.extract", "records_table", "per-frame tables"),
    ("deepcrashtest.pipeline.geometry_pass", "estimate_camera", "camera estimation"),
    ("deepcrashtest.geometry.selfcalib", "self_calibrate", "self-calibration"),
    ("deepcrashtest.geometry.world_tracks", "raw_scenario_from_tracks", "world tracks"),
    ("deepcrashtest.pipeline.crash", "crash_for_raw", "crash"),
    ("deepcrashtest.pipeline.stage2", "processed_scenario", "stage 2"),
    ("deepcrashtest.viz.report", "build_report", "report"),
    ("deepcrashtest.video.shots", "detect_shots", "shot scan"),
]

cpu: collections.Counter[str] = collections.Counter()
calls: collections.Counter[str] = collections.Counter()
_depth = threading.local()


def _timed(fn: Any, name: str) -> Any:
    @functools.wraps(fn)
    def wrapper(*args: Any, **kwargs: Any) -> Any:
        t = time.thread_time()
        try:
            return fn(*args, **kwargs)
        finally:
            cpu[name] += time.thread_time() - t
            calls[name] += 1

    return wrapper


phases: dict[str, float] = {}


def _patch_pass(c0: float) -> None:
    """Main-thread CPU before the pass's first frame and after its last (the serial phases)."""
    from deepcrashtest.pipeline.extract import _Pass

    run = _Pass.run

    def timed(self: Any, *args: Any, **kwargs: Any) -> Any:
        phases["before"] = time.thread_time() - c0
        try:
            return run(self, *args, **kwargs)
        finally:
            phases["end"] = time.thread_time()

    _Pass.run = timed  # type: ignore[method-assign]


def _patch() -> None:
    for module, attr, name in STAGES:
        mod = importlib.import_module(module)
        owner, _, leaf = attr.rpartition(".")
        target = getattr(mod, owner) if owner else mod
        setattr(target, leaf, _timed(getattr(target, leaf), name))


def run_extract_cli(app: Any, video: str, max_frames: int | None, extra: str) -> dict[str, Any]:
    """``deepcrashtest extract VIDEO --json [--max-frames N] EXTRA`` in this process (the typer ``app``), into a
    temporary folder; returns its summary."""
    import contextlib
    import io
    import json

    with tempfile.TemporaryDirectory() as tmp:
        argv = ["extract", video, "-o", str(Path(tmp) / "out"), "--json", *extra.split()]
        if max_frames:
            argv += ["--max-frames", str(max_frames)]
        buf = io.StringIO()
        with contextlib.redirect_stdout(buf):
            try:
                app(argv, standalone_mode=False)
            except SystemExit as exc:
                if exc.code:
                    raise
        return dict(json.loads(buf.getvalue()))


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("video", nargs="?", default=str(DEFAULT))
    ap.add_argument("--max-frames", type=int, default=None)
    ap.add_argument("--native-threads", type=int, default=0, help="OpenCV + onnxruntime threads (0: their default)")
    ap.add_argument("--args", default="", help="extra extract arguments")
    args = ap.parse_args()
    t0, c0, m0 = time.perf_counter(), time.process_time(), time.thread_time()
    import cv2

    if args.native_threads:
        cv2.setNumThreads(args.native_threads)
        import onnxruntime as ort

        init = ort.InferenceSession.__init__

        def single(self: Any, path: Any, opts: Any = None, *a: Any, **k: Any) -> None:
            opts = opts or ort.SessionOptions()
            opts.intra_op_num_threads = args.native_threads
            init(self, path, opts, *a, **k)

        ort.InferenceSession.__init__ = single  # type: ignore[method-assign]
    from deepcrashtest.cli import app

    t_import = time.process_time() - c0
    m_patch = time.thread_time()
    _patch()  # imports every patched module now: its CPU is left out of the phase before the first frame
    _patch_pass(m0 + time.thread_time() - m_patch)
    summary = run_extract_cli(app, args.video, args.max_frames, args.args)
    wall, total = time.perf_counter() - t0, time.process_time() - c0
    n = summary["frames"]
    cpu["imports (cli, before the run)"] = t_import
    print(f"{args.video}: {n} frames, native threads {args.native_threads or 'default'}")
    print(f"wall {wall:.1f} s = {n / wall:.2f} fps; process CPU {total:.1f} s = {total / n * 1000:.0f} ms/frame")
    print("| stage | CPU ms/frame | share of process CPU | calls |")
    print("|---|---|---|---|")
    for name, s in sorted(cpu.items(), key=lambda kv: -kv[1]):
        print(f"| {name} | {s / n * 1000:.1f} | {100 * s / total:.0f} % | {calls.get(name, '')} |")
    other = total - sum(cpu.values())
    print(
        f"| other (native pools, codec threads, imports in threads, GIL) | {other / n * 1000:.1f} | "
        f"{100 * other / total:.0f} % | |"
    )
    print(
        f"main thread CPU before the first frame {phases['before']:.2f} s, after the last "
        f"{time.thread_time() - phases['end']:.2f} s (serial phases; forked children not counted)"
    )
    print(f"peak RSS {resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024:.0f} MB")
    sys.stdout.flush()


if __name__ == "__main__":
    main()
