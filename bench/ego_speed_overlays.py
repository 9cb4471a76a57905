"""Ego speed on real dashcam clips against the speed their overlay shows (bench/labels/ego_speed_overlays.json).

For each labelled clip the geometry stage's own camera estimate (dashboard rows + horizon from the first
2 s, as ``extract`` does) feeds :class:`~deepcrashtest.geometry.egomotion.EgoMotionEstimator` over the
decoded frames; the smoothed speed is compared frame by frame with the overlay reading. Printed per clip:
the overlay's mean, the estimate's mean and median over the labelled frames, the median error in % of the
overlay on frames where it reads > 0, the frames the estimator calls stopped (< 0.3 m/s), how many frames
had a road-scale measurement (and their spread, before smoothing), and the camera
``fx * height`` that would make the means agree: the road plane's metric scale is proportional to the
assumed focal length times the assumed camera height, and a clip without calibration runs on the
unknown-dashcam default (90 deg horizontal field of view, 1.3 m). The highway clip (no overlay) runs with
its chessboard calibration and is checked against a plausible range. One more line per labelled clip: how
much the scene grows in the image over each reading (:func:`scene_expansion`, no focal length needed).

Run: PYTHONPATH=src python bench/ego_speed_overlays.py [--data DIR] [--clips a,b] [--tracks DIR] [--set NAME=X]
[--overlay-mask] [--fx PX] [--height M] [--horizon ROW] [--jitter N] [--draw DIR]
``--tracks DIR``: ``DIR/<clip>/tracks.csv`` from an earlier extract masks the road users (as extract does)
and self-calibrates the unknown camera from them as extract does (one more line: the speed rescaled by the
measured over the assumed focal length x camera height);
``--set``: an :class:`EgoMotionEstimator` option (repeatable), to compare variants on the same clips;
``--overlay-mask``: with ``still_mask`` from :func:`~deepcrashtest.geometry.camera.static_overlay_mask` of the
first 2 s (not used by extract yet); ``--fx`` / ``--height``: the labelled clips' camera with this focal length
(px) / height (m) instead of the unknown-dashcam default (to check a focal length measured elsewhere: the
speed should follow focal x height); ``--horizon ROW``: the labelled clips' camera pitched to this horizon row
(px) and held there (``with_horizon(camera, ROW, "user")``: the estimator's road normal then does not follow its
learned direction of travel); ``--early`` (with ``--tracks``): the estimator
measures with the focal length and height the self-calibration reads from the first 2 s of boxes (horizon row
kept), and the speed is rescaled by the whole clip's self-calibration over that camera (the "self-calibrated"
line, which with ``--fx`` / ``--height`` too rescales to the whole clip's calibration); ``--jitter N`` (with
``--fx`` and ``--height``): the labelled clips again at focal
lengths 1..N % either side with the height scaled to keep ``fx * height``, and the spread of the mean speeds (a
measurement that followed the camera only through ``fx * height`` would not move); ``--draw DIR``:
``DIR/<clip>_NNN.png`` per frame, the tracked points (red: in the road region whose motion gives the metric
scale, green: scene), the horizon row the estimator uses (yellow) and the masked dashboard rows (magenta). One
more line per labelled clip: the time base (identical consecutive frames), the dashboard rows, the horizon the
estimator learned from its direction of travel against the boxes' (with ``--tracks``), and the pairs that gave a
road scale.
"""

from __future__ import annotations

import argparse
import json
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
DATA = ROOT.parent / "shared" / "data"
LABELS = ROOT / "bench" / "labels" / "ego_speed_overlays.json"


