"""Detectors compared on the real data, all in one run (so the speed ratios share the machine's load).

For each detector spec (default: YOLO26n at the exported inputs and SSD-MobileNet with and without its
horizon tiles) prints:

* KITTI, the 6 labelled tracking frames: car recall / precision at IoU 0.5 (moderate cars, the project's
  own matching, ``datasets/kitti/detection_eval.py``) and ms per frame;
* KITTI raw highway queue (78 frames, no labels): vehicles found per frame;
* the DAD crash clips (every ``--step``-th frame): pedestrians and two-wheelers (+ cars) found per frame.

Frames are run detector after detector on the same image (interleaved), so a load spike hits all alike.
Run: PYTHONPATH=src python bench/detector_compare.py [--specs yolo26n,ssd,ssd:tiles=0] [--step 10]
The figures without labels are counts, not accuracy: look at the frames (``--png DIR``) before judging.
"""

from __future__ import annotations

import argparse
import os
import time
from pathlib import Path

import cv2
import numpy as np

ROOT = Path(__file__).resolve().parents[1]
DATA = ROOT.parent / "shared" / "data"
TWO_WHEELERS = ["motorcycle", "bicycle"]
VEHICLES = ["car", "truck", "bus"]


def kitti_frames() -> list[tuple[np.ndarray, object]]:
    from deepcrashtest.datasets.kitti.files import read_labels

    root = DATA / "kitti_tracking"
    out = []
    for seq in ("0001", "0016"):
        labels = read_labels(root / "label_02" / f"{seq}.txt")
        for f in sorted((root / "image_02" / seq).glob("*.png")):
            out.append((cv2.imread(str(f)), labels[labels["frame"] == int(f.stem)]))
    return out


def video_frames(step: int) -> list[np.ndarray]:
    from deepcrashtest.video.source import open_video

    out = []
    for clip in sorted((DATA / "crash_dad").glob("*.mp4")):
        with open_video(clip) as src:
            out += [f.image for f in src if f.index % step == step - 1]
    return out


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--specs", default="yolo26n,yolo26n:size=960,yolo26n:size=1280,ssd:tiles=0,ssd")
    ap.add_argument("--step", type=int, default=10, help="every N-th frame of the DAD clips")
    ap.add_argument("--queue-step", type=int, default=1, help="every N-th frame of the KITTI queue")
    ap.add_argument("--png", type=Path, default=None, help="write DAD frames with each detector's boxes here")
    args = ap.parse_args()
    cv2.setNumThreads(2)
    from deepcrashtest.datasets.kitti.detection_eval import MatchCounts, match_frame, split_kitti_cars
    from deepcrashtest.perception.detect import make_detector

    specs = args.specs.split(",")
    dets = [make_detector(s) for s in specs]
    print(f"load (uptime): {os.getloadavg()[0]:.1f} {os.getloadavg()[1]:.1f} on {os.cpu_count()} cores")
    secs = {s: [0.0, 0.0, 0.0] for s in specs}
    counts = {s: MatchCounts() for s in specs}
    for image, labels in kitti_frames():
        for s, d in zip(specs, dets, strict=True):
            t = time.perf_counter()
            found = d(image)
            secs[s][0] += time.perf_counter() - t
            cars = found.subset(np.flatnonzero(np.isin(found.categories, VEHICLES)))
            counts[s] += match_frame(cars.boxes, *split_kitti_cars(labels))
    queue = sorted((DATA / "kitti_raw_highway_queue" / "image_02" / "data").glob("*.png"))[:: args.queue_step]
    found_q = {s: 0 for s in specs}
    for f in queue:
        image = cv2.imread(str(f))
        for s, d in zip(specs, dets, strict=True):
            t = time.perf_counter()
            found = d(image)
            secs[s][1] += time.perf_counter() - t
            found_q[s] += int(np.isin(found.categories, VEHICLES).sum())
    dad = video_frames(args.step)
    found_d = {s: {"pedestrian": 0, "two-wheeler": 0, "vehicle": 0} for s in specs}
    for k, image in enumerate(dad):
        for s, d in zip(specs, dets, strict=True):
            t = time.perf_counter()
            found = d(image)
            secs[s][2] += time.perf_counter() - t
            found_d[s]["pedestrian"] += int((found.categories == "pedestrian").sum())
            found_d[s]["two-wheeler"] += int(np.isin(found.categories, TWO_WHEELERS).sum())
            found_d[s]["vehicle"] += int(np.isin(found.categories, VEHICLES).sum())
            if args.png is not None:
                _draw(args.png / f"dad{k:03d}_{s.replace(':', '_').replace('=', '')}.jpg", image, found)
    print(f"{len(queue)} KITTI queue frames, {len(dad)} DAD frames (every {args.step}th)")
    head = "| detector | KITTI car recall | precision | ms/frame KITTI | ms/frame 1280x720 | queue vehicles/frame |"
    print(head + " DAD pedestrians/frame | DAD two-wheelers/frame | DAD vehicles/frame |")
    print("|---" * 9 + "|")
    for s in specs:
        c, n = counts[s], max(len(dad), 1)
        print(
            f"| {s} | {c.recall:.2f} ({c.tp}/{c.tp + c.fn}) | {c.precision:.2f} | {secs[s][0] / 6 * 1000:.0f} "
            f"| {secs[s][2] / n * 1000:.0f} | {found_q[s] / len(queue):.1f} | {found_d[s]['pedestrian'] / n:.2f} "
            f"| {found_d[s]['two-wheeler'] / n:.2f} | {found_d[s]['vehicle'] / n:.2f} |"
        )
    base = specs[-1]
    for s in specs[:-1]:
        print(f"speed ratio {s} / {base} on 1280x720: {secs[base][2] / max(secs[s][2], 1e-9):.1f}x faster")


def _draw(path: Path, image: np.ndarray, found) -> None:  # type: ignore[no-untyped-def]
    path.parent.mkdir(parents=True, exist_ok=True)
    img = image.copy()
    for b, c, p in zip(found.boxes.astype(int), found.categories, found.scores, strict=True):
        cv2.rectangle(img, (b[0], b[1]), (b[2], b[3]), (0, 255, 0), 2)
        cv2.putText(img, f"{c} {p:.2f}", (b[0], b[1] - 3), cv2.FONT_HERSHEY_SIMPLEX, 0.5, (0, 255, 0), 1)
    cv2.imwrite(str(path), img)


if __name__ == "__main__":
    main()
