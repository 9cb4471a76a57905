"""Camera models: intrinsics (user YAML, chessboard, field of view, default), horizon, dashboard mask.

All intrinsics are pinhole, in pixels of the full video frame. ``Camera`` is the Scenario's
model (``deepcrashtest.scenario.Camera``): x right, y down, z forward; ``pitch_rad`` > 0 tilts
the optical axis down (the horizon then lies above the principal point).

Default for unknown dashcams: a 90 deg horizontal field of view (``fx = width / 2``).
Consumer dashcams advertise 120-140 deg *diagonal* fields of view through barrel-distorting
lenses; near the image centre such a lens behaves like a pinhole of focal length
``r_diag / theta_diag`` (equidistant model), i.e. 600-700 px for a 1280-px-wide frame, a
horizontal field of view of 85-95 deg. The two calibrated cameras in the shared data bracket it
(Udacity 58 deg, KITTI 82 deg). Distances scale linearly with the focal length, so a wrong
default scales all distances and speeds by the same factor; relative motion is unaffected.
"""

from __future__ import annotations

import math
from collections.abc import Iterable, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import cv2
import numpy as np
import yaml
from pydantic import ValidationError

from deepcrashtest.errors import UserError
from deepcrashtest.fileio import require_file
from deepcrashtest.scenario import MAX_CAMERA_HEIGHT_M, Camera, format_validation_error

DEFAULT_HFOV_DEG = 90.0
DASHCAM_HEIGHT_M = 1.3  # a windscreen-mounted dashcam in a passenger car
LANDSCAPE_ASPECT = 16 / 9  # the frame a portrait picture is taken as cut from (default camera)
KITTI_HEIGHT_M = 1.65
_CAMERA_KEYS = {"fx", "fy", "cx", "cy", "distortion", "height_m", "pitch_rad", "roll_rad", "forward_offset_m"}


def camera_from_fov(width: int, height: int, hfov_deg: float, **kw: Any) -> Camera:
    """Square-pixel pinhole with the given horizontal field of view, principal point at the centre."""
    if not 10.0 <= hfov_deg < 179.0:
        raise UserError(f"horizontal field of view must be in [10, 179) degrees (got {hfov_deg})")
    f = 0.5 * width / math.tan(math.radians(hfov_deg) / 2)
    kw.setdefault("intrinsics_source", "fov")
    return Camera(fx=f, fy=f, cx=width / 2.0, cy=height / 2.0, **kw)


def default_camera(
    width: int, height: int, height_m: float = DASHCAM_HEIGHT_M, area: tuple[int, int, int, int] | None = None
) -> Camera:
    """The unknown-dashcam default (90 deg horizontal field of view, 1.3 m above the road). ``area``: the
    picture ``(x0, y0, x1, y1)`` (px) inside black bars: the field of view spans it, centred on it.

    A picture taller than wide is a portrait cut from a landscape dashcam's frame (phones and short-video sites
    show dashcam clips so): its focal length is that of the 16:9 landscape of its height, 90 deg over
    ``height * 16 / 9`` (0.89 x the height, px), not 90 deg over its narrow width (3.2x shorter for 9:16)."""
    x0, y0, x1, y1 = area if area is not None else (0, 0, width, height)
    portrait = portrait_size(width, height, area)
    span = x1 - x0 if portrait is None else portrait[1] * LANDSCAPE_ASPECT  # the width the 90 deg spread over (px)
    f = 0.5 * span / math.tan(math.radians(DEFAULT_HFOV_DEG) / 2)
    return Camera(fx=f, fy=f, cx=(x0 + x1) / 2.0, cy=(y0 + y1) / 2.0, height_m=height_m, intrinsics_source="default")


def portrait_size(width: int, height: int, area: tuple[int, int, int, int] | None = None) -> tuple[int, int] | None:
    """The picture's (width, height) px (``area`` inside black bars, else the ``width`` x ``height`` frame) when it is
    taller than wide: a portrait, which :func:`default_camera` takes as cut from a 16:9 landscape; None otherwise."""
    x0, y0, x1, y1 = area if area is not None else (0, 0, width, height)
    return (x1 - x0, y1 - y0) if x1 - x0 < y1 - y0 else None