@dataclass
class ClipRun:
    speed: np.ndarray  # smoothed ego speed per decoded frame, m/s
    fx: float  # px
    height_m: float
    cpu_ms: float  # estimator CPU time per frame (decoding not counted)
    raw: np.ndarray  # per frame: the keyframe pair's speed measurement (m/s) or NaN (none, or no road scale)
    factors: str = ""  # time base, dashboard rows, horizons, road-scale pairs (one line)
    calibration: str = ""  # with --tracks: extract's self-calibration of the unknown camera (one line)
    images: list[np.ndarray] | None = None  # the decoded frames (for the scene-expansion check)
    ego_scale: float = 1.0  # the factor it applies to the speed (measured over assumed focal x height)
    readings: list[tuple[int, float, float, str]] | None = None  # the speed filter's (step, m/s, var, outcome)


def overlay_speeds(entry: dict[str, Any], n: int) -> np.ndarray:
    """Per-frame overlay speed (m/s; NaN where unlabelled) for ``n`` frames."""
    out = np.full(n, np.nan)
    for r in entry["readings"]:
        out[r["first_frame"] : min(n, r["last_frame"] + 1)] = r["kmh"] / 3.6
    return out


def read_frames(video: Path, count: int) -> tuple[list[np.ndarray], float]:
    """The first ``count`` decoded frames of ``video`` (BGR, cv2's decode order) and its frame rate (fps)."""
    import cv2

    cap = cv2.VideoCapture(str(video))
    fps = float(cap.get(cv2.CAP_PROP_FPS))
    images = []
    while len(images) < count:
        ok, img = cap.read()
        if not ok:
            break
        images.append(img)
    cap.release()
    return images, fps


def run_clip(
    video: Path,
    chessboard: bool,
    last_frame: int,
    tracks: Path | None,
    options: dict[str, Any],
    overlay_mask: bool = False,
    camera: tuple[float | None, float | None] = (None, None),
    draw: Path | None = None,
    horizon: float | None = None,
    early: bool = False,
) -> ClipRun:
    import pandas as pd

    from deepcrashtest.geometry.camera import calibrate_chessboard, default_camera, static_overlay_mask, with_horizon
    from deepcrashtest.geometry.egomotion import EgoMotionEstimator
    from deepcrashtest.geometry.selfcalib import self_calibrate
    from deepcrashtest.pipeline.geometry_pass import estimate_camera

    images, fps = read_frames(video, last_frame + 1)
    h, w = images[0].shape[:2]
    cam = default_camera(w, h)
    fx, height = camera
    if fx is not None and not chessboard:
        cam = cam.model_copy(update={"fx": fx, "fy": fx})
    if height is not None and not chessboard:
        cam = cam.model_copy(update={"height_m": height})
    if chessboard:
        calib, _, _ = calibrate_chessboard(video.parent / "camera_calibration")
        cam = calib.model_copy(update={"height_m": cam.height_m})
    cam, rows, _ = estimate_camera(images[: int(2 * fps) + 1], cam)
    if horizon is not None and not chessboard:
        cam = with_horizon(cam, horizon, "user")  # held: the road normal is not learned from the travel
    base = with_horizon(default_camera(w, h), cam.horizon_v(), cam.pitch_source)  # what extract starts from
    boxes = pd.read_csv(tracks) if tracks is not None and tracks.exists() else None
    if early and boxes is not None and not chessboard:  # the camera the first 2 s of boxes self-calibrate
        first = self_calibrate(boxes[boxes.frame <= int(2 * fps)], base, (w, h)).camera
        cam = with_horizon(cam.model_copy(update={"fx": first.fx, "fy": first.fy, "height_m": first.height_m}),
                           cam.horizon_v(), cam.pitch_source)  # fmt: skip
    overlay = static_overlay_mask(images[: int(2 * fps) + 1]) if overlay_mask else None
    est = EgoMotionEstimator(cam, mask_bottom_rows=rows, still_mask=overlay, **options)
    t0 = time.process_time()
    raw = []
    for i, img in enumerate(images):
        b = boxes[boxes.frame == i][["x1", "y1", "x2", "y2"]].to_numpy(float) if boxes is not None else None
        state = est.update(img, i / fps, b)
        raw.append(np.nan if state.raw_speed is None else state.raw_speed)
        if draw is not None:
            draw_points(draw / f"{video.stem}_{i:03d}.png", img, est, rows)
    cpu_ms = (time.process_time() - t0) / len(images) * 1000
    ego = est.result()
    same = sum(int(np.array_equal(a, b)) for a, b in zip(images, images[1:], strict=False))
    horizon = est._horizon_row() / est._scale_f  # noqa: SLF001 (a diagnosis of the estimator's own state)
    factors = (
        f"{len(images)} frames at {fps:g} fps, {same} identical to the one before; dashboard rows {rows}; horizon "
        f"row {cam.horizon_v():.0f} at the start ({cam.pitch_source}), {horizon:.0f} learned from the travel; "
        f"road scale on {int(np.isfinite(raw).sum())} of {len(images) - 1} frame pairs"
    )
    run = ClipRun(ego.speed, cam.fx, cam.height_m, cpu_ms, np.asarray(raw), factors, images=images)
    run.readings = est._filter.readings  # noqa: SLF001 (a diagnosis of the estimator's own state)
    if boxes is not None and len(boxes) and cam.intrinsics_source == "default":
        cal = self_calibrate(boxes, base, (w, h), ego, ego_scaled_by_height=True)  # the whole clip's, as extract
        run.ego_scale = cal.camera.fy * cal.height_m / (cam.fy * cam.height_m)  # what the estimator assumed
        run.calibration = f"height {cal.height_m:.2f} m, focal {cal.fy:.0f} px, horizon row {cal.horizon_v:.0f}"
    return run


