"""How much tracking accuracy a longer gap between detector calls costs: the tracker's boxes against the
detector's own boxes on the frames it skipped.

The detector runs on every frame once; the tracker then sees those detections only every N-th frame
(the schedule of ``extract --detect-every N``) and carries its boxes by optical flow between. On each
skipped frame, the road users the detector finds there (score >= 0.5, at least ``--min-height`` px tall)
are matched to the tracker's confirmed boxes (IoU >= 0.5, Hungarian): recall = matched / found, and mean
IoU of the matches. No labels exist at 25 fps; the per-frame detector is the reference (its own misses
are not counted against the tracker), so this measures what skipping costs, not absolute accuracy.

``--stable-iou 0.5 [--stable-score 0.5]`` adds a need-driven schedule (every 5th frame, a call skipped while the
last two found the same road users: :func:`stable_schedule`), replayed from the same detections.

Run: PYTHONPATH=src python bench/detect_gap.py [VIDEO ...] [--frames 250] [--every 2,3,5,6,8] [--stable-iou 0.5]
"""

from __future__ import annotations

import argparse
import itertools
import os
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
UDACITY = ROOT.parent / "shared" / "data" / "dashcam_udacity"
DEFAULT = [str(UDACITY / "highway_lane_challenge.mp4"), str(UDACITY / "highway_project_video.mp4")]


def main() -> None:
    from scipy.optimize import linear_sum_assignment

    from deepcrashtest.perception.boxes import iou_matrix
    from deepcrashtest.perception.detect import DEFAULT_DETECTOR, make_detector
    from deepcrashtest.perception.roadusers import road_users
    from deepcrashtest.perception.track import track_detected
    from deepcrashtest.video.source import open_video

    ap = argparse.ArgumentParser()
    ap.add_argument("videos", nargs="*", default=DEFAULT)
    ap.add_argument("--frames", type=int, default=250)
    ap.add_argument("--every", default="1,2,3,5,6,8,10")
    ap.add_argument("--min-height", type=float, default=20.0)
    ap.add_argument("--detector", default=DEFAULT_DETECTOR)
    ap.add_argument(
        "--stable-iou",
        default="",
        help="also a need-driven schedule per value (e.g. 0.5,0.7): every 5th frame, but a call is skipped when the "
        "last two calls found the same road users (one to one at IoU >= the value; never two skips in a row)",
    )
    ap.add_argument("--stable-score", default="0.5", help="least score of a road user compared (e.g. 0.3,0.5)")
    args = ap.parse_args()
    det = make_detector(args.detector)
    print(f"detector {det.name}; load average {os.getloadavg()[0]:.1f}")
    print("| video | detect every | gap s | reference road users | recall IoU>=0.5 | mean IoU | detector calls |")
    print("|---|---|---|---|---|---|---|")
    for video in args.videos:
        t0 = time.process_time()
        with open_video(video) as src:
            fps = src.meta.fps
            frames = list(itertools.islice(src, args.frames))
        dets = [det(f.image) for f in frames]
        cpu = (time.process_time() - t0) / len(frames) * 1000
        schedules = [(str(e), int(e), set(range(0, len(frames), int(e)))) for e in args.every.split(",")]
        if args.stable_iou:  # need-driven: every 5th frame, a call skipped while the last two calls agree
            base = 5  # extract's schedule at 25 fps
            for tau, low in itertools.product(
                map(float, args.stable_iou.split(",")), map(float, args.stable_score.split(","))
            ):
                calls = stable_schedule(dets, base, tau, low)
                schedules.append((f"{base}, skip if stable (IoU {tau:g}, score {low:g})", base, calls))
        for name, every, calls in schedules:
            pairs = [(f, d if k in calls else None) for k, (f, d) in enumerate(zip(frames, dets, strict=True))]
            found = matched = 0
            ious: list[float] = []
            for k, ft in enumerate(track_detected(pairs, fps, every)):
                if k in calls and len(calls) < len(frames):
                    continue  # detection frames: the tracker took these boxes
                ref = road_users(dets[k])
                keep = (ref.scores >= 0.5) & ((ref.boxes[:, 3] - ref.boxes[:, 1]) >= args.min_height)
                ref_boxes = ref.boxes[keep]
                found += len(ref_boxes)
                if not len(ref_boxes) or not ft.tracks:
                    continue
                iou = iou_matrix(np.array([b.box for b in ft.tracks], float), ref_boxes.astype(float))
                rows, cols = linear_sum_assignment(-iou)
                good = iou[rows, cols] >= 0.5
                matched += int(good.sum())
                ious += iou[rows, cols][good].tolist()
            print(
                f"| {Path(video).name} | {name} | {every / fps:.2f} | {found} | {matched / max(found, 1):.3f} | "
                f"{np.mean(ious) if ious else float('nan'):.3f} | {len(calls)} |"
            )
        print(f"({Path(video).name}: {len(frames)} frames at {fps:g} fps, detector {cpu:.0f} ms CPU a frame)")


def stable_schedule(dets: list, every: int, min_iou: float, min_score: float) -> set[int]:
    """Frames a need-driven schedule computable ahead of the tracker (from the detector's own boxes) calls the
    detector on: every ``every``-th frame, except that a call is skipped when the last two calls made found the
    same road users (score >= ``min_score``, riders joined: as many, matched one to one at IoU >= ``min_iou``;
    nothing appeared, left or moved fast), and never two calls in a row. Measured and not taken (README,
    Performance, eighth round); ``extract`` with it was commit 9d0d5da of branch extractfps6."""
    from scipy.optimize import linear_sum_assignment

    from deepcrashtest.perception.boxes import iou_matrix
    from deepcrashtest.perception.roadusers import road_users

    def boxes(k: int) -> np.ndarray:
        d = road_users(dets[k])
        return np.asarray(d.boxes[d.scores >= min_score], float).reshape(-1, 4)

    def same(a: np.ndarray, b: np.ndarray) -> bool:
        if len(a) != len(b):
            return False
        if not len(a):
            return True
        iou = iou_matrix(a, b)
        rows, cols = linear_sum_assignment(-iou)
        return bool((iou[rows, cols] >= min_iou).all())

    calls: list[int] = []
    skipped_last = False
    for k in range(0, len(dets), every):
        if len(calls) >= 2 and not skipped_last and same(boxes(calls[-2]), boxes(calls[-1])):
            skipped_last = True
            continue
        calls.append(k)
        skipped_last = False
    return set(calls)


if __name__ == "__main__":
    main()