def _on_picture(width: int, height: int, hfov_deg: float, area: tuple[int, int, int, int] | None, **kw: Any) -> Camera:
    """:func:`camera_from_fov` over the picture ``area`` (x0, y0, x1, y1, px) when given, else the frame."""
    if area is None:
        return camera_from_fov(width, height, hfov_deg, **kw)
    x0, y0, x1, y1 = area
    cam = camera_from_fov(x1 - x0, y1 - y0, hfov_deg, **kw)
    return cam.model_copy(update={"cx": (x0 + x1) / 2.0, "cy": (y0 + y1) / 2.0})


def camera_from_yaml(path: str | Path, width: int | None = None, height: int | None = None) -> Camera:
    """Read a camera YAML: fx, fy, cx, cy (px) [, distortion, height_m, pitch_rad, ...] or hfov_deg.

    With ``hfov_deg`` (and no fx) the frame size ``width``/``height`` is needed.
    """
    p = require_file(path, "camera file")
    try:
        data = yaml.safe_load(p.read_text())
    except yaml.YAMLError as exc:
        raise UserError(f"{p}: not valid YAML ({str(exc).splitlines()[0]})") from None
    if not isinstance(data, dict):
        raise UserError(f"{p}: expected a mapping of camera parameters")
    unknown = set(data) - _CAMERA_KEYS - {"hfov_deg", "width", "height"}
    if unknown:
        raise UserError(f"{p}: unknown camera keys {sorted(unknown)} (allowed: {sorted(_CAMERA_KEYS | {'hfov_deg'})})")
    extra = {k: data[k] for k in _CAMERA_KEYS - {"fx", "fy", "cx", "cy"} if k in data}
    if "height_m" in extra:
        extra["height_source"] = "user"
    if "pitch_rad" in extra:
        extra["pitch_source"] = "user"
    try:
        if "fx" in data:
            return Camera(
                fx=float(data["fx"]), fy=float(data["fy"] if "fy" in data else data["fx"]), cx=float(data["cx"]),
                cy=float(data["cy"]), intrinsics_source="user", **extra,
            )  # fmt: skip
        if "hfov_deg" in data:
            w = int(data.get("width", width or 0))
            h = int(data.get("height", height or 0))
            if w <= 0 or h <= 0:
                raise UserError(f"{p}: hfov_deg needs the frame width and height")
            return camera_from_fov(w, h, float(data["hfov_deg"]), intrinsics_source="user", **extra)
    except ValidationError as exc:  # a ValueError whose text spans lines: one line naming the fields
        raise UserError(f"{p}: bad camera parameters ({format_validation_error(exc)})") from None
    except (KeyError, TypeError, ValueError) as exc:
        raise UserError(f"{p}: bad camera parameters ({exc})") from None
    raise UserError(f"{p}: needs fx, cx, cy (pixels) or hfov_deg")


def calibrate_chessboard(
    folder: str | Path, pattern: tuple[int, int] = (9, 6), square_m: float = 1.0, max_images: int | None = None
) -> tuple[Camera, float, int]:
    """Calibrate from chessboard photos (OpenCV). Returns (camera, RMS reprojection error px, images used)."""
    root = Path(folder)
    if not root.is_dir():
        raise UserError(f"{root}: chessboard folder not found")
    files = sorted(p for p in root.iterdir() if p.suffix.lower() in {".jpg", ".jpeg", ".png", ".bmp"})
    if max_images:
        files = files[:max_images]
    obj = np.zeros((pattern[0] * pattern[1], 3), np.float32)
    obj[:, :2] = np.mgrid[0 : pattern[0], 0 : pattern[1]].T.reshape(-1, 2) * square_m
    obj_pts, img_pts = [], []
    size: tuple[int, int] | None = None
    crit = (cv2.TERM_CRITERIA_EPS + cv2.TERM_CRITERIA_MAX_ITER, 30, 1e-3)
    for f in files:
        grey = cv2.imread(str(f), cv2.IMREAD_GRAYSCALE)
        if grey is None:
            continue
        if size is None:
            size = (grey.shape[1], grey.shape[0])
        elif (grey.shape[1], grey.shape[0]) != size:
            continue
        found, corners = cv2.findChessboardCorners(grey, pattern, None)
        if not found:
            continue
        corners = cv2.cornerSubPix(grey, corners, (11, 11), (-1, -1), crit)
        obj_pts.append(obj)
        img_pts.append(corners)
    if size is None or len(obj_pts) < 3:
        raise UserError(f"{root}: found a {pattern[0]}x{pattern[1]} chessboard in {len(obj_pts)} images (need >= 3)")
    rms, K, dist, _, _ = cv2.calibrateCamera(obj_pts, img_pts, size, None, None)
    cam = Camera(
        fx=float(K[0, 0]), fy=float(K[1, 1]), cx=float(K[0, 2]), cy=float(K[1, 2]),
        distortion=[float(v) for v in np.ravel(dist)[:5]], intrinsics_source="chessboard",
    )  # fmt: skip
    return cam, float(rms), len(obj_pts)