def draw_points(path: Path, img: np.ndarray, est: Any, rows: int) -> None:
    """One frame with the estimator's tracked points (red: road region, green: scene), its horizon row
    (yellow) and the masked dashboard rows (magenta), written to ``path`` (PNG)."""
    import cv2

    out = img.copy()
    s = est._scale_f  # noqa: SLF001
    h, w = out.shape[:2]
    p = est._p  # noqa: SLF001
    road = est._road_region(p[:, 0], p[:, 1], int(round(h * s))) if len(p) else np.zeros(0, bool)  # noqa: SLF001
    for (u, v), r in zip(p / s, road, strict=True):
        cv2.circle(out, (int(u), int(v)), 3, (0, 0, 255) if r else (0, 200, 0), -1)
    hv = int(est._horizon_row() / s)  # noqa: SLF001
    cv2.line(out, (0, hv), (w - 1, hv), (0, 255, 255), 1)
    if rows:
        cv2.line(out, (0, h - rows), (w - 1, h - rows), (255, 0, 255), 1)
    path.parent.mkdir(parents=True, exist_ok=True)
    cv2.imwrite(str(path), out)


def scene_expansion(entry: dict[str, Any], images: list[np.ndarray]) -> str:
    """How much the scene grows in the image over each overlay reading (a check on the overlay that needs no
    focal length): a similarity transform (RANSAC) of corners tracked from the reading's first to its last
    frame in the upper 55 % of the image (buildings, trees, parked cars; no bonnet, no overlay line). Driving
    ``d`` metres towards a point ``Z`` metres ahead scales it by ``Z / (Z - d)``: a 6 km/h reading over 2.6 s
    (4.3 m) grows a point 20 m ahead x1.28, 40 m ahead x1.12."""
    import cv2

    parts = []
    for rd in entry["readings"]:
        a, b = rd["first_frame"], min(rd["last_frame"], len(images) - 1)
        if b <= a:
            continue
        g0, g1 = (cv2.cvtColor(images[k], cv2.COLOR_BGR2GRAY) for k in (a, b))
        roi = np.zeros_like(g0)
        roi[: int(0.55 * g0.shape[0])] = 255
        p0 = cv2.goodFeaturesToTrack(g0, 400, 0.01, 7, mask=roi)
        if p0 is None:
            continue
        p1, st, _ = cv2.calcOpticalFlowPyrLK(g0, g1, p0, None, winSize=(21, 21), maxLevel=3)
        ok = st.ravel() == 1
        M, _ = cv2.estimateAffinePartial2D(p0[ok], p1[ok], ransacReprojThreshold=1.0)
        if M is not None:
            parts.append(f"frames {a}-{b} ({rd['kmh']} km/h) x{float(np.hypot(M[0, 0], M[1, 0])):.3f}")
    return "scene expansion over each reading: " + ", ".join(parts)


