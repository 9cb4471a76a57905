"""Ego-motion of a clip measured at every frame vs at most N frames a second (the frames between
interpolated), each under tiny perturbations (the dashboard mask 0-3 rows taller), in one run.

The estimator is chaotic at the 0.01 px level (a RANSAC sample flips, the keyframes move), so one run
of each says little; the spread over the perturbed runs is the noise to compare the rates against.
Each run's speed is also compared frame by frame with the first every-frame run (mean |difference|,
m/s): a rate whose difference stays within the every-frame runs' own is as good as every frame.
No ground truth on these clips: KITTI odometry (10 fps, measured at every frame at any cap >= 10 Hz)
is in ``bench/egomotion_bench.py`` (``--rate 6`` measures every other KITTI frame).
Run: PYTHONPATH=src python bench/egomotion_rate_spread.py [VIDEO] [--max-frames N] [--rates 0,20,10]
[--rows 60] (rate 0: every frame; default rates: every frame, ``MAX_RATE_HZ`` (20), and 10 Hz, rejected: README)
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path

import av
import cv2
import numpy as np

from deepcrashtest.geometry.camera import default_camera
from deepcrashtest.geometry.egomotion import MAX_RATE_HZ, EgoMotionEstimator

ROOT = Path(__file__).resolve().parents[1]
DEFAULT = ROOT.parent / "shared" / "data" / "dashcam_udacity" / "highway_lane_challenge.mp4"


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("video", nargs="?", default=str(DEFAULT))
    ap.add_argument("--max-frames", type=int, default=10**9)
    ap.add_argument("--rates", default=f"0,{MAX_RATE_HZ:g},10", help="Hz, comma-separated (0: every frame)")
    ap.add_argument("--rows", type=int, default=60, help="dashboard rows of the first run (+0..3 for the others)")
    args = ap.parse_args()
    cv2.setNumThreads(1)
    frames, times = [], []
    with av.open(args.video) as c:
        for f in c.decode(video=0):
            frames.append(cv2.cvtColor(f.to_ndarray(format="bgr24"), cv2.COLOR_BGR2GRAY))
            times.append(float(f.time or 0.0))
            if len(frames) >= args.max_frames:
                break
    h, w = frames[0].shape
    print(f"{args.video}: {len(frames)} frames; ego-motion with the default camera, CPU of one thread")
    print(
        "| rate | dashboard rows | final yaw deg | path m | median speed m/s | mean abs speed diff m/s | CPU ms/frame |"
    )
    print("|---|---|---|---|---|---|---|")
    ref: np.ndarray | None = None
    for rate in (float(r) for r in args.rates.split(",")):
        for rows in range(args.rows, args.rows + 4):
            est = EgoMotionEstimator(default_camera(w, h), mask_bottom_rows=rows, max_rate_hz=rate or None)
            c0 = time.thread_time()
            for img, t in zip(frames, times, strict=True):
                est.update(img, t - times[0])
            r = est.result()
            cpu = (time.thread_time() - c0) / len(frames) * 1000
            ref = r.speed if ref is None else ref
            diff = float(np.mean(np.abs(r.speed - ref)))
            print(
                f"| {f'{rate:g} Hz' if rate else 'every frame'} | {rows} | {np.degrees(r.yaw[-1]):.2f} | "
                f"{r.path_length():.1f} | {np.median(r.speed):.2f} | {diff:.3f} | {cpu:.1f} |",
                flush=True,
            )


if __name__ == "__main__":
    main()
