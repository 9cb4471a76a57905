"""Which horizon extract's ego-motion runs on, against the one its localisation uses (diagnosis, issue #14 item 5).

``extract`` picks the ego-motion and lanes horizon from the first 2 s of pixels
(:func:`deepcrashtest.pipeline.geometry_pass.estimate_camera`: lane vanishing point, else the flow's focus of
expansion), while localisation uses the self-calibrated horizon of the whole clip's vehicle boxes
(:func:`deepcrashtest.geometry.selfcalib.self_calibrate`). Part 1 prints, per clip, the pixel horizon, the
horizon of the same first 2 s of boxes (:func:`~deepcrashtest.geometry.selfcalib.horizon_from_few_boxes`, prior
camera height) and the whole clip's self-calibrated one (from a cached extract's ``scenario_raw.json``).
Part 2 runs :class:`~deepcrashtest.geometry.egomotion.EgoMotionEstimator` on ccd_000014 (GPS overlay 57-59 km/h)
with each horizon and with/without the burned-in overlay rows masked: mean speed, frames read as stopped,
frames with a road-scale measurement and their readings.

Run: PYTHONPATH=src python bench/ego_horizon_diag.py --work DIR [--clips a,b] [--skip-survey]
``DIR/<clip>/`` holds an earlier extract (``tracks.csv``, ``scenario_raw.json``; e.g. a copy of a
``bench/fidelity_crashes.py --work`` folder).
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

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
        for mask in (rows, 40):
            est = EgoMotionEstimator(cam, mask_bottom_rows=mask)
            raw = []
            for i, img in enumerate(images):
                b = tracks[tracks.frame == i][["x1", "y1", "x2", "y2"]].to_numpy(float)
                s = est.update(img, i / fps, b)
                raw.append(s.raw_speed)
            speed = est.result().speed[1:] * 3.6
            got = np.array([r for r in raw if r is not None]) * 3.6
            print(
                f"{name:28} {mask:>11d} {np.mean(speed):9.1f} {int(np.sum(speed < 1.08)):>4d}/{len(speed):<3d} "
                f"{len(got):>7d}  {np.array2string(np.round(got), separator=' ')}",
                flush=True,
            )


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
