"""Bonnet/dashboard detection against the by-eye labels in ``bench/labels/bonnet_rows.json``.

For each labelled clip the detector gets what the geometry stage gives it (``estimate_camera``: the
first 2 s of frames, every ``len // 9``-th), and prints the detected rows, the top row at the image
centre and at 10 % / 90 % of the width against the label, and the error (detected top - labelled
top, px; a missing bonnet counts as the frame's bottom row). Tuning split: clips at even positions
of the sorted list tune, odd positions report (``--split tune|report|all``). The detector's parameters
(``edge_min``, ``still_ratio``, ``below_pct``, ``min_coverage``) were chosen on the tune split.

    python bench/bonnet_bench.py [--split report] [--render OUT_DIR]
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import cv2
import numpy as np

from deepcrashtest.geometry.camera import bonnet_contour, detect_dashboard_rows

DATA = Path(__file__).resolve().parents[1] / ".." / "shared" / "data"
LABELS = Path(__file__).resolve().parent / "labels" / "bonnet_rows.json"
FOLDERS = ("crash_ccd", "crash_dad", "dashcam_udacity")


def calib_frames(video: Path, seconds: float = 2.0) -> list[np.ndarray]:
    """The geometry stage's calibration frames: the first ``seconds`` of video, every len//9-th."""
    cap = cv2.VideoCapture(str(video))
    fps = float(cap.get(cv2.CAP_PROP_FPS)) or 10.0
    images = []
    while len(images) < int(seconds * fps) + 1:
        ok, img = cap.read()
        if not ok:
            break
        images.append(img)
    cap.release()
    return images[:: max(1, len(images) // 9)]


def top(label: int | str, height: int) -> float:
    return float(height) if label == "none" else float(label)


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--split", choices=("tune", "report", "all"), default="all")
    ap.add_argument("--render", type=Path, default=None, help="write the first frame with the contour here")
    args = ap.parse_args()
    labels = {k: v for k, v in json.loads(LABELS.read_text()).items() if not k.startswith("_")}
    names = sorted(labels)
    pick = {"tune": names[0::2], "report": names[1::2], "all": names}[args.split]
    print(f"{'clip':28s} rows  centre det/lab   left det/lab   right det/lab   |err| c/l/r px")
    errs = []
    over = 0  # clips where the centre is masked > 20 px above the labelled bonnet (road masked)
    for name in pick:
        video = next(p for f in FOLDERS if (p := DATA / f / f"{name}.mp4").exists())
        frames = calib_frames(video)
        h, w = frames[0].shape[:2]
        rows = detect_dashboard_rows(frames)
        c = bonnet_contour(frames)
        det_c = float(h - rows)
        row = [det_c]
        for frac in (0.1, 0.9):
            v = c.row_at(frac * w) if c is not None and rows > 0 else float("nan")
            row.append(float(h) if not np.isfinite(v) else v)
        lab = [top(labels[name][k], h) for k in ("centre", "left", "right")]
        err = [abs(d - t) for d, t in zip(row, lab, strict=True)]
        errs.append(err)
        over += int(lab[0] - row[0] > 20)
        print(
            f"{name:28s} {rows:4d}  {row[0]:6.0f}/{lab[0]:4.0f}   {row[1]:6.0f}/{lab[1]:4.0f}   "
            f"{row[2]:6.0f}/{lab[2]:4.0f}    {err[0]:4.0f} {err[1]:4.0f} {err[2]:4.0f}"
        )
        if args.render is not None and c is not None:
            img = frames[0].copy()
            for k, t in enumerate(c.top_px):
                if np.isfinite(t):
                    u0, u1 = int(c.bin_edges_px[k]), int(c.bin_edges_px[k + 1])
                    cv2.line(img, (u0, int(t)), (u1, int(t)), (0, 0, 255), 3)
            cv2.line(img, (0, h - rows), (w, h - rows), (0, 255, 0), 2)
            args.render.mkdir(parents=True, exist_ok=True)
            cv2.imwrite(str(args.render / f"{name}.jpg"), cv2.resize(img, None, fx=0.5, fy=0.5))
    e = np.asarray(errs)
    print(
        f"{args.split}: {len(pick)} clips, centre |err| median {np.median(e[:, 0]):.0f} px, "
        f"max {e[:, 0].max():.0f} px; clips with centre |err| > 30 px: {int((e[:, 0] > 30).sum())}, "
        f"road masked > 20 px: {over}"
    )


if __name__ == "__main__":
    main()