def scale_camera(camera: Camera, sx: float, sy: float | None = None) -> Camera:
    """The same camera for a resized frame (intrinsics scaled; distortion unchanged)."""
    sy = sx if sy is None else sy
    scaled = {"fx": camera.fx * sx, "fy": camera.fy * sy, "cx": camera.cx * sx, "cy": camera.cy * sy}
    return camera.model_copy(update=scaled)


def undistort(image: np.ndarray, camera: Camera) -> np.ndarray:
    """Remove lens distortion (same intrinsics after undistortion)."""
    if not camera.distortion:
        return image
    return cv2.undistort(image, camera.matrix(), np.asarray(camera.distortion))


def undistort_points(points: np.ndarray, camera: Camera) -> np.ndarray:
    """(n, 2) pixels of the lens-distorted image -> (n, 2) pixels of the undistorted (pinhole) image with the
    same intrinsics; returned unchanged when the camera has no distortion."""
    pts = np.asarray(points, dtype=np.float64).reshape(-1, 2)
    if not camera.distortion or not len(pts):
        return pts.copy()
    K = camera.matrix()
    criteria = (cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, 40, 1e-6)  # strong wide-angle terms converge slowly
    dist = np.asarray(camera.distortion, float)
    out = cv2.undistortPointsIter(pts.reshape(-1, 1, 2), K, dist, np.eye(3), K, criteria)
    return np.asarray(out, dtype=np.float64).reshape(-1, 2)


def cut_sides(boxes: np.ndarray, size: tuple[int, int]) -> np.ndarray:
    """(n, 4) bool: which sides ``x1, y1, x2, y2`` of (n, 4) boxes (px) the frame's border cuts off (a side within a
    pixel or two of it), ``size`` = (width, height) px: the test every monocular cue and the self-calibration use."""
    b = np.asarray(boxes, dtype=np.float64).reshape(-1, 4)
    w, h = size
    return np.column_stack([b[:, 0] <= 1, b[:, 1] <= 1, b[:, 2] >= w - 2, b[:, 3] >= h - 2])


def undistort_boxes(boxes: np.ndarray, camera: Camera, size: tuple[int, int] | None = None) -> np.ndarray:
    """(n, 4) boxes ``x1, y1, x2, y2`` (px) of the lens-distorted image -> the boxes of the same road users in the
    undistorted image (same intrinsics): what the pinhole geometry (ground plane, box heights) must measure.

    A road user's outline is taken as a rectangle of the undistorted image. A barrel-distorting (wide-angle) lens
    bows its edges outwards: each side of the detector's box touches the bowed edge where that edge comes nearest
    the image centre's row or column (the bottom edge at the column of the centre, or the box's side nearest it),
    so each side moves as that point does. A pincushion lens bows them inwards: the box touches at the edge's
    ends, the far corner. ``size`` (width, height px): a side the frame's border cuts off (:func:`cut_sides`)
    stays cut, and every other side stays uncut (the undistorted image is larger than the frame). Unchanged
    without distortion."""
    b = np.asarray(boxes, dtype=np.float64).reshape(-1, 4)
    if not camera.distortion or not len(b):
        return b.copy()
    x1, y1, x2, y2 = b.T
    corner = undistort_points(np.array([[0.0, 0.0]]), camera)[0]
    barrel = bool(np.hypot(*(corner - (camera.cx, camera.cy))) >= np.hypot(camera.cx, camera.cy))
    if barrel:  # the point of each edge nearest the centre's column (top, bottom) or row (sides)
        xm, ym = np.clip(camera.cx, x1, x2), np.clip(camera.cy, y1, y2)
    else:  # the end of each edge farthest from it
        xm = np.where(np.abs(x1 - camera.cx) > np.abs(x2 - camera.cx), x1, x2)
        ym = np.where(np.abs(y1 - camera.cy) > np.abs(y2 - camera.cy), y1, y2)
    pts = np.concatenate([np.column_stack([x1, ym]), np.column_stack([x2, ym]), np.column_stack([xm, y1]),
                          np.column_stack([xm, y2])])  # fmt: skip
    u = undistort_points(pts, camera).reshape(4, len(b), 2)
    out = np.column_stack([u[0, :, 0], u[2, :, 1], u[1, :, 0], u[3, :, 1]])
    if size is not None:  # each side cut off (:func:`cut_sides`) as the detector saw it, and only those
        cut, far = cut_sides(b, size), np.array([size[0], size[1]], float)
        out[:, :2] = np.where(cut[:, :2], np.minimum(out[:, :2], 0.0), np.maximum(out[:, :2], 1.5))
        out[:, 2:] = np.where(cut[:, 2:], np.maximum(out[:, 2:], far - 1.0), np.minimum(out[:, 2:], far - 2.5))
    return out


