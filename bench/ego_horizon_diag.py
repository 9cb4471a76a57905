"""Which horizon extract's ego-motion runs on, against the one its localisation uses (diagnosis, issue #14 item 5).

``extract`` picks the ego-motion and lanes horizon from the first 2 s of pixels
(:func:`deepcrashtest.pipeline.geometry_pass.estimate_camera`: lane vanishing point, else the flow's focus of
expansion), while localisation uses the self-calibrated horizon of the whole clip's vehicle boxes
(:func:`deepcrashtest.geometry.selfcalib.self_calibrate`). Part 1 prints, per clip, the pixel horizon, the
horizon of the same first 2 s of boxes (:func:`~deepcrashtest.geometry.selfcalib.horizon_from_few_boxes`, prior
camera height) and the whole clip's self-calibrated one (from a cached extract's ``scenario_raw.json``).
Part 2 runs :class:`~deepcrashtest.geometry.egomotion.EgoMotionEstimator` on ccd_000014 (GPS overlay 57-59 km/h)
with each horizon, with the burned-in overlay rows masked (40 bottom rows) or with a persistent-edge mask
(:func:`persistent_edges`: Canny edges present in >= 90 % of the first 2 s, dilated 9 px; the variant tried in
extract and dropped, README): mean speed, frames read as stopped, frames with a road-scale measurement and their
readings.

Run: PYTHONPATH=src python bench/ego_horizon_diag.py --work DIR [--clips a,b] [--skip-survey]
``DIR/<clip>/`` holds an earlier extract (``tracks.csv``, ``scenario_raw.json``; e.g. a copy of a
``bench/fidelity_crashes.py --work`` folder).
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path
from typing import Any

import numpy as np

ROOT = Path(__file__).resolve().parents[1]


def first_frames(video: str, n: int) -> list[np.ndarray]:
    import cv2

    cap = cv2.VideoCapture(video)
    images = []
    while len(images) < n:
        ok, img = cap.read()
        if not ok:
            break
        images.append(img)
    cap.release()
    return images


def persistent_edges(images: list[np.ndarray], share: float = 0.9) -> np.ndarray:
    """Full-frame mask of the edges present in ``share`` of the frames (burned-in text, borders), dilated."""
    import cv2

    grey = [cv2.cvtColor(im, cv2.COLOR_BGR2GRAY) for im in images[:: max(1, len(images) // 10)]]
    still = np.mean([cv2.Canny(g, 60, 150) > 0 for g in grey], axis=0) >= share
    return cv2.dilate(still.astype(np.uint8), np.ones((9, 9), np.uint8)) > 0


def survey(work: Path, wanted: set[str]) -> None:
    import pandas as pd

    from deepcrashtest.geometry.camera import default_camera
    from deepcrashtest.geometry.selfcalib import horizon_from_few_boxes
    from deepcrashtest.pipeline.geometry_pass import estimate_camera

    print(f"{'clip':22} {'pixel horizon (source)':>28} {'first-2s boxes (n)':>20} {'self-calibrated':>16}")
    for d in sorted(p for p in work.iterdir() if (p / "scenario_raw.json").exists()):
        if wanted and d.name not in wanted:
            continue
        raw = json.loads((d / "scenario_raw.json").read_text())
        fps = float(raw["source"]["fps"])
        images = first_frames(raw["source"]["path"], int(2 * fps) + 1)
        h, w = images[0].shape[:2]
        cam, _, src = estimate_camera(images, default_camera(w, h))
        tracks = pd.read_csv(d / "tracks.csv")
        few = horizon_from_few_boxes(tracks[tracks.frame < len(images)], (w, h), cam.height_m)
        sc = raw["provenance"]["parameters"].get("self_calibration", {})
        boxes = f"{few[0]:.0f} +- {few[1]:.0f} ({few[2]})" if few else "-"
        selfcal = f"{sc.get('horizon_v', float('nan')):.0f} +- {sc.get('horizon_sigma_px') or float('nan'):.0f}"
        print(f"{d.name:22} {f'{cam.horizon_v():.0f} ({src})':>28} {boxes:>20} {selfcal:>16}", flush=True)


def ego_variants(work: Path, data: Path) -> None:
    import pandas as pd

    from deepcrashtest.geometry.camera import default_camera, with_horizon
    from deepcrashtest.geometry.egomotion import EgoMotionEstimator
    from deepcrashtest.geometry.selfcalib import horizon_from_few_boxes
    from deepcrashtest.pipeline.geometry_pass import estimate_camera

    labels = json.loads((ROOT / "bench" / "labels" / "ego_speed_overlays.json").read_text())["clips"]["ccd_000014"]
    fps = float(labels["fps"])
    last = max(r["last_frame"] for r in labels["readings"])
    images = first_frames(str(data / labels["video"]), last + 1)
    h, w = images[0].shape[:2]
    tracks = pd.read_csv(work / "ccd_000014" / "tracks.csv")
    cam0 = default_camera(w, h)
    pixel, rows, src = estimate_camera(images[: int(2 * fps) + 1], cam0)
    few = horizon_from_few_boxes(tracks[tracks.frame <= int(2 * fps)], (w, h), cam0.height_m)
    assert few is not None
    overlay = np.mean([r["kmh"] for r in labels["readings"]])
    print(f"\nccd_000014, overlay mean {overlay:.1f} km/h, default focal {cam0.fy:.0f} px, height {cam0.height_m} m")
    print(f"{'horizon':28} {'masked rows':>11} {'mean km/h':>9} {'stopped':>8} {'scaled':>7}  road-scale readings km/h")
    boxes_cam = with_horizon(cam0, few[0], "self_calibration")
    for name, cam in ((f"{src} {pixel.horizon_v():.0f}", pixel), (f"boxes {few[0]:.0f}", boxes_cam)):
        for mask in (rows, 40, -1):  # -1: the detected rows and the persistent-edge mask
            est = EgoMotionEstimator(cam, mask_bottom_rows=rows if mask < 0 else mask)
            if mask < 0:
                est._static_mask = _with_still(est._static_mask, persistent_edges(images[: int(2 * fps) + 1]))
            raw = []
            for i, img in enumerate(images):
                b = tracks[tracks.frame == i][["x1", "y1", "x2", "y2"]].to_numpy(float)
                s = est.update(img, i / fps, b)
                raw.append(s.raw_speed)
            speed = est.result().speed[1:] * 3.6
            got = np.array([r for r in raw if r is not None]) * 3.6
            label = str(mask) if mask >= 0 else f"{rows}+edges"
            print(
                f"{name:28} {label:>11} {np.mean(speed):9.1f} {int(np.sum(speed < 1.08)):>4d}/{len(speed):<3d} "
                f"{len(got):>7d}  {np.array2string(np.round(got), separator=' ')}",
                flush=True,
            )


def _with_still(static_mask: Any, still: np.ndarray) -> Any:
    """The estimator's mask function with ``still`` (full-frame px) removed as well."""
    import cv2

    def masked(shape: tuple[int, int], boxes: np.ndarray) -> np.ndarray:
        m = static_mask(shape, boxes)
        m[cv2.resize(still.astype(np.uint8), (shape[1], shape[0]), interpolation=cv2.INTER_NEAREST) > 0] = 0
        return m

    return masked


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--work", required=True, help="folder with <clip>/tracks.csv and scenario_raw.json")
    ap.add_argument("--data", default=str(ROOT.parent / "shared" / "data"))
    ap.add_argument("--clips", default="", help="comma-separated clips for the survey (default: all in --work)")
    ap.add_argument("--skip-survey", action="store_true")
    args = ap.parse_args()
    import cv2

    cv2.setNumThreads(2)
    if not args.skip_survey:
        survey(Path(args.work), set(filter(None, args.clips.split(","))))
    ego_variants(Path(args.work), Path(args.data))


if __name__ == "__main__":
    main()
