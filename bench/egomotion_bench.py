"""Ego-motion cost and accuracy in one run: ms per frame and the KITTI odometry errors.

For each shared KITTI odometry sequence, the estimator runs over frames already in memory (decoding
is not timed) and prints CPU ms/frame, wall ms/frame, median speed error, distance error and yaw
drift. The estimator runs at its default width (960 px); with ``--compare`` also at full resolution
(``max_width=1280``) in the same process, so the speed-up is a ratio measured under the same load.
``--rate HZ`` (repeatable) adds runs whose estimator measures at most HZ frames a second (``max_rate_hz``;
5 on these 10 fps sequences = every other frame measured, the others interpolated, errors still over every
frame): what ``MAX_RATE_HZ`` does to a 25 fps video (measured at 12.5 fps), with twice its motion per pair.
``--set NAME=X`` (repeatable): an :class:`EgoMotionEstimator` option for every run (to check an option on KITTI).
Run: PYTHONPATH=src python bench/egomotion_bench.py [--data DIR] [--compare] [--threads 2] [--rate 6] [--set NAME=X]
Timings on a shared machine are inflated by other load; say so when you quote them.
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
DATA = ROOT.parent / "shared" / "data" / "kitti_odometry"


def run(
    folder: Path, max_width: int, rate: float | None = None, options: dict[str, float] | None = None
) -> tuple[float, float, dict[str, object]]:
    import cv2

    from deepcrashtest.datasets.kitti.files import KITTI_CAMERA_HEIGHT_M, read_poses
    from deepcrashtest.eval.egomotion import egomotion_errors, frame_times, read_odometry_calib
    from deepcrashtest.geometry.egomotion import EgoMotionEstimator
    from deepcrashtest.scenario import Camera

    images = [cv2.imread(str(p), cv2.IMREAD_GRAYSCALE) for p in sorted((folder / "image_0").glob("*.png"))]
    poses = read_poses(folder / "poses.txt")[: len(images)]
    K = read_odometry_calib(folder)
    cam = Camera(fx=K[0, 0], fy=K[1, 1], cx=K[0, 2], cy=K[1, 2], height_m=KITTI_CAMERA_HEIGHT_M)
    times = frame_times(folder, len(images))
    opts: dict[str, float] = dict(options or {})
    if rate is not None:
        opts["max_rate_hz"] = rate
    est = EgoMotionEstimator(cam, max_width=max_width, **opts)  # type: ignore[arg-type]
    c0, w0 = time.process_time(), time.perf_counter()
    for img, t in zip(images, times, strict=True):
        est.update(img, float(t))
    cpu = (time.process_time() - c0) / len(images) * 1000
    wall = (time.perf_counter() - w0) / len(images) * 1000
    return cpu, wall, egomotion_errors(est.result(), poses, times)


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--data", default=str(DATA))
    ap.add_argument("--compare", action="store_true", help="also run at full resolution (max_width=1280)")
    ap.add_argument("--threads", type=int, default=2)
    ap.add_argument("--rate", type=float, action="append", default=[], help="also measure at most HZ frames/s")
    ap.add_argument("--set", action="append", default=[], help="estimator option NAME=NUMBER (repeatable)")
    args = ap.parse_args()
    options = {k: float(v) for k, v in (o.split("=", 1) for o in args.set)}
    import cv2

    cv2.setNumThreads(args.threads)
    folders = sorted(p for p in Path(args.data).iterdir() if (p / "poses.txt").exists())
    widths = [960, 1280] if args.compare else [960]
    print(
        f"{'sequence':26} {'width':>5} {'rate':>5} {'cpu ms/f':>8} {'wall ms/f':>9} {'speed err %':>11} "
        f"{'dist err %':>10} {'yaw deg/100m':>12}"
    )
    runs = [(w, None) for w in widths] + [(widths[0], rate) for rate in args.rate]
    for folder in folders:
        for w, rate in runs:
            cpu, wall, r = run(folder, w, rate, options)
            print(
                f"{folder.name:26} {w:5d} {rate or 'all':>5} {cpu:8.1f} {wall:9.1f} "
                f"{r['speed_error_median_pct']!s:>11} "
                f"{r['distance_error_pct']!s:>10} {r['yaw_drift_deg_per_100m']!s:>12}"
            )


if __name__ == "__main__":
    main()
