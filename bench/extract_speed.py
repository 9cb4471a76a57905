"""Speed and memory of detection + tracking at 1280x720 (stage 1a of `deepcrashtest extract`).

Prints, for several --detect-every values, frames per second of decode + detect + track (end to end,
with and without writing annotated.mp4), the process CPU per frame (all threads: less dependent on
other load than fps), the per-detector-call time, and the process's peak RSS.
Run: PYTHONPATH=src python bench/extract_speed.py [VIDEO] [--frames N] [--threads 2]
Timings on a shared machine are inflated by other load; say so when you quote them.
"""

from __future__ import annotations

import argparse
import resource
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
DEFAULT = ROOT.parent / "shared" / "data" / "dashcam_udacity" / "highway_project_video.mp4"


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument(
        "video", nargs="?", default=str(DEFAULT if DEFAULT.exists() else ROOT / "examples/highway_sample.mp4")
    )
    ap.add_argument("--frames", type=int, default=100)
    ap.add_argument("--every", default="1,5,10")
    ap.add_argument("--threads", type=int, default=2)
    ap.add_argument("--skip", type=int, default=0, help="start after this many frames (decoded, not timed)")
    ap.add_argument("--detector", default="yolo26n")
    args = ap.parse_args()

    import cv2

    cv2.setNumThreads(args.threads)
    from deepcrashtest.perception.annotate import Annotator
    from deepcrashtest.perception.detect import make_detector
    from deepcrashtest.perception.track import track_video
    from deepcrashtest.video.source import open_video
    from deepcrashtest.video.writer import VideoWriter

    det = make_detector(args.detector)
    calls = {"n": 0, "s": 0.0}

    def timed(image):  # type: ignore[no-untyped-def]
        t = time.perf_counter()
        out = det(image)
        calls["n"] += 1
        calls["s"] += time.perf_counter() - t
        return out

    timed.name = det.name  # type: ignore[attr-defined]
    print(f"video {args.video}, {args.frames} frames, cv2 threads {args.threads}, detector {det.name}")
    with open_video(args.video) as src:  # decode only
        t = time.perf_counter()
        n = sum(1 for _, _ in zip(range(args.frames), src, strict=False))
        print(f"decode only: {n / (time.perf_counter() - t):.1f} fps")
    for every in [int(e) for e in args.every.split(",")]:
        for write in (False, True):
            calls.update(n=0, s=0.0)
            with tempfile.TemporaryDirectory() as tmp, open_video(args.video) as video:
                m = video.meta
                src = _skip(video, args.skip)
                t, c = time.perf_counter(), time.process_time()
                if write:
                    with VideoWriter(Path(tmp) / "a.mp4", m.fps, m.width, m.height) as w:
                        draw = Annotator(m.fps).draw
                        hook = lambda ft, w=w, d=draw: w.write(d(ft))  # noqa: E731
                        df = track_video(src, timed, every, args.frames, on_frame=hook, fps=m.fps)
                else:
                    df = track_video(src, timed, every, args.frames, fps=m.fps)
                el, cpu = time.perf_counter() - t, time.process_time() - c
            per_det = calls["s"] / max(calls["n"], 1) * 1000
            what = "detect+track+annotate+encode" if write else "detect+track"
            print(
                f"detect every {every:2d}: {what:29s} {args.frames / el:6.1f} fps, "
                f"{cpu / args.frames * 1000:4.0f} ms CPU/frame "
                f"({per_det:.0f} ms/detector call, {calls['n']} calls, {df['track_id'].nunique()} tracks)"
            )
    print(f"peak RSS {resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024:.0f} MB")


def _skip(frames, n):  # type: ignore[no-untyped-def]
    it = iter(frames)
    for _ in range(n):
        next(it)
    return it


if __name__ == "__main__":
    main()