def report_labelled(name: str, entry: dict[str, Any], r: ClipRun) -> None:
    truth = overlay_speeds(entry, len(r.speed))
    lab = np.isfinite(truth) & (np.arange(len(r.speed)) > 0)
    moving = lab & (truth > 0)
    s, tr = r.speed, truth
    err = 100 * float(np.median((s[moving] - tr[moving]) / tr[moving])) if moving.any() else float("nan")
    mean_t, mean_e = float(np.mean(tr[lab])), float(np.mean(s[lab]))
    fh = r.fx * r.height_m * mean_t / mean_e if mean_e > 0.05 else float("nan")
    print(
        f"{name:22} {'default':10} {mean_t * 3.6:6.1f}kh {mean_e * 3.6:6.1f}kh {np.median(s[lab]) * 3.6:6.1f}kh "
        f"{err:7.1f} {int(np.sum(s[lab] < 0.3)):3d}/{int(lab.sum()):<3d} {r.fx * r.height_m:7.0f} {fh:9.0f} "
        f"{r.cpu_ms:8.1f}"
    )
    if r.calibration:
        sc = s * r.ego_scale
        err_c = 100 * float(np.median((sc[moving] - tr[moving]) / tr[moving])) if moving.any() else float("nan")
        mean_c = float(np.mean(sc[lab]))
        f_match = r.fx * mean_t / mean_c if mean_c > 0.05 else float("nan")  # speed goes with the focal length
        print(
            f"{'':22} self-calibrated as extract does ({r.calibration}): speed x {r.ego_scale:.2f}, mean "
            f"{mean_c * 3.6:.1f} km/h, median error {err_c:.1f} %; the focal length that would match: {f_match:.0f} px"
        )
    m = lab & np.isfinite(r.raw)
    if m.any():
        print(
            f"{'':22} road-scale measurements on {int(m.sum())} of {int(lab.sum())} frames: median "
            f"{np.median(r.raw[m]) * 3.6:.1f} km/h, 10-90 % {np.percentile(r.raw[m], 10) * 3.6:.1f}-"
            f"{np.percentile(r.raw[m], 90) * 3.6:.1f} km/h (before the Kalman/RTS smoother)"
        )
    print(f"{'':22} {r.factors}")
    if r.images is not None:
        print(f"{'':22} {scene_expansion(entry, r.images)}")
    zero = lab & (tr == 0)
    if zero.any():
        print(f"{'':22} overlay 0 km/h on {int(zero.sum())} frames: mean speed there {np.mean(s[zero]):.2f} m/s")


