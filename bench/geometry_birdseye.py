"""Bird's-eye evidence: ego path + lanes extracted from a dashcam video by the geometry stage.

Usage: python bench/geometry_birdseye.py VIDEO OUT.png [--step N] [--max-frames N] [--chessboard DIR]

Frames are read with OpenCV (every ``step``-th frame, at most ``max-frames``), no vehicle tracks
are given (ego path and lanes only), and the figures (path length, mean speed, lanes found,
warnings, seconds per processed frame) are printed as one JSON line. Timings on a shared
machine are contaminated by other jobs.
"""

from __future__ import annotations

import argparse
import json
import time
from dataclasses import dataclass
from pathlib import Path

import cv2
import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt
import numpy as np
import pandas as pd

from deepcrashtest.geometry.camera import calibrate_chessboard, default_camera, scale_camera
from deepcrashtest.pipeline.geometry_pass import extract_geometry


@dataclass
class Frame:
    index: int
    time: float
    image: np.ndarray


def frames(path: Path, step: int, max_frames: int):
    cap = cv2.VideoCapture(str(path))
    fps = cap.get(cv2.CAP_PROP_FPS) or 25.0
    i = n = 0
    while n < max_frames:
        ok, img = cap.read()
        if not ok:
            break
        if i % step == 0:
            yield Frame(i, i / fps, img), pd.DataFrame()
            n += 1
        i += 1


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("video", type=Path)
    ap.add_argument("out", type=Path)
    ap.add_argument("--step", type=int, default=1)
    ap.add_argument("--max-frames", type=int, default=10_000)
    ap.add_argument("--chessboard", type=Path, default=None)
    a = ap.parse_args()
    cap = cv2.VideoCapture(str(a.video))
    w, h = int(cap.get(cv2.CAP_PROP_FRAME_WIDTH)), int(cap.get(cv2.CAP_PROP_FRAME_HEIGHT))
    fps, count = cap.get(cv2.CAP_PROP_FPS), int(cap.get(cv2.CAP_PROP_FRAME_COUNT))
    cap.release()
    if a.chessboard:
        cam, _, _ = calibrate_chessboard(a.chessboard)
        cam = scale_camera(cam, w / 1280.0)
    else:
        cam = default_camera(w, h)
    meta = {"path": str(a.video), "fps": fps, "frame_count": count, "width": w, "height": h}
    t0 = time.perf_counter()
    res = extract_geometry(frames(a.video, a.step, a.max_frames), meta, cam, max_width=640)
    elapsed = time.perf_counter() - t0
    sc, ego = res.scenario, res.scenario.ego.trajectory
    fig, ax = plt.subplots(figsize=(10, 5))
    x, y = np.asarray(ego.x), np.asarray(ego.y)
    ax.plot(x, y, "k-", lw=2, label="ego path (extracted)")
    if res.lanes is not None and res.lanes.both_found.any():
        tl = res.lanes
        ok = tl.both_found
        t_ego = np.asarray(ego.t)
        lane_t = tl.t - tl.t[0]
        centre_off = np.interp(t_ego, lane_t[ok], tl.lateral_offset[ok])  # ego left of lane centre
        half = 0.5 * np.interp(t_ego, lane_t[ok], tl.lane_width[ok])
        yaw = np.asarray(ego.yaw)
        nx, ny = -np.sin(yaw), np.cos(yaw)
        seen = np.interp(t_ego, lane_t, ok.astype(float)) > 0.5  # only where both boundaries were found
        for side in (1, -1):
            d = -centre_off + side * half
            ax.plot((x + d * nx)[seen], (y + d * ny)[seen], "g.", ms=3)
        ax.plot([], [], "g.", label="ego-lane boundaries where detected (lane detector)")
    ax.set_aspect("equal", adjustable="datalim")
    ax.set_xlabel("x forward (m)")
    ax.set_ylabel("y left (m)")
    ax.set_title(
        f"{a.video.name}: {len(ego.t)} frames (every {a.step}), horizon: {res.horizon_source}, "
        f"dashboard rows: {res.dashboard_rows}"
    )
    ax.legend(loc="best")
    fig.tight_layout()
    fig.savefig(a.out, dpi=110)
    speed = np.asarray(ego.speed)
    print(json.dumps({
        "video": a.video.name, "frames_processed": len(ego.t), "step": a.step,
        "path_length_m": round(float(np.sum(np.hypot(np.diff(x), np.diff(y)))), 1),
        "mean_speed_kmh": round(float(speed.mean() * 3.6), 1),
        "heading_change_deg": round(float(np.degrees(ego.yaw[-1] - ego.yaw[0])), 1),
        "lanes_both_found": None if res.lanes is None else round(float(res.lanes.both_found.mean()), 3),
        "lane_width_m": None if res.lanes is None else res.lanes.median_lane_width(),
        "dashboard_rows": res.dashboard_rows, "horizon_source": res.horizon_source,
        "warnings": sc.warnings, "s_per_frame": round(elapsed / max(1, len(ego.t)), 3),
    }))  # fmt: skip


if __name__ == "__main__":
    main()