def undistorted_tracks(tracks: Any, camera: Camera, size: tuple[int, int] | None = None) -> Any:
    """The tracks table (a DataFrame with ``x1, y1, x2, y2`` px) with its boxes in the undistorted image
    (:func:`undistort_boxes`, ``size`` the frame's); the table itself when the camera has no distortion."""
    if not camera.distortion or not len(tracks):
        return tracks
    out = tracks.copy()
    cols = ["x1", "y1", "x2", "y2"]
    out[cols] = undistort_boxes(tracks[cols].to_numpy(dtype=float), camera, size)
    return out


def with_horizon(camera: Camera, horizon_v: float, source: str) -> Camera:
    """Set the pitch so that the horizon lies on image row ``horizon_v`` (pixels)."""
    pitch = math.atan2(camera.cy - horizon_v, camera.fy)
    return camera.model_copy(update={"pitch_rad": pitch, "pitch_source": source})


# --------------------------------------------------------------------------- horizon
def vanishing_point_from_lines(lines: np.ndarray, width: int, height: int) -> tuple[float, float] | None:
    """Least-squares intersection of image lines (N, 4: x1, y1, x2, y2) -> (u, v) pixels, or None.

    Each line is weighted by its length; lines nearly horizontal or vertical are ignored.
    """
    L = np.asarray(lines, dtype=float).reshape(-1, 4)
    if len(L) < 2:
        return None
    d = L[:, 2:] - L[:, :2]
    length = np.hypot(d[:, 0], d[:, 1])
    ang = np.degrees(np.abs(np.arctan2(d[:, 1], d[:, 0]))) % 180
    keep = (length > 10) & (np.minimum(ang, 180 - ang) > 15) & (np.abs(ang - 90) > 5)
    if keep.sum() < 2:
        return None
    L, d, length = L[keep], d[keep], length[keep]
    normal = np.column_stack([-d[:, 1], d[:, 0]]) / length[:, None]
    c = np.sum(normal * L[:, :2], axis=1)
    has_left = np.any(d[:, 0] * d[:, 1] < 0)
    has_right = np.any(d[:, 0] * d[:, 1] > 0)
    if not (has_left and has_right):
        return None
    sol, *_ = np.linalg.lstsq(normal * length[:, None], c * length, rcond=None)
    u, v = float(sol[0]), float(sol[1])
    if not (-0.5 * width < u < 1.5 * width and 0 < v < height):
        return None
    return u, v


def focus_of_expansion(p0: np.ndarray, p1: np.ndarray) -> tuple[float, float] | None:
    """Focus of expansion of a forward-moving camera from point tracks (least squares, pixels)."""
    d = np.asarray(p1, float) - np.asarray(p0, float)
    mag = np.hypot(d[:, 0], d[:, 1])
    keep = mag > 0.5
    if keep.sum() < 10:
        return None
    n = np.column_stack([-d[keep, 1], d[keep, 0]]) / mag[keep, None]
    c = np.sum(n * p0[keep], axis=1)
    sol, *_ = np.linalg.lstsq(n, c, rcond=None)
    return float(sol[0]), float(sol[1])


