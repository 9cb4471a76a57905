"""Ego-motion of a 25 fps clip measured at every frame vs at most ``MAX_RATE_HZ`` (every other frame, the
rest interpolated), each under tiny perturbations (the dashboard mask 0-3 rows taller), in one run.

The estimator is chaotic at the 0.01 px level (a RANSAC sample flips, the keyframes move), so one run
of each says little; the spread over the perturbed runs is the noise to compare the two rates against.
No ground truth on this clip: KITTI odometry (10 fps, measured at every frame either way) is in
``bench/egomotion_bench.py`` (``--rate 6`` measures every other KITTI frame).
Run: PYTHONPATH=src python bench/egomotion_rate_spread.py [VIDEO] [MAX_FRAMES]
"""

from __future__ import annotations

import sys
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
    video = sys.argv[1] if len(sys.argv) > 1 else str(DEFAULT)
    limit = int(sys.argv[2]) if len(sys.argv) > 2 else 10**9
    cv2.setNumThreads(1)
    frames, times = [], []
    with av.open(video) as c:
        for f in c.decode(video=0):
            frames.append(cv2.cvtColor(f.to_ndarray(format="bgr24"), cv2.COLOR_BGR2GRAY))
            times.append(float(f.time or 0.0))
            if len(frames) >= limit:
                break
    h, w = frames[0].shape
    print(f"{video}: {len(frames)} frames; ego-motion with the default camera, CPU of one thread")
    print("| rate | dashboard rows | final yaw deg | path m | end x, y m | median speed m/s | CPU ms/frame |")
    print("|---|---|---|---|---|---|---|")
    for rate in (None, MAX_RATE_HZ):
        for rows in (60, 61, 62, 63):
            est = EgoMotionEstimator(default_camera(w, h), mask_bottom_rows=rows, max_rate_hz=rate)
            c0 = time.thread_time()
            for img, t in zip(frames, times, strict=True):
                est.update(img, t - times[0])
            r = est.result()
            cpu = (time.thread_time() - c0) / len(frames) * 1000
            print(
                f"| {rate or 'every frame'} | {rows} | {np.degrees(r.yaw[-1]):.2f} | {r.path_length():.1f} | "
                f"{r.x[-1]:.1f}, {r.y[-1]:.1f} | {np.median(r.speed):.2f} | {cpu:.1f} |",
                flush=True,
            )


if __name__ == "__main__":
    main()
