"""Diagnostic: camera pitch or principal-point offset, and the focal length, from the scene's vertical lines.

    PYTHONPATH=src nice -n 10 python bench/vertical_lines.py [--work DIR] [--clips a,b]

Run on the 20 shared clips (first 2 s, every ~5th frame, vehicle boxes from ``DIR/<clip>/tracks.csv``
masked, horizon row from ``DIR/<clip>/scenario_raw.json``; default DIR /work/cache/fid_s9) it prints
per clip the fit below and the focal length it implies. **Not used by extract**: measured 2026-12-01,
``k`` comes out > 0 (verticals converging upwards) on 16 of 20 clips whatever side of the image centre
the horizon lies, and the Udacity clip (chessboard fy 1154 px, cy 388, k1 -0.26) reads 628 px at its
chessboard cy: the barrel distortion of dashcam lenses bends verticals more than a few degrees of
pitch tilts them, so the cue needs a distortion model (plumb-line calibration) first. With
``--distortion`` (a term ``x y`` beside the pitch's, branch dashfocal, 2026-12-02) ``k`` takes the
horizon's sign on more clips but still misreads the known ones: Udacity 781 px (chessboard 1154; its
segments span only rows -134..45 about the centre), ccd_000014 968 px (k 19.2e-5 +- 4.2e-5). On ccd_000014
(horizon 180 px below the centre) the verticals are near parallel (k 12e-5 +- 5e-5 over 2 s, -0.3e-5
over 5 s): a level camera whose principal point is not at the image centre, not a steep pitch.

Poles, posts, sign and building edges stand vertical in the world. In the image they meet at the
**vertical vanishing point**: for a camera pitched up by ``theta`` (horizon ``d_h = f tan(theta)``
pixels below the principal point row ``cy``) it lies ``D = f / tan(theta)`` pixels above ``cy``, so

    f^2 = d_h * D

(the horizon and the vertical vanishing point are pole and polar of each other). A vertical line
through the image point ``(x, y)`` (relative to ``(cx, cy)``) has the slope ``s = dx/dy = x / (y + D)``
plus the roll ``s0``: with ``k = 1 / D`` it is linear, ``s = s0 + k (x - s y)``, fitted robustly
(Tukey weights, segment length as weight) over near-vertical line segments of a few frames
(OpenCV's LSD). A level camera gives ``k = 0`` (parallel verticals). So, with the horizon row from
the boxes (:mod:`deepcrashtest.geometry.selfcalib`):

* ``k`` and ``d_h`` of the same sign and both well measured: the focal length ``sqrt(d_h / k)``;
* ``k`` near 0 while the horizon lies far from the image centre: the camera is level and the image's
  principal point is not at its centre (a cropped or re-framed video): the horizon is the principal
  point's row, not a pitch - and the focal length is not measurable from the image geometry (a level
  pinhole's ground-plane image only fixes focal length x camera height in metres per pixel).

The sigma of ``k`` is a bootstrap over frames. Lens distortion bends lines at the image edges (a
barrel lens makes verticals bow outwards), which the fit treats as noise; segments are kept short
of the frame edges.
"""

from __future__ import annotations

import argparse
import json
import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np

DATA = Path(__file__).resolve().parents[1].parent / "shared" / "data"

#: Segment filter: length (fraction of the image height) and at most this far from vertical (deg).
MIN_SEGMENT_REL = 0.05
MAX_TILT_DEG = 15.0
#: Fewer segments than this (over all frames) and nothing is measured.
MIN_SEGMENTS = 30
BOOTSTRAP = 40
TUKEY_C = 4.685


@dataclass(frozen=True)
class VerticalLines:
    """The fit: ``k`` (1/px: inverse distance of the vertical vanishing point above ``cy``; > 0
    above, i.e. a camera pitched up), its 1-sigma, the roll slope ``s0`` and the segments used."""

    k: float
    k_sigma: float
    roll_slope: float
    segments: int