def report_jitter(name: str, entry: dict[str, Any], runs: list[tuple[float, ClipRun]]) -> None:
    """One line per run of a focal-length jitter (``--jitter``) and the spread of the mean speeds: each run keeps
    focal length x height (what the road plane's metric scale follows), so a measurement that depended on the
    camera only through it would read the same every time."""
    means = []
    for f, r in runs:
        truth = overlay_speeds(entry, len(r.speed))
        lab = np.isfinite(truth) & (np.arange(len(r.speed)) > 0)
        means.append(float(np.mean(r.speed[lab])) * 3.6)
        print(
            f"{'':22} fx {f:6.0f} px, height {r.height_m:.3f} m: mean {means[-1]:5.1f} km/h, road-scale readings on "
            f"{int(np.isfinite(r.raw[lab]).sum())} frames"
        )
    truth_mean = float(np.nanmean(overlay_speeds(entry, len(runs[0][1].speed))[1:])) * 3.6
    print(
        f"{name:22} jitter: mean speed median {np.median(means):.1f} km/h, range {min(means):.1f}-{max(means):.1f} "
        f"over {len(runs)} cameras of the same fx*h (overlay {truth_mean:.1f} km/h)"
    )


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--data", default=str(DATA))
    ap.add_argument("--clips", default="", help="comma-separated clip names (default: all)")
    ap.add_argument("--tracks", default="", help="folder with <clip>/tracks.csv to mask road users")
    ap.add_argument("--set", action="append", default=[], help="estimator option NAME=NUMBER (repeatable)")
    ap.add_argument(
        "--overlay-mask", action="store_true", help="with the static overlay mask (EgoMotionEstimator still_mask)"
    )
    ap.add_argument("--fx", type=float, default=None, help="focal length (px) of the labelled clips' camera")
    ap.add_argument("--height", type=float, default=None, help="camera height (m) of the labelled clips' camera")
    ap.add_argument("--horizon", type=float, default=None, help="horizon row (px) held by the labelled clips' camera")
    ap.add_argument(
        "--jitter", type=int, default=0, help="with --fx/--height: also runs at fx x (1 +- k %%), k = 1..N, fx*h kept"
    )
    ap.add_argument("--early", action="store_true", help="camera from the first 2 s of boxes (with --tracks)")
    ap.add_argument("--draw", default="", help="folder for PNGs of the tracked points, one per frame")
    args = ap.parse_args()
    import cv2

    cv2.setNumThreads(2)
    options = {k: float(v) for k, v in (o.split("=", 1) for o in args.set)}
    labels = json.loads(LABELS.read_text())
    wanted = set(filter(None, args.clips.split(",")))
    print(
        f"{'clip':22} {'camera':10} {'overlay':>8} {'est mean':>8} {'est med':>8} {'err %':>7} "
        f"{'stopped':>7} {'fx*h':>7} {'to match':>9} {'cpu ms/f':>8}"
    )
    for name, entry in labels["clips"].items():
        if wanted and name not in wanted:
            continue
        last = max(r["last_frame"] for r in entry["readings"])
        tracks = Path(args.tracks) / name / "tracks.csv" if args.tracks else None
        draw = Path(args.draw) if args.draw else None
        clip = run_clip(
            Path(args.data) / entry["video"],
            False,
            last,
            tracks,
            options,
            args.overlay_mask,
            (args.fx, args.height),
            draw,
            args.horizon,
            args.early,
        )
        report_labelled(name, entry, clip)
        if args.jitter and args.fx and args.height:
            runs = []
            for k in range(-args.jitter, args.jitter + 1):
                fk = args.fx * (1.0 + 0.01 * k)
                cam = (fk, args.height * args.fx / fk)
                r = clip if k == 0 else run_clip(Path(args.data) / entry["video"], False, last, tracks, options,
                                                  args.overlay_mask, cam, None, args.horizon, args.early)  # fmt: skip
                runs.append((fk, r))
            report_jitter(name, entry, runs)
    for name, entry in labels["plausibility"].items():
        if wanted and name not in wanted:
            continue
        r = run_clip(Path(args.data) / entry["video"], True, 250, None, options, args.overlay_mask)
        lo, hi = entry["range_kmh"]
        med = float(np.median(r.speed[1:])) * 3.6
        verdict = "plausible" if lo <= med <= hi else "IMPLAUSIBLE"
        print(
            f"{name:22} {'chessboard':10} {lo:3d}-{hi:3d}kh {float(np.mean(r.speed[1:])) * 3.6:6.1f}kh {med:6.1f}kh "
            f"{verdict:>15} {r.fx * r.height_m:7.0f} {'':>9} {r.cpu_ms:8.1f}"
        )


if __name__ == "__main__":
    main()
