"""What each real clip's overlay gives: the GPS speed and the clock read as ``extract`` reads them (round overlay49).

For every video of the shared crash and highway data (or ``--clips``), the frames at extract's size go through
:class:`deepcrashtest.perception.overlay.OverlayReader` exactly as ``extract`` feeds it (``wants`` / ``offer`` /
``see``). Printed per clip, one JSON line: the speed read (range, readings, the line as read) and, where
``bench/labels/ego_speed_overlays.json`` labels the clip, how many readings equal the by-eye label at their frame
(within 1 km/h); the clock's rate (clock seconds per video second), its 95 % interval, its ticks, the frames per
clock second, and whether ``extract`` would warn of a slow-motion or sped-up video; the reader's CPU seconds. No
parameter is chosen here.

Run: PYTHONPATH=src python bench/overlay_clips.py [--clips ccd_000014,dad_000528] [--data DIR]
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path
from typing import Any

import numpy as np

from deepcrashtest.perception.overlay import OverlayReader
from deepcrashtest.perception.text import make_text_reader
from deepcrashtest.video.size import DEFAULT_MAX_WIDTH
from deepcrashtest.video.source import open_video

ROOT = Path(__file__).resolve().parents[1]
LABELS = ROOT / "bench" / "labels" / "ego_speed_overlays.json"
FOLDERS = ("crash_ccd", "crash_dad", "dashcam_udacity")


def read_clip(video: Path) -> dict[str, Any]:
    """The overlay of ``video`` read as extract reads it: one JSON-able row."""
    reader = make_text_reader()
    if reader is None:
        raise SystemExit("no text reader installed (make setup installs rapidocr_onnxruntime)")
    overlay = OverlayReader(reader)
    cpu = 0.0
    with open_video(video, max_width=DEFAULT_MAX_WIDTH) as source:
        fps = source.meta.fps
        for frame in source:
            t0 = time.process_time()
            if overlay.wants(float(frame.time)):
                overlay.offer(int(frame.index), float(frame.time), frame.image)
            else:
                overlay.see(int(frame.index), float(frame.time), frame.image)
            cpu += time.process_time() - t0
    row: dict[str, Any] = {"clip": video.stem, "fps": fps, "cpu_s": round(cpu, 2), "failed": overlay.failed}
    speed = overlay.speed()
    row["speed"] = None if speed is None else speed.describe()
    if speed is not None:
        row["speed_readings"] = [[int(f), float(v)] for f, v in zip(speed.frames, speed.kmh, strict=True)]
    clock = overlay.clock()
    rate = None if clock is None else clock.rate()
    row["clock"] = None if clock is None else clock.sample
    if clock is not None and rate is not None:
        gaps = np.diff(clock.ticks_t)
        row |= {
            "clock_rate": round(rate[0], 4),
            "clock_interval_95": [round(rate[1], 4), round(rate[2], 4)],
            "ticks": len(clock.ticks_t),
            "frames_per_clock_s": round(float(np.median(gaps)) * fps, 2) if len(gaps) else None,
            "warns": clock.slow_motion() is not None,
        }
    return row


def label_agreement(row: dict[str, Any], labels: dict[str, Any]) -> dict[str, Any]:
    """``row`` with how many of its speed readings equal the by-eye label at their frame (within 1 km/h)."""
    label = labels.get(row["clip"])
    if label is None or "speed_readings" not in row:
        return row
    truth = {f: r["kmh"] for r in label["readings"] for f in range(r["first_frame"], r["last_frame"] + 1)}
    checked = [(f, v) for f, v in row["speed_readings"] if f in truth]
    row["label_agrees"] = f"{sum(abs(v - truth[f]) <= 1.0 for f, v in checked)}/{len(checked)}"
    return row


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--data", type=Path, default=ROOT.parent / "shared" / "data")
    ap.add_argument("--clips", default="", help="comma-separated clip names (default: every video of the data)")
    args = ap.parse_args()
    wanted = {c for c in args.clips.split(",") if c}
    videos = [v for folder in FOLDERS for v in sorted((args.data / folder).glob("*.mp4"))]
    videos = [v for v in videos if not wanted or v.stem in wanted]
    labels = json.loads(LABELS.read_text())["clips"]
    for video in videos:
        print(json.dumps(label_agreement(read_clip(video), labels)), flush=True)


if __name__ == "__main__":
    main()