def vertical_segments(image: np.ndarray, mask_bottom_rows: int = 0) -> np.ndarray:
    """Near-vertical line segments ``(N, 4)`` of one BGR or grey frame (x1, y1, x2, y2 px), from
    OpenCV's line segment detector, above the dashboard rows and away from the frame's borders."""
    import cv2

    grey = image if image.ndim == 2 else cv2.cvtColor(image, cv2.COLOR_BGR2GRAY)
    h, w = grey.shape[:2]
    found = cv2.createLineSegmentDetector().detect(grey)[0]
    if found is None:
        return np.zeros((0, 4))
    seg = found[:, 0].astype(float)
    dx, dy = seg[:, 2] - seg[:, 0], seg[:, 3] - seg[:, 1]
    length = np.hypot(dx, dy)
    tilt = np.degrees(np.arctan2(np.abs(dx), np.abs(dy)))
    inside = (np.minimum(seg[:, 0], seg[:, 2]) > 0.02 * w) & (np.maximum(seg[:, 0], seg[:, 2]) < 0.98 * w)
    inside &= np.maximum(seg[:, 1], seg[:, 3]) < h - mask_bottom_rows - 2
    return seg[(length >= MIN_SEGMENT_REL * h) & (tilt < MAX_TILT_DEG) & inside]


#: With ``--distortion``: one more column ``x y`` in the fit (a radial lens distortion ``k1`` tilts a
#: vertical through ``(x, y)`` by about ``2 k1 x y / f^2``: odd in ``y``, where the pitch's tilt is not).
DISTORTION_TERM = False


def _fit(x: np.ndarray, y: np.ndarray, s: np.ndarray, w0: np.ndarray, iters: int = 20) -> tuple[float, float]:
    """Robust ``s = s0 + k (x - s y)`` (+ ``c x y`` with :data:`DISTORTION_TERM`) -> (s0, k)."""
    cols = [np.ones_like(x), x - s * y] + ([x * y * 1e-3] if DISTORTION_TERM else [])
    A = np.column_stack(cols)
    w = w0.copy()
    sol = np.zeros(A.shape[1])
    for _ in range(iters):
        sw = np.sqrt(w)
        sol = np.linalg.lstsq(A * sw[:, None], s * sw, rcond=None)[0]
        r = s - A @ sol
        scale = TUKEY_C * (1.4826 * float(np.median(np.abs(r))) + 1e-9)
        w = w0 * np.where(np.abs(r) < scale, (1.0 - (r / scale) ** 2) ** 2, 0.0)
    return float(sol[0]), float(sol[1])


def fit_vertical_lines(segments: list[np.ndarray], cx: float, cy: float, seed: int = 0) -> VerticalLines | None:
    """The vertical vanishing point's ``k`` from per-frame segment arrays (see the module
    docstring); None with fewer than :data:`MIN_SEGMENTS` segments. Sigma: bootstrap over frames."""
    parts = [p for p in segments if len(p)]
    if sum(len(p) for p in parts) < MIN_SEGMENTS:
        return None

    def columns(p: np.ndarray) -> tuple[np.ndarray, ...]:
        x = 0.5 * (p[:, 0] + p[:, 2]) - cx
        y = 0.5 * (p[:, 1] + p[:, 3]) - cy
        s = (p[:, 2] - p[:, 0]) / (p[:, 3] - p[:, 1])
        return x, y, s, np.hypot(p[:, 2] - p[:, 0], p[:, 3] - p[:, 1])

    cols = [columns(p) for p in parts]
    allc = [np.concatenate([c[i] for c in cols]) for i in range(4)]
    s0, k = _fit(*allc)
    rng = np.random.default_rng(seed)
    boots = []
    for _ in range(BOOTSTRAP):
        pick = rng.integers(0, len(cols), len(cols))
        boots.append(_fit(*[np.concatenate([cols[j][i] for j in pick]) for i in range(4)], iters=8)[1])
    return VerticalLines(k, float(np.std(boots)), s0, len(allc[0]))


def focal_from_verticals(
    lines: VerticalLines, horizon_below_cy: float, horizon_sigma_px: float
) -> tuple[float, float] | None:
    """(focal length px, relative 1-sigma) from ``f^2 = d_h / k``, or None when ``k`` and the
    horizon offset ``d_h`` (px, > 0: below ``cy``) are not both of one sign beyond 2 sigma."""
    k, dh = lines.k, horizon_below_cy
    if k * dh <= 0 or abs(k) < 2 * lines.k_sigma or abs(dh) < 2 * horizon_sigma_px:
        return None
    rel = 0.5 * math.hypot(lines.k_sigma / abs(k), horizon_sigma_px / abs(dh))
    return math.sqrt(dh / k), rel


