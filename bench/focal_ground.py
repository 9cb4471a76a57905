"""Focal length from the ground's rigid motion while the ego yaws, on cameras with a known focal length.

    PYTHONPATH=src nice -n 10 python bench/focal_ground.py [--clips seq00,seq06,highway,ccd_000014]
        [--gap 2] [--max-frames 200] [--horizon ROW] [--horizon-offset PX] [--search PX] [--target PX]
        [--max-chain N] [--undistort] [--pairs] [--crash-work DIR [--mask-boxes]]

Per clip: the estimate of :func:`deepcrashtest.geometry.focal_ground.focal_from_ground` (focal px,
1-sigma of ``log f``, chained segments that turned, their median yaw) against the true focal length
where known. The horizon row: KITTI the calibration's principal row (a level camera), the Udacity
highway 424 (extract's box self-calibration reads 430), ccd_000014 the boxes' 540; with ``--crash-work``
(a fidelity ``--work`` folder) every crash clip in it at its extracted horizon, ``--mask-boxes`` keeping
corners off its detected boxes. ``--horizon-offset`` shifts the horizon (sensitivity), ``--search``
refines it from the ground's own motion (``horizon_from_ground``), ``--undistort`` takes the Udacity
frames through its chessboard calibration. Measured (docs/notes/selfcal13.md): seq00 731 px +- 3.3 %
(true 718.9), seq06 none (straight), Udacity 604 +- 13 % (1154), ccd_000014 295-448 px (overlay-implied
~2,700): not used by extract.
"""

from __future__ import annotations

import argparse
import json
import math
from pathlib import Path

import numpy as np
from focal_epipolar import _frames as frames_of

from deepcrashtest.geometry.camera import calibrate_chessboard, undistort
from deepcrashtest.geometry.focal_ground import focal_from_ground

DATA = Path(__file__).resolve().parents[1].parent / "shared" / "data"
ODO = DATA / "kitti_odometry"
#: name: (source, true focal px or None, horizon row, bottom rows masked, principal column or None)
CLIPS: dict[str, tuple[Path, float | None, float, int, float | None]] = {
    "seq00": (ODO / "seq00_frames0000-0159" / "image_0", 718.86, 185.2, 0, 607.2),
    "seq06": (ODO / "seq06_frames0000-0050" / "image_0", 707.1, 185.2, 0, 607.2),
    "highway": (DATA / "dashcam_udacity" / "highway_project_video.mp4", 1154.0, 424.0, 60, None),
    "ccd_000014": (DATA / "crash_ccd" / "ccd_000014.mp4", None, 540.0, 40, None),
}


def box_masks(tracks: Path, frames: list[np.ndarray], pad: int = 10) -> list[np.ndarray | None]:
    """Per frame a uint8 mask that is zero on every detected box of ``tracks`` (a tracks.csv), padded."""
    import pandas as pd

    df = pd.read_csv(tracks)
    out: list[np.ndarray | None] = []
    for k, img in enumerate(frames):
        m = np.full(img.shape, 255, np.uint8)
        for r in df[df["frame"] == k].itertuples():
            y0, y1 = max(0, int(r.y1) - pad), int(r.y2) + pad
            m[y0:y1, max(0, int(r.x1) - pad) : int(r.x2) + pad] = 0
        out.append(m)
    return out


def crash_clips(work: Path) -> dict[str, tuple[Path, float | None, float, int, float | None]]:
    """The crash clips of a fidelity ``--work`` folder, each with its extracted horizon row (pixels)."""
    out: dict[str, tuple[Path, float | None, float, int, float | None]] = {}
    for scen in sorted(work.glob("*/scenario.json")):
        name = scen.parent.name
        video = DATA / ("crash_dad" if name.startswith("dad") else "crash_ccd") / f"{name}.mp4"
        if not video.exists():
            continue
        cam = json.loads(scen.read_text())["camera"]
        row = cam["cy"] - cam["fy"] * math.tan(cam["pitch_rad"])
        out[name] = (video, None, row, 86, None)
    return out


def main() -> None:
    """Print each clip's estimate."""
    ap = argparse.ArgumentParser()
    ap.add_argument("--clips", default=",".join(CLIPS))
    ap.add_argument("--gap", type=int, default=2)
    ap.add_argument("--max-frames", type=int, default=200)
    ap.add_argument("--horizon", type=float, default=None)
    ap.add_argument("--horizon-offset", type=float, default=0.0)
    ap.add_argument("--pairs", action="store_true", help="print each pair's focal length")
    ap.add_argument("--target", type=float, default=25.0)
    ap.add_argument("--search", type=float, default=0.0, help="refine the horizon within +-PX rows")
    ap.add_argument("--max-chain", type=int, default=10)
    ap.add_argument("--crash-work", type=Path, default=None, help="a fidelity --work folder: its crash clips")
    ap.add_argument("--mask-boxes", action="store_true", help="crash clips: corners off the detected boxes")
    ap.add_argument("--roll", action="store_true", help="fit a static camera roll with the focal length")
    ap.add_argument("--undistort", action="store_true", help="Udacity frames undistorted by the chessboard")
    args = ap.parse_args()
    clips = dict(CLIPS)
    if args.crash_work is not None:
        clips = crash_clips(args.crash_work)
        args.clips = ",".join(clips)
    for name in args.clips.split(","):
        src, truth, row, bottom, cx = clips[name]
        frames = frames_of(src, args.max_frames)
        masks = None
        if args.crash_work is not None and args.mask_boxes:
            masks = box_masks(args.crash_work / name / "tracks.csv", frames)
        if args.undistort and name == "highway":
            cam = calibrate_chessboard(DATA / "dashcam_udacity" / "camera_calibration")[0]
            frames = [undistort(f, cam) for f in frames]
            cx = cam.cx
        horizon = (args.horizon if args.horizon is not None else row) + args.horizon_offset
        est = focal_from_ground(
            frames,
            horizon,
            cx=cx,
            gap=args.gap,
            bottom_rows=bottom,
            target_px=args.target,
            max_pairs=args.max_chain,
            horizon_search_px=args.search,
            masks=masks,
            fit_roll=args.roll,
        )
        focal = "none" if est.focal_px is None else f"{est.focal_px:7.0f}"
        err = "" if truth is None or est.focal_px is None else f"  error {100 * (est.focal_px / truth - 1):+.1f} %"
        print(
            f"{name:12} frames {len(frames):4d}  focal {focal} px  sigma(log) {est.sigma_log:.3f}  "
            f"horizon {est.horizon_row:.0f}  pairs {est.pairs:3d}  median yaw {np.degrees(est.yaw_rad):.2f} deg  "
            f"roll {np.degrees(est.roll_rad):.2f} deg  true {truth}{err}"
        )
        if args.pairs:
            print("   ", " ".join(f"{f:.0f}" for f in est.per_pair))


if __name__ == "__main__":
    main()