def estimate_horizon_flow(frames: Iterable[np.ndarray], max_pairs: int = 10) -> float | None:
    """Median focus-of-expansion row over consecutive frame pairs (grey or BGR), pixels, or None."""
    rows: list[float] = []
    prev = None
    for f in frames:
        g = f if f.ndim == 2 else cv2.cvtColor(f, cv2.COLOR_BGR2GRAY)
        if prev is not None:
            pts = cv2.goodFeaturesToTrack(prev, 800, 0.01, 8)
            if pts is not None:
                nxt, st, _ = cv2.calcOpticalFlowPyrLK(prev, g, pts, None)  # type: ignore[call-overload]
                ok = st.ravel() == 1
                foe = focus_of_expansion(pts.reshape(-1, 2)[ok], nxt.reshape(-1, 2)[ok])
                if foe is not None and 0 < foe[1] < g.shape[0]:
                    rows.append(foe[1])
            if len(rows) >= max_pairs:
                break
        prev = g
    return float(np.median(rows)) if rows else None


# --------------------------------------------------------------------------- dashboard
_BONNET_WIDTH = 320  # frames are analysed downscaled to this width, px
_BONNET_BINS = 32  # column bins of the contour


def _bonnet_stack(
    frames: Iterable[np.ndarray], max_frames: int, width: int = _BONNET_WIDTH, spread: bool = False
) -> tuple[np.ndarray, float]:
    """Downscaled (to ``width`` px), lightly blurred grey frames (t, h, w) as float32 and the downscale
    factor: the first ``max_frames`` frames, or with ``spread`` ``max_frames`` spread over all of them."""
    out: list[np.ndarray] = []
    scale = 1.0
    if spread:
        seq = list(frames)
        frames = seq[:: max(1, len(seq) // max_frames)]
    for f in frames:
        g = f if f.ndim == 2 else cv2.cvtColor(f, cv2.COLOR_BGR2GRAY)
        scale = min(1.0, width / g.shape[1])
        fy = max(scale, 1.0 / g.shape[0])  # a 1280 x 2 sliver keeps a row
        g = cv2.resize(g, None, fx=scale, fy=fy, interpolation=cv2.INTER_AREA)
        out.append(cv2.GaussianBlur(g.astype(np.float32), (3, 3), 0))
        if len(out) >= max_frames:
            break
    return (np.stack(out) if out else np.zeros((0, 1, 1), np.float32)), scale


#: Overlay mask (:func:`static_overlay_mask`): frames analysed at this width (burned-in glyphs are ~10-20 px
#: tall at 1280 px: at the bonnet's 320 px they blur away), px.
_OVERLAY_WIDTH = 640


#: Overlay mask thresholds (:func:`static_overlay_mask`): the edge's gradient (grey levels per pixel), the
#: stillness (temporal std over mean gradient, ~px of motion), the row gap closed and the dilation (px at
#: :data:`_OVERLAY_WIDTH`).
_OVERLAY_EDGE_MIN = 24.0
_OVERLAY_STILL = 0.1
_OVERLAY_CLOSE_PX = 21
_OVERLAY_DILATE_PX = 3


def static_overlay_mask(
    frames: Iterable[np.ndarray], max_frames: int = 10, max_share: float = 0.03
) -> np.ndarray | None:
    """Pixels burned into or fixed to the picture (date/time/speed text, logos, frame borders, the bonnet's
    edge): full-frame bool mask (True = not scene), or None when nothing is found or the camera stands
    (nearly) still.

    ``frames``: a second or two of video (BGR or grey, any size), ``max_frames`` of them spread over it.
    A pixel is an overlay when it lies on an edge in at least 90 % of the frames (10th percentile of the
    Sobel gradient magnitude at least :data:`_OVERLAY_EDGE_MIN` grey levels per pixel, frames at
    :data:`_OVERLAY_WIDTH` px) and its grey level does not change: temporal standard deviation under
    :data:`_OVERLAY_STILL` times its mean gradient, i.e. it moved less than ~0.1 px. A scene edge that
    persists (a distant ridge near the focus of expansion) still drifts by a pixel or more with the
    camera's wobble and keeps its corners; text on the picture does not move at all. When more than
    ``max_share`` of the frame is such still detail (a standing or crawling camera: the stopped DAD 512
    20.7 %, the near-still DAD 528 4.5 %, against 0.1-1.4 % on 9 moving CCD/DAD clips and the Udacity
    highway clip, 0 on KITTI odometry) the scene itself is still and None is returned: the ego-motion's
    stopped test needs those points. Overlay corners otherwise outlive the blurred scene's in the feature
    tracker and read as "stopped" (ccd_000014, ccd_000080). Gaps along a row up to :data:`_OVERLAY_CLOSE_PX`
    (changing digits between still ones) are closed, then the mask is dilated by :data:`_OVERLAY_DILATE_PX`.
    For ``EgoMotionEstimator(still_mask=...)``, which ``extract`` does not switch on yet (README).
    """
    frames = list(frames)
    stack, _ = _bonnet_stack(frames, max_frames, width=_OVERLAY_WIDTH, spread=True)
    if len(stack) < 4:
        return None
    grad = np.stack([np.hypot(cv2.Sobel(g, cv2.CV_32F, 1, 0), cv2.Sobel(g, cv2.CV_32F, 0, 1)) / 4.0 for g in stack])
    persistent = np.percentile(grad, 10, axis=0) >= _OVERLAY_EDGE_MIN
    fixed = persistent & (stack.std(axis=0) < _OVERLAY_STILL * grad.mean(axis=0))
    share = float(fixed.mean())
    if share == 0.0 or share > max_share:
        return None
    # a text line's glyphs that change (the seconds, a speed) sit between still ones: close the line's gaps
    fixed_u8 = cv2.morphologyEx(fixed.astype(np.uint8), cv2.MORPH_CLOSE, np.ones((1, _OVERLAY_CLOSE_PX), np.uint8))
    k = 2 * _OVERLAY_DILATE_PX + 1
    fixed_u8 = cv2.dilate(fixed_u8, np.ones((k, k), np.uint8))
    fixed = fixed_u8 > 0
    h, w = frames[0].shape[:2]
    return cv2.resize(fixed.astype(np.uint8), (w, h), interpolation=cv2.INTER_NEAREST) > 0


@dataclass(frozen=True)
class BonnetContour:
    """Top edge of the bonnet/dashboard: ``top_px[k]`` is the full-frame row (NaN: no bonnet) over the
    full-frame columns ``bin_edges_px[k]`` to ``bin_edges_px[k + 1]``; ``frame_height`` in px."""

    top_px: np.ndarray
    bin_edges_px: np.ndarray
    frame_height: int

    def row_at(self, u: float) -> float:
        """The contour's row at full-frame column ``u`` (px); NaN where no bonnet was found."""
        k = int(np.clip(np.searchsorted(self.bin_edges_px, u, side="right") - 1, 0, len(self.top_px) - 1))
        return float(self.top_px[k])


def bonnet_contour(
    frames: Iterable[np.ndarray],
    max_frames: int = 12,
    edge_min: float = 12.0,
    still_ratio: float = 1.5,
    max_static: float = 0.5,
    min_top: float = 0.68,
    below_pct: float = 50.0,
    boxes: Sequence[np.ndarray] | None = None,
) -> BonnetContour | None:
    """Top edge of the bonnet/dashboard per column bin, full-frame pixel rows (NaN: no bonnet there).

    ``frames`` should span a second or more of driving (BGR or grey, any size). The bonnet is what
    stays put in the image while the scene moves past: below its top edge the image hardly changes
    (temporal std of the grey level), above it the road does, and the edge itself is in the same
    place in every frame (the ``edge_min`` grey levels per pixel of vertical Sobel gradient in at
    least 80 % of the frames). Per column bin, the highest row in the lower 45 % of the frame where
    such a persistent edge has a region below it whose temporal std is at most ``still_ratio``
    times the road's just above is taken; bins without one are NaN. A plain blurred road has no
    persistent edge, so it is not mistaken for a bonnet. Returns None when the scene does not
    change (median temporal std of the lower half under ``min_moving`` grey levels: a stopped
    camera, nothing to tell the bonnet from the road) or fewer than 4 frames are given. ``boxes``: each frame's
    road users (N, 4) x1, y1, x2, y2 full-frame px; a bin whose edge lies inside a box that does not reach the
    frame's bottom, in at least half the frames, is that road user's (:func:`_in_road_users`), not the bonnet.
    """
    stack, scale = _bonnet_stack(frames, max_frames)
    if len(stack) < 4:
        return None
    t, h, w = stack.shape
    std = stack.std(axis=0)
    grad = np.abs(np.stack([cv2.Sobel(g, cv2.CV_32F, 0, 1, ksize=3) for g in stack])) / 4.0
    persistent = np.percentile(grad, 20, axis=0)  # an edge present in >= 80 % of the frames
    scene = grad[:, : int(0.6 * h)].mean(axis=0) >= edge_min  # the scene's edges (upper 60 %)
    if not scene.any() or float((persistent[: int(0.6 * h)] >= edge_min)[scene].mean()) > max_static:
        return None  # the scene's own edges stay put: a stopped camera
    edges = np.linspace(0, w, _BONNET_BINS + 1).astype(int)
    top = np.full(_BONNET_BINS, np.nan)
    for k in range(_BONNET_BINS):
        p = np.median(persistent[:, edges[k] : edges[k + 1]], axis=1)
        s = np.median(std[:, edges[k] : edges[k + 1]], axis=1)
        best = edge_min
        for r in range(int(min_top * h), h - 2):
            if p[r] < best or p[r] < p[r - 1] or p[r] < p[r + 1]:
                continue  # not the strongest persistent edge's crest so far
            above = float(np.median(s[max(0, r - 12) : r - 2]))
            below = float(np.percentile(s[r + 2 :], below_pct))
            if below <= still_ratio * above:
                top[k], best = (r + 0.5) / scale, float(p[r])
    if boxes is not None:
        top[_in_road_users(top, edges / scale, list(boxes)[:t], h / scale)] = np.nan
    return BonnetContour(top, edges / scale, int(round(h / scale)))


def _in_road_users(top: np.ndarray, edges: np.ndarray, boxes: list[np.ndarray], height: float) -> np.ndarray:
    """(bins,) True where the bin's edge row ``top`` (full-frame px; NaN: none) lies inside a road user's box at the
    bin's centre column in at least half of the frames' ``boxes`` (each (N, 4) x1, y1, x2, y2 px), a box that does not
    reach the frame's bottom (``height`` px; a box along the bottom can be the bonnet itself taken for a car): a car
    followed at a steady gap keeps its edges in place as a bonnet does (dad_000487 through a longer lens: the red
    car's bumper masked 218 rows of road)."""
    out = np.zeros(len(top), bool)
    if not boxes:
        return out
    cols = 0.5 * (edges[:-1] + edges[1:])
    hits = np.zeros(len(top), int)
    for b in boxes:
        b = np.asarray(b, float).reshape(-1, 4)
        b = b[b[:, 3] < (1.0 - BOTTOM_SHARE) * height]
        inside = (
            (b[None, :, 0] <= cols[:, None])
            & (cols[:, None] <= b[None, :, 2])
            & (b[None, :, 1] <= top[:, None])
            & (top[:, None] <= b[None, :, 3])
        )
        hits += inside.any(axis=1)
    return np.isfinite(top) & (hits >= 0.5 * len(boxes))


#: A box reaches the picture's bottom edge when its bottom lies within this share of the picture's height of it: it
#: may be the ego's own bonnet taken for a vehicle (:func:`_in_road_users` keeps the bonnet's edges inside it;
#: ``geometry.ego_parts`` tells such tracks).
BOTTOM_SHARE = 0.01


def detect_dashboard_rows(
    frames: Iterable[np.ndarray],
    max_frames: int = 12,
    min_coverage: float = 0.6,
    max_step_px: float = 12.0,
    boxes: Sequence[np.ndarray] | None = None,
) -> int:
    """Rows at the bottom of the frame covered by the car's own bonnet/dashboard, full-frame pixels.

    From :func:`bonnet_contour` (frames spanning a second or more of driving) and
    :func:`dashboard_rows_from_contour`; 0 when unsure (masking too little costs less than masking road)
    and for a stopped camera, where nothing tells the bonnet from the road. ``boxes``: each frame's road users
    (:func:`bonnet_contour`).
    """
    contour = bonnet_contour(frames, max_frames=max_frames, boxes=boxes)
    return dashboard_rows_from_contour(contour, min_coverage, max_step_px)


#: A bonnet's or dashboard's top is highest at the image's centre by at most this share of the frame's height above
#: its top at the sides (its bulge: 0-45 px of 720 on the labelled clips, ``bench/labels/bonnet_rows.json``). A central
#: persistent edge further above the contour found at the sides is something in front (a car followed at a steady gap,
#: a windscreen reflection): dad_000487 re-encoded claimed 230 rows of road there (its bonnet 50), and its ego-motion
#: found no road point under the mask (0 km/h for a 46 km/h ride).
MAX_BONNET_BULGE = 0.12


def dashboard_rows_from_contour(
    contour: BonnetContour | None, min_coverage: float = 0.6, max_step_px: float = 12.0
) -> int:
    """Rows below the bonnet contour's highest point in the central half of the image, px.

    The contour must be found in at least ``min_coverage`` of the column bins of the central half
    and be smooth there (median step between neighbouring found bins at most ``max_step_px``
    full-frame px, after a running median of 3 bins: a bin off on its own, a dashboard's vent or a
    reflection, is no roughness; ccd_000031 cut 1.5 s before its crash had read 0 rows, its steps' median 20 px
    over a dashboard stepping between two structures, with it 98 against the label's 130); otherwise 0 (no
    bonnet claimed). Bins more than ``3 * max_step_px`` from the
    contour's median are left out before the highest point is taken, so that a short persistent edge
    above the bonnet (the tail lights of a car followed at a constant gap) does not pull it up; a central top more
    than ``MAX_BONNET_BULGE`` of the frame's height above the median of the bins found outside the central half
    (at least two) is no bonnet either (0).
    """
    if contour is None:
        return 0
    n = len(contour.top_px)
    centre = np.zeros(n, bool)
    centre[n // 4 : 3 * n // 4] = True
    ok = np.isfinite(contour.top_px)
    if ok[centre].mean() < min_coverage:
        return 0
    from scipy.ndimage import median_filter  # (SciPy loads in the background while the frames flow)

    # a bin off on its own (a dashboard's vent, a reflection) is no roughness of the contour
    steps = np.abs(np.diff(median_filter(contour.top_px[ok & centre], size=3, mode="nearest")))
    if steps.size and float(np.median(steps)) > max_step_px:
        return 0
    central = contour.top_px[ok & centre]
    kept = central[np.abs(central - np.median(central)) <= 3.0 * max_step_px]
    sides = contour.top_px[ok & ~centre]
    if len(sides) >= 2 and float(np.median(sides)) - float(kept.min()) > MAX_BONNET_BULGE * contour.frame_height:
        return 0  # the central edge stands far above the bonnet beside it: something in front, not the bonnet
    return max(0, int(math.ceil(contour.frame_height - float(kept.min()))))


def camera_for_video(
    width: int,
    height: int,
    yaml_path: str | Path | None = None,
    hfov_deg: float | None = None,
    chessboard: str | Path | None = None,
    height_m: float | None = None,
    area: tuple[int, int, int, int] | None = None,
) -> Camera:
    """The camera of a video of ``width`` x ``height`` pixels from whichever source the user gave.

    Priority: a camera YAML, then chessboard photos (scaled when the photos' size differs from the
    video's), then a horizontal field of view, else :func:`default_camera`. ``height_m`` (camera
    height above the road) overrides the source's. ``area``: the picture ``(x0, y0, x1, y1)`` (px) inside
    black bars (:mod:`deepcrashtest.video.bars`): a field of view (given or default) spans it, centred on it.
    """
    if yaml_path is not None:
        cam = camera_from_yaml(yaml_path, width, height)
        if not (0 <= cam.cx <= width and 0 <= cam.cy <= height):
            raise UserError(
                f"{yaml_path}: principal point (cx, cy) = ({cam.cx:g}, {cam.cy:g}) px lies outside the "
                f"{width}x{height} frame (a camera file for another resolution?)"
            )
    elif chessboard is not None:
        cam, _, _ = calibrate_chessboard(chessboard)
        first = next(p for p in sorted(Path(chessboard).iterdir()) if p.suffix.lower() in {".jpg", ".jpeg", ".png"})
        photo = cv2.imread(str(first))
        if photo is not None and photo.shape[1] != width:
            cam = scale_camera(cam, width / photo.shape[1], height / photo.shape[0])
    elif hfov_deg is not None:
        cam = _on_picture(width, height, hfov_deg, area)
    else:
        cam = default_camera(width, height, area=area)
    if height_m is not None:
        if not 0 < height_m <= MAX_CAMERA_HEIGHT_M:  # NaN and inf too (the Camera model's limit)
            raise UserError(f"camera height must be > 0 and <= {MAX_CAMERA_HEIGHT_M:g} m (got {height_m})")
        cam = cam.model_copy(update={"height_m": float(height_m), "height_source": "user"})
    return cam