def level_bound_focal(lines: VerticalLines, horizon_below_cy: float) -> float:
    """The smallest focal length (px) with which the horizon offset ``d_h`` is a pitch the verticals
    allow (2 sigma): ``sqrt(|d_h| / (k' + 2 sigma))``, ``k' = |k|`` when ``k`` has the sign of
    ``d_h``, else 0. A shorter focal length would have tilted the verticals more than they are."""
    k = lines.k if lines.k * horizon_below_cy > 0 else 0.0
    return math.sqrt(abs(horizon_below_cy) / (abs(k) + 2.0 * lines.k_sigma + 1e-12))


def _clip_segments(video: Path, boxes: np.ndarray | None) -> tuple[list[np.ndarray], tuple[int, int]]:
    """Segments of every ~5th frame of the first 2 s, those inside (padded) vehicle boxes dropped."""
    import cv2

    cap = cv2.VideoCapture(str(video))
    fps = cap.get(cv2.CAP_PROP_FPS) or 10.0
    out, size, i = [], (0, 0), 0
    while i <= 2 * fps:
        ok, img = cap.read()
        if not ok:
            break
        size = (img.shape[1], img.shape[0])
        if i % max(1, int(fps / 5)) == 0:
            seg = vertical_segments(img)
            mx, my = 0.5 * (seg[:, 0] + seg[:, 2]), 0.5 * (seg[:, 1] + seg[:, 3])
            inside = np.zeros(len(seg), bool)
            for _, x1, y1, x2, y2 in boxes[boxes[:, 0] == i] if boxes is not None else []:
                pad = 0.2 * (x2 - x1)
                inside |= (mx > x1 - pad) & (mx < x2 + pad) & (my > y1 - pad) & (my < y2 + pad)
            out.append(seg[~inside])
        i += 1
    cap.release()
    return out, size


def main() -> None:
    import pandas as pd

    ap = argparse.ArgumentParser()
    ap.add_argument("--work", default="/work/cache/fid_s9", help="folder with <clip>/tracks.csv, scenario_raw.json")
    ap.add_argument("--clips", default="")
    ap.add_argument("--distortion", action="store_true", help="fit a radial-distortion term x*y as well")
    args = ap.parse_args()
    global DISTORTION_TERM
    DISTORTION_TERM = args.distortion
    videos = sorted(DATA.glob("crash_*/*.mp4")) + [DATA / "dashcam_udacity" / "highway_project_video.mp4"]
    wanted = set(filter(None, args.clips.split(",")))
    for video in videos:
        clip, work = video.stem, Path(args.work) / video.stem
        if wanted and clip not in wanted:
            continue
        tracks = work / "tracks.csv"
        boxes = pd.read_csv(tracks)[["frame", "x1", "y1", "x2", "y2"]].to_numpy(float) if tracks.exists() else None
        segs, (w, h) = _clip_segments(video, boxes)
        lines = fit_vertical_lines(segs, w / 2, h / 2)
        raw = work / "scenario_raw.json"
        if lines is None or not raw.exists():
            print(f"{clip:22} not measured")
            continue
        cam = json.loads(raw.read_text())["camera"]
        dh = cam["cy"] - cam["fy"] * math.tan(cam["pitch_rad"]) - h / 2
        sig = cam.get("horizon_sigma_px") or 5.0
        focal = focal_from_verticals(lines, dh, sig)
        said = f"{focal[0]:.0f} px +- {100 * focal[1]:.0f} %" if focal else "none"
        print(
            f"{clip:22} segments {lines.segments:4d}  k {lines.k * 1e5:6.2f}e-5 +- {lines.k_sigma * 1e5:4.2f}  "
            f"roll slope {lines.roll_slope:+.3f}  horizon {dh:+6.1f} +- {sig:4.1f} px from the centre  "
            f"focal {said}  level-camera bound {level_bound_focal(lines, dh):.0f} px"
        )


if __name__ == "__main__":
    main()
