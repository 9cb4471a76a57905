"""Where a detector call spends its time: onnxruntime's own per-operator profile of the default detector.

Builds the detector as ``extract`` does (``make_detector``: the fine pass and the coarse pass, the threads
``extract`` gives it), swaps in a session of the same model with onnxruntime's profiler on (same session
options otherwise), runs it on every ``--step``-th frame of a video (``--frames`` of them, after two warm-up
calls) and prints the calling thread's CPU per frame and the operators' share of the kernel time (Conv,
the activations, concatenations, the NCHWc layout reorders, ...). The profile's JSON goes to a temporary
folder. The per-frame CPU includes the profiler's own overhead (a few per cent); the shares include the
two warm-up calls.

Run: PYTHONPATH=src python bench/detector_ops.py [VIDEO] [--spec yolo26n] [--frames 8] [--step 25]
"""

from __future__ import annotations

import argparse
import collections
import json
import tempfile
import time
from pathlib import Path
from typing import Any

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
DEFAULT = ROOT.parent / "shared" / "data" / "dashcam_udacity" / "highway_lane_challenge.mp4"


def frames_of(video: str, count: int, step: int) -> list[np.ndarray]:
    """Every ``step``-th decoded frame (BGR), ``count`` of them at most."""
    from deepcrashtest.video.source import open_video

    out: list[np.ndarray] = []
    with open_video(Path(video)) as source:
        for k, frame in enumerate(source):
            if k % step == 0:
                out.append(frame.image)
            if len(out) >= count:
                break
    return out


def profiled(det: Any, folder: str) -> Any:
    """``det`` (an ``OnnxYoloDetector``) with a profiling session of the same model and options."""
    import onnxruntime as ort

    session = det.session
    opts = ort.SessionOptions()
    opts.intra_op_num_threads = session.get_session_options().intra_op_num_threads
    opts.add_session_config_entry("session.intra_op.allow_spinning", "0")
    opts.enable_profiling = True
    opts.profile_file_prefix = str(Path(folder) / "ort")
    det.session = ort.InferenceSession(session._model_path, opts, providers=["CPUExecutionProvider"])
    return det


def operator_times(profile: Path) -> collections.Counter[str]:
    """Kernel microseconds per operator type from onnxruntime's profile JSON."""
    times: collections.Counter[str] = collections.Counter()
    for event in json.loads(profile.read_text()):
        if event.get("cat") == "Node" and event.get("name", "").endswith("_kernel_time"):
            times[event["args"].get("op_name", "?")] += int(event["dur"])
    return times


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("video", nargs="?", default=str(DEFAULT))
    ap.add_argument("--spec", default="yolo26n", help="detector spec (make_detector)")
    ap.add_argument("--frames", type=int, default=8)
    ap.add_argument("--step", type=int, default=25)
    args = ap.parse_args()
    from deepcrashtest.perception.detect import make_detector

    images = frames_of(args.video, args.frames, args.step)
    with tempfile.TemporaryDirectory() as tmp:
        det = profiled(make_detector(args.spec), tmp)
        for image in images[:2]:
            det(image)
        t = time.thread_time()
        for image in images:
            det(image)
        cpu_ms = (time.thread_time() - t) / len(images) * 1000
        times = operator_times(Path(det.session.end_profiling()))
    total = sum(times.values()) or 1
    print(f"{args.video}: {len(images)} frames (+2 warm-up), {args.spec}: {cpu_ms:.0f} ms CPU a frame (profiled)")
    print("| operator | share of kernel time |")
    print("|---|---|")
    for op, us in times.most_common(12):
        print(f"| {op} | {us / total * 100:.1f} % |")


if __name__ == "__main__":
    main()
