"""Monocular 3D tracking in the ground plane: image tracks + camera + ego poses -> world tracks.

Input: the image tracker's table (one row per track per frame, columns of
:data:`deepcrashtest.geometry.world_tracks.TRACK_COLUMNS`), the camera and the ego's camera path
(:class:`~deepcrashtest.geometry.egomotion.EgoMotion`: camera positions in the world frame, x
forward, y left, metres; yaw radians). Output: one row per track per frame with the vehicle's
centre on the road in the same world frame, its velocity, heading and one size per track.

Per track:

1. **Depth cues** of every detected box (camera frame, z forward, metres), each with a relative
   1-sigma error:

   * bottom edge on the road: ``Z = fy h / (v_bottom - v_horizon)``; its relative error is the
     bottom edge's pixel error over ``v_bottom - v_horizon`` (growing with range) and the road's
     unknown height under the vehicle relative to the camera's road (``road_height_rel`` of ``h``:
     real roads are not flat; on the KITTI labels the road under a car 10-20 m ahead lies
     1.37-1.86 m below the camera, 10th-90th percentile). Unused where the box is cut at the bottom.
   * box height: ``Z = fy H / box_height`` with the track's height ``H``, times :func:`hull_factor`
     (a vehicle lower than the camera shows its roof: the box's top edge is the roof's far edge);
     unused where the box is cut at the top or bottom.
   * box width: ``Z = fx W_app / box_width``, ``W_app = L |sin a| + W |cos a|`` the vehicle's width
     seen at view angle ``a`` (its heading against the line of sight); unused where cut at a side.

2. **One size per track**: the height the bottom-edge cue implies in each frame
   (``box_height Z_bottom / fy``) is pooled over the track (inverse-variance, in log) with the class
   prior of each candidate class (car, van, truck, bus, motorcycle, bicycle, pedestrian, see
   :data:`CANDIDATES`); the class whose prior explains the pooled height best is kept, and its
   posterior height is then fused, where the camera's height is measured or self-calibrated, with the
   height its near ground contacts imply (boxes whose bottom edge lies far below the horizon, where the
   bottom edge gives the depth to a few per cent: :func:`contact_height`, their shared error
   :func:`contact_floor`) and scales its length and width. The
   same pooling gives the width cue's scale.

3. The cues are fused per frame by inverse variance (in log depth); the visible face is moved to
   the vehicle's centre (half its extent along the line of sight) and into the world frame with
   that frame's ego pose. The measurement covariance is the range error along the line of sight
   and the bearing error across it.

4. A constant-velocity Kalman filter (``filterpy.kalman.KalmanFilter``: x, y, vx, vy in the world
   frame; white-noise acceleration) runs over every frame from the track's first to its last
   detection, with the range-dependent covariance of each measurement, and a Rauch-Tung-Striebel
   smoother (``KalmanFilter.rts_smoother``) gives the final states: extraction is offline, so every
   state uses the whole track. Frames without a detection are predicted (and smoothed). A measurement further
   than ``gate_chi2`` from the prediction is left out; when every measurement of ``gate_reset_s`` has been left
   out, the filter restarts at the next one (a road user that turned: the prediction had left it).

5. **Standing vehicles** (:func:`_static_fit`): a track the filter finds (nearly) standing is fitted once more
   as one ground point seen from each frame's camera pose: its bearing in every frame and its box heights (one
   height for the track) fix its range by the parallax of the ego's own motion, which does not rest on the
   class's size. Kept where that parallax is large and the fit good; the track then stands at that point.

The filter is filterpy's (a maintained, plain-numpy Kalman filter with per-step R/F/Q and an RTS
smoother) rather than a hand-written one; the motion is constant velocity in the ground plane
because the ego's motion is removed first, so parked cars stand still and a straight-driving car
moves uniformly whatever the ego does.
"""

from __future__ import annotations

import math
from collections import Counter
from collections.abc import Sequence
from dataclasses import dataclass, replace

import numpy as np
import pandas as pd
from filterpy.kalman import KalmanFilter
from scipy.ndimage import median_filter

from deepcrashtest.geometry.egomotion import EgoMotion
from deepcrashtest.geometry.mono_config import (
    CANDIDATES,
    Cues,
    MonoConfig,
    RoadProfile,
    class_size,
    width_cue_sigma,
)
from deepcrashtest.geometry.mono_size import box_cues, hull_factor, size_scale, track_size, width_m
from deepcrashtest.geometry.standing import StandingFit, StandingNoise, Views, fit_standing
from deepcrashtest.perception.roadusers import track_category
from deepcrashtest.scenario import Camera, frame_video_time

OUTPUT_COLUMNS = (
    "frame", "time", "track_id", "category", "x", "y", "vx", "vy", "yaw", "speed",
    "length", "width", "height", "range", "detected", "x1", "y1", "x2", "y2", "score", "horizon_v",
)  # fmt: skip


def frame_horizon(
    frames: np.ndarray,
    v_bottom: np.ndarray,
    z_size: np.ndarray,
    camera: Camera,
    vh: float | np.ndarray,
    shrink: float = 2.0,
    road: RoadProfile | None = None,
) -> np.ndarray:
    """Per-row horizon (px): the frame's pitch wobble estimated from all its boxes.

    Each uncut box whose depth ``z_size`` (m) is known from its track's size implies a horizon row
    ``v_bottom - fy h / z_size``; the frame's median offset from ``vh`` (shrunk towards 0 by
    ``n / (n + shrink)`` for n boxes, then a running median of 3 over the frames with boxes, and interpolated for
    the frames between them: a video's detector runs every few frames) is added to ``vh``. ``vh``: one
    row, or one per box (the camera's pitch at each box's frame). ``road``: the road's drop against range (None:
    the camera's height everywhere)."""
    drop = camera.height_m if road is None else camera.height_m * road.ratio(z_size)
    implied = v_bottom - camera.fy * drop / z_size
    ok = np.isfinite(implied)
    vh = np.broadcast_to(np.asarray(vh, dtype=float), implied.shape)
    uniq, inv = np.unique(frames, return_inverse=True)
    off = np.zeros(len(uniq))
    seen = np.zeros(len(uniq), bool)
    for k in range(len(uniq)):
        m = ok & (inv == k)
        n = int(m.sum())
        if n:
            off[k] = float(np.median(implied[m] - vh[m])) * n / (n + shrink)
            seen[k] = True
    # over the frames that measured it: a video's detector runs every few frames
    off[seen] = median_filter(off[seen], size=3, mode="nearest")
    if seen.any() and not seen.all():  # frames between detections: linearly between their neighbours' offsets
        off[~seen] = _between_measured(uniq[~seen], uniq[seen], off[seen])
    return vh + off[inv]


#: :func:`frame_horizon` carries its offset across at most this many frames without a box (a video's detector
#: runs every 2-6 frames); a longer gap (no road user in view) keeps the camera's horizon.
HORIZON_GAP_FRAMES = 8


def _between_measured(frames: np.ndarray, measured: np.ndarray, offsets: np.ndarray) -> np.ndarray:
    """The offsets (px) at ``frames`` between the ``measured`` frames (sorted) linearly interpolated where the
    measured frames either side are at most :data:`HORIZON_GAP_FRAMES` apart (held within that many frames before the
    first and after the last), else 0."""
    out = np.interp(frames, measured, offsets)
    k = np.searchsorted(measured, frames)
    before = np.where(k > 0, measured[np.maximum(k - 1, 0)], -np.inf)
    after = np.where(k < len(measured), measured[np.minimum(k, len(measured) - 1)], np.inf)
    near = np.where(
        np.isfinite(before) & np.isfinite(after),
        after - before <= HORIZON_GAP_FRAMES,
        np.minimum(frames - before, after - frames) <= HORIZON_GAP_FRAMES,
    )
    return np.where(near, out, 0.0)


def _fuse_depth(
    cues: Cues, rows: np.ndarray, size: tuple[float, float, float], h_rel: float, w_scale: float, w_rel: float,
    camera: Camera, cfg: MonoConfig, width_sigma: float, edges: np.ndarray | None = None,
    rel_yaw: np.ndarray | None = None,
) -> tuple[np.ndarray, np.ndarray]:  # fmt: skip
    """Fused depth of the visible face (m) and its relative sigma, per row (``width_sigma``: the width cue's relative
    sigma, :func:`~deepcrashtest.geometry.mono_config.width_cue_sigma`; ``edges``, ``rel_yaw``: :func:`width_m`)."""
    length, width, height = size
    z_h = _height_depth(cues, rows, ("", length, width, height), camera, cfg)
    r_h = np.hypot(h_rel, cfg.height_sigma_px / cues.box_h[rows])
    z_h[cues.cut_v[rows]] = np.nan
    app = w_scale * width_m(length, width, cues, rows, camera, cfg, edges, rel_yaw)
    z_w = camera.fx * app / cues.box_w[rows]
    r_w = np.hypot(w_rel, np.hypot(width_sigma, cfg.height_sigma_px / cues.box_w[rows]))
    z_w[cues.cut_u[rows]] = np.nan
    num = np.zeros(len(rows))
    den = np.zeros(len(rows))
    for z, r in ((cues.z_bottom[rows], cues.r_bottom[rows]), (z_h, r_h), (z_w, r_w)):
        ok = np.isfinite(z) & (z > 0)
        w = np.where(ok, 1.0 / np.maximum(np.nan_to_num(r, nan=1.0), 1e-3) ** 2, 0.0)
        num += w * np.log(np.where(ok, z, 1.0))
        den += w
    z = np.where(den > 0, np.exp(num / np.maximum(den, 1e-12)), np.nan)
    return z, 1.0 / np.sqrt(np.maximum(den, 1e-12))


def _motion_model(kf: KalmanFilter, dt: float, accel_std: float) -> None:
    """Constant-velocity transition and white-acceleration noise (``accel_std``, m/s^2) over ``dt`` seconds."""
    kf.F = np.array([[1, 0, dt, 0], [0, 1, 0, dt], [0, 0, 1, 0], [0, 0, 0, 1]], float)
    g = np.array([[dt**2 / 2, 0], [0, dt**2 / 2], [dt, 0], [0, dt]])
    kf.Q = g @ g.T * accel_std**2


def _kalman(
    frames: np.ndarray,
    meas: np.ndarray,
    covs: np.ndarray,
    fps: float,
    cfg: MonoConfig,
    frame_t: np.ndarray | None = None,
) -> tuple[np.ndarray, np.ndarray]:
    """CV Kalman filter + RTS smoother over frames ``frames[0]..frames[-1]``; ``meas`` (n, 2) world xy
    at ``frames`` (NaN rows: no measurement), ``covs`` (n, 2, 2). Returns (all frames, states (m, 4)).
    ``frame_t``: the video time (s) of every frame index, where the frames are not ``1 / fps`` apart (a
    variable-frame-rate video: each step then spans its own interval); None: ``1 / fps`` each."""
    span = np.arange(frames[0], frames[-1] + 1)
    at = {int(f): i for i, f in enumerate(frames)}
    dt = 1.0 / fps
    steps = np.diff(frame_t[span]) if frame_t is not None else None
    kf = KalmanFilter(dim_x=4, dim_z=2)
    _motion_model(kf, dt, cfg.accel_std)
    kf.H = np.array([[1, 0, 0, 0], [0, 1, 0, 0]], float)
    first = int(np.nonzero(np.isfinite(meas[:, 0]))[0][0])  # rows before it: carried (smoothed back)
    lead_s = _elapsed(int(frames[0]), int(frames[first]), dt, frame_t)
    _restart(kf, meas[first], covs[first] + np.eye(2) * (cfg.init_speed_std * lead_s) ** 2, cfg.init_speed_std)
    xs = np.zeros((len(span), 4))
    ps = np.zeros((len(span), 4, 4))
    fs = np.zeros((len(span), 4, 4)) if steps is not None else None  # each step's transition (frames unevenly apart)
    qs = np.zeros((len(span), 4, 4)) if steps is not None else None
    updates = 0
    gated: list[int] = []  # frames of the measurements gated out since the last one taken
    for k, f in enumerate(span):
        if k:
            if steps is not None:
                _motion_model(kf, float(steps[k - 1]), cfg.accel_std)
            kf.predict()
        if fs is not None and qs is not None:
            fs[k], qs[k] = kf.F, kf.Q
        i = at.get(int(f))
        if i is not None and np.isfinite(meas[i, 0]):
            resid = meas[i] - kf.H @ kf.x
            S = kf.H @ kf.P @ kf.H.T + covs[i]
            if updates < 3 or float(resid @ np.linalg.solve(S, resid)) < cfg.gate_chi2:
                kf.update(meas[i], R=covs[i])
                updates += 1
                gated = []
            elif (
                len(gated) >= 2
                and cfg.gate_reset_s is not None
                and _elapsed(gated[0], f, dt, frame_t) >= cfg.gate_reset_s
            ):
                _restart(kf, meas[i], covs[i], cfg.init_speed_std)  # the prediction has left the road user
                updates, gated = 1, []
            else:
                gated.append(int(f))
        xs[k], ps[k] = kf.x, kf.P
    if len(span) > 1:
        # the transition into step k is fs[k] (filterpy's smoother takes Fs[k + 1] from step k)
        xs, _, _, _ = kf.rts_smoother(xs[:, :, None], ps, fs, qs)  # None: the filter's own F and Q throughout
        xs = xs[:, :, 0]
    return span, xs


def _elapsed(f0: int, f1: int, dt: float, frame_t: np.ndarray | None) -> float:
    """Seconds from frame ``f0`` to frame ``f1``: ``dt`` a frame, or ``frame_t``'s own times."""
    return (f1 - f0) * dt if frame_t is None else float(frame_t[f1] - frame_t[f0])


def _restart(kf: KalmanFilter, z: np.ndarray, cov: np.ndarray, speed_std: float) -> None:
    """(Re)start the filter at measurement ``z`` (position covariance ``cov``), the velocity unknown."""
    kf.x = np.array([z[0], z[1], 0.0, 0.0])
    kf.P = np.zeros((4, 4))
    kf.P[:2, :2] = cov
    kf.P[2, 2] = kf.P[3, 3] = speed_std**2


@dataclass
class _Rows:
    """The rows of all tracks, sorted by track then frame, with their ego index and per-track spans."""

    df: pd.DataFrame
    boxes: np.ndarray
    detected: np.ndarray
    frames: np.ndarray
    ego_i: np.ndarray
    spans: list[tuple[int, int]]
    classes: list[str]  # each track's class as the detector reports it (:func:`track_category` of its rows)


def _rows(tracks: pd.DataFrame, ego: EgoMotion) -> _Rows:
    frame_to_i = {int(f): i for i, f in enumerate(ego.frame)}
    df = tracks[tracks["frame"].isin(frame_to_i.keys())].sort_values(["track_id", "frame"])
    df = df.drop_duplicates(["track_id", "frame"])
    if "state" not in df.columns:
        df = df.assign(state="detected")
    if "score" not in df.columns:
        df = df.assign(score=1.0)
    tid = df["track_id"].to_numpy()
    starts = np.r_[0, np.nonzero(np.diff(tid))[0] + 1, len(df)] if len(df) else np.zeros(1, int)
    spans = [(int(a), int(b)) for a, b in zip(starts[:-1], starts[1:], strict=True)]
    cats = df["category"].to_numpy(dtype=str)
    return _Rows(
        df=df,
        boxes=df[["x1", "y1", "x2", "y2"]].to_numpy(float),
        detected=(df["state"] == "detected").to_numpy(),
        frames=df["frame"].to_numpy(int),
        ego_i=np.array([frame_to_i[int(f)] for f in df["frame"]], dtype=int),
        spans=spans,
        classes=[track_category(Counter(cats[a:b].tolist())) for a, b in spans],
    )


def _sizes_and_cues(
    r: _Rows, camera: Camera, image_size: tuple[int, int], vh: np.ndarray, cfg: MonoConfig
) -> tuple[list, Cues, np.ndarray, RoadProfile | None]:
    """Each track's size (:func:`track_size`), the rows' cues, horizon rows (px): ``vh`` (per row)
    moved by the per-frame horizon of the boxes (:func:`frame_horizon`), and the road profile the cues
    read the bottom edges on (:func:`road_profile`, where ``cfg.road_profile``; else None)."""
    cues = box_cues(r.boxes, camera, image_size, vh, cfg)
    scale = size_scale(r.df, cues, r.detected, camera, cfg.size_scale_min_below_px) * cfg.prior_scale

    def sizes(choose: bool) -> list:
        c_cfg = cfg if choose else replace(cfg, contact_far_below_px=None)  # the horizon's sizes: near contacts only
        return [
            track_size(c, cues, np.arange(a, b), r.detected, camera, c_cfg, scale, choose)
            for c, (a, b) in zip(r.classes, r.spans, strict=True)
        ]

    if not cfg.frame_horizon:
        return sizes(True), cues, vh, None
    first = sizes(False)  # the detector's classes first: the horizon must not depend on the class choice
    z_size = np.full(len(r.df), np.nan)
    for (a, b), sz in zip(r.spans, first, strict=True):
        rows = np.arange(a, b)
        z_size[a:b] = (
            _height_depth(cues, rows, sz, camera, cfg) if cfg.horizon_hull else camera.fy * sz[3] / cues.box_h[a:b]
        )
    z_size[~r.detected | cues.cut_v] = np.nan
    vh_rows = frame_horizon(r.frames, r.boxes[:, 3], z_size, camera, vh, cfg.horizon_shrink)
    cues = box_cues(r.boxes, camera, image_size, vh_rows, cfg)
    road = road_profile(r, cues, first, camera, cfg) if cfg.road_profile else None
    if road is not None:
        vh_rows = frame_horizon(r.frames, r.boxes[:, 3], z_size, camera, vh, cfg.horizon_shrink, road)
        cues = box_cues(r.boxes, camera, image_size, vh_rows, cfg, road)
    return sizes(True), cues, vh_rows, road


def road_profile_of(
    tracks: pd.DataFrame, camera: Camera, ego: EgoMotion, image_size: tuple[int, int], config: MonoConfig
) -> RoadProfile | None:
    """The road profile :func:`localize_tracks` reads the bottom edges on with ``config`` (at the clip's
    horizon; None: ``road_profile`` off or too few rows)."""
    r = _rows(tracks, ego)
    return _sizes_and_cues(r, camera, image_size, np.full(len(r.df), camera.horizon_v()), config)[3]


def _height_depth(cues: Cues, rows: np.ndarray, size: tuple, camera: Camera, cfg: MonoConfig) -> np.ndarray:
    """Depth (m) of the near face of ``rows`` from their box heights with the track's ``size`` (class, length,
    width, height, ...), the roof's far edge removed (:func:`hull_factor`, fixed point) where ``hull_height``."""
    _, length, width, height = size[:4]
    z_h = camera.fy * height / cues.box_h[rows]
    if cfg.hull_height:
        for _ in range(3):  # the roof's far edge: the box is taller than the near face (fixed point)
            hull = hull_factor(height, length, width, camera.height_m, z_h, cues.bearing[rows])
            z_h = camera.fy * height * hull / cues.box_h[rows]
    return z_h


def road_profile(r: _Rows, cues: Cues, sizes: list, camera: Camera, cfg: MonoConfig) -> RoadProfile | None:
    """The road's drop below the camera against range, from the tracks themselves (None: too few rows).

    Each detected uncut box with a bottom-edge cue reads the road's drop under it as ``below Z_h / fy`` (``below``
    its bottom row under the horizon, px; ``Z_h`` its depth from its box height with its track's height,
    :func:`_height_depth`). A track's height is wrong by one factor, the same in all its frames, so the log drops
    are fitted as one offset per track (removed by subtracting each track's mean) plus a profile ``f(Z)``:
    piecewise linear through ``road_knots_m``, 0 up to ``road_ref_m`` (the camera's height there), each knot
    pulled to 0 by ``road_knot_sigma``. Only tracks seen over a range of depths inform it (a far road higher
    or lower than the camera's, or a crest, makes a receding car's bottom rows creep against its box
    heights). Each row weighs ``1 / sqrt(n)`` for a track of n rows; rows off the first fit by more than 0.15
    (log) are dropped once."""
    knots = np.array((cfg.road_ref_m, *cfg.road_knots_m))
    y_parts, b_parts, w_parts = [], [], []
    for (a, b), size in zip(r.spans, sizes, strict=True):
        rows = np.arange(a, b)
        rows = rows[r.detected[rows] & ~cues.cut_v[rows] & np.isfinite(cues.z_bottom[rows])]
        if len(rows) < 3:
            continue
        z_h = _height_depth(cues, rows, size, camera, cfg)
        below = camera.fy * camera.height_m / cues.z_bottom[rows]
        y = np.log(np.maximum(below * z_h / camera.fy, 1e-3) / camera.height_m)
        basis = _hat_basis(z_h, knots)
        y_parts.append(y - y.mean())
        b_parts.append(basis - basis.mean(axis=0))
        w_parts.append(np.full(len(rows), 1.0 / math.sqrt(len(rows))))
    if not y_parts or sum(len(y) for y in y_parts) < cfg.road_min_rows:
        return None
    y, basis, w = np.concatenate(y_parts), np.vstack(b_parts), np.concatenate(w_parts)
    keep = np.ones(len(y), bool)
    for _ in range(2):
        f = _ridge(basis[keep], y[keep], w[keep], cfg.road_knot_sigma, 0.05)
        keep = np.abs(y - basis @ f) < 0.15
    return RoadProfile(tuple(float(k) for k in knots), (0.0, *(float(v) for v in f)))


def _hat_basis(z: np.ndarray, knots: np.ndarray) -> np.ndarray:
    """(n, len(knots) - 1) weights of the knots after the first for piecewise-linear interpolation at ``z``
    (the first knot's value is fixed at 0; flat before it and past the last)."""
    eye = np.eye(len(knots))
    return np.column_stack([np.interp(z, knots, eye[k]) for k in range(1, len(knots))])


def _ridge(basis: np.ndarray, y: np.ndarray, w: np.ndarray, prior_sigma: float, row_sigma: float) -> np.ndarray:
    """Weighted least squares ``basis f = y`` (rows' 1-sigma ``row_sigma / w``) with a 0-mean prior on each f."""
    a = np.vstack([basis * (w / row_sigma)[:, None], np.eye(basis.shape[1]) / prior_sigma])
    rhs = np.r_[y * w / row_sigma, np.zeros(basis.shape[1])]
    return np.linalg.lstsq(a, rhs, rcond=None)[0]


def _measurements(
    rows: np.ndarray, size: tuple, cues: Cues, r: _Rows, ego: EgoMotion, camera: Camera, cfg: MonoConfig,
    width_sigma: float, edges: np.ndarray | None = None, rel_yaw: np.ndarray | None = None,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:  # fmt: skip
    """World-frame centres (n, 2; NaN: no measurement), their covariances (n, 2, 2) and the
    camera-to-centre ranges (n,) of one track's rows (``width_sigma``: :func:`_fuse_depth`'s; ``edges``,
    ``rel_yaw``: :func:`width_m`)."""
    _, length, width, height, h_rel, w_scale, w_rel = size
    z_near, rel = _fuse_depth(
        cues, rows, (length, width, height), h_rel, w_scale, w_rel, camera, cfg, width_sigma, edges, rel_yaw
    )
    bearing = cues.bearing[rows]
    a = np.arctan(bearing)
    off = 0.5 * (length * np.abs(np.cos(a)) + width * np.abs(np.sin(a)))
    ray = np.column_stack([bearing, np.ones(len(rows))])
    ray /= np.linalg.norm(ray, axis=1, keepdims=True)
    near = np.column_stack([bearing * z_near, z_near])
    centre = near + off[:, None] * ray  # camera frame (x right, z forward)
    rng = np.linalg.norm(centre, axis=1)
    ei = r.ego_i[rows]
    yaw_e = ego.yaw[ei]
    c, s = np.cos(yaw_e), np.sin(yaw_e)
    fwd, left = centre[:, 1], -centre[:, 0]
    meas = np.column_stack([ego.x[ei] + c * fwd - s * left, ego.y[ei] + s * fwd + c * left])
    meas[~r.detected[rows] | ~np.isfinite(z_near)] = np.nan
    # covariance: range error along the line of sight, bearing error across it (world frame)
    sig_r = np.linalg.norm(near, axis=1) * np.nan_to_num(rel, nan=1.0)
    sig_c = rng * cfg.bearing_sigma_px / camera.fx
    ang = yaw_e + np.arctan2(-ray[:, 0], ray[:, 1])
    u = np.column_stack([np.cos(ang), np.sin(ang)])
    v = np.column_stack([-u[:, 1], u[:, 0]])
    covs = sig_r[:, None, None] ** 2 * u[:, :, None] * u[:, None, :]
    covs += sig_c[:, None, None] ** 2 * v[:, :, None] * v[:, None, :]
    return meas, covs, rng


def _static_fit(
    rows: np.ndarray, xs: np.ndarray, size: tuple, cues: Cues, r: _Rows, ego: EgoMotion, camera: Camera,
    cfg: MonoConfig,
) -> np.ndarray | None:  # fmt: skip
    """World ground position (x, y m) of a standing vehicle from its whole track (:func:`_standing_fit` with the
    track's size), or None: no standing fit, or its size far from the track's (``static_max_size_dev``)."""
    fit = _standing_fit(rows, xs, size, cues, r, ego, camera, cfg, cfg.static_size_rel)
    return fit.xy if fit is not None and abs(fit.log_scale) <= cfg.static_max_size_dev else None


def _standing_fit(
    rows: np.ndarray, xs: np.ndarray, size: tuple, cues: Cues, r: _Rows, ego: EgoMotion, camera: Camera,
    cfg: MonoConfig, size_rel: float,
) -> StandingFit | None:  # fmt: skip
    """:func:`~deepcrashtest.geometry.standing.fit_standing` on a track's detected, uncut boxes (its height scale's
    prior the track's size, relative sigma ``size_rel``), or None: the first pass ``xs`` (n, 4) not slow, too few
    boxes, the fit poor or too little parallax (``MonoConfig.static_*``)."""
    if np.median(np.hypot(xs[:, 2], xs[:, 3])) > cfg.static_max_speed:
        return None
    use = r.detected[rows] & ~cues.cut_v[rows] & ~cues.cut_u[rows]
    if use.sum() < cfg.static_min_rows:
        return None
    noise = StandingNoise(cfg.bearing_sigma_px / camera.fx, cfg.height_sigma_px, cfg.static_height_rel, size_rel)
    fit = fit_standing(
        track_views(rows[use], cues, r, ego), size[1:3], math.log(camera.fy * size[3]), np.median(xs[:, :2], axis=0),
        noise,
    )  # fmt: skip
    if fit is None or fit.chi2 > cfg.static_max_chi2 or fit.parallax_rad < cfg.static_min_parallax_rad:
        return None
    return fit


def _standing_class(
    rows: np.ndarray, xs: np.ndarray, size: tuple, cues: Cues, r: _Rows, ego: EgoMotion, camera: Camera,
    cfg: MonoConfig, detector_class: str,
) -> tuple:  # fmt: skip
    """The track's size (:func:`track_size`'s tuple) with, for a standing vehicle whose detector class has other
    candidates (:data:`CANDIDATES`: car or van), the class whose height (scaled like the track's) is nearest in
    log to the height its standing fit measures with a loose size prior (``static_class_rel``); a class other
    than the detector's costs ``static_class_switch`` (log)."""
    candidates = CANDIDATES.get(detector_class, (size[0],))
    fit = (
        _standing_fit(rows, xs, size, cues, r, ego, camera, cfg, cfg.static_class_rel) if len(candidates) > 1 else None
    )
    if fit is None:
        return size
    scale = size[3] / class_size(size[0])[2]
    log_h = math.log(size[3]) + fit.log_scale

    def miss(cls: str) -> float:
        switch = 0.0 if cls == detector_class else cfg.static_class_switch
        return abs(log_h - math.log(scale * class_size(cls)[2])) + switch

    cls = min(candidates, key=miss)
    if cls == size[0]:
        return size
    length, width, height = (scale * v for v in class_size(cls))
    return (cls, length, width, height, *size[4:])


def track_views(rows: np.ndarray, cues: Cues, r: _Rows, ego: EgoMotion) -> Views:
    """The :class:`~deepcrashtest.geometry.standing.Views` of rows ``rows``."""
    ei = r.ego_i[rows]
    return Views(ego.x[ei], ego.y[ei], ego.yaw[ei], cues.bearing[rows], cues.box_h[rows])


def _heading_against_axis(xs: np.ndarray, ego_i: np.ndarray, ego: EgoMotion) -> tuple[np.ndarray, np.ndarray]:
    """Per row of a track's filtered states ``xs`` (n, 4: x, y, vx, vy world m, m/s): its heading left of the
    camera's axis (rad) and its speed (m/s), for the width geometry of its second pass."""
    return np.arctan2(xs[:, 3], xs[:, 2]) - ego.yaw[ego_i], np.hypot(xs[:, 2], xs[:, 3])


def _heading_along(rel: np.ndarray, speed: np.ndarray, cfg: MonoConfig) -> np.ndarray | None:
    """Per row (``rel``, ``speed``: :func:`_heading_against_axis`): whether the vehicle heads along the camera's
    axis or against it within ``cfg.width_edges_along_deg``, or is slower than ``cfg.along_min_speed`` (m/s);
    None when the option is off."""
    if cfg.width_edges_along_deg <= 0:
        return None
    slow = speed < cfg.along_min_speed
    return slow | (np.abs(np.sin(rel)) <= math.sin(math.radians(cfg.width_edges_along_deg)))


def _oblique_yaw(rel: np.ndarray, speed: np.ndarray, along: np.ndarray | None, cfg: MonoConfig) -> np.ndarray | None:
    """Per row (``rel``, ``speed``: :func:`_heading_against_axis`): its heading left of the camera's axis (rad)
    where ``cfg.width_oblique`` and the row is not ``along`` (NaN elsewhere); None when off or no such row."""
    if not cfg.width_oblique:
        return None
    other = np.ones(len(rel), bool) if along is None else ~along
    other &= speed >= cfg.oblique_min_speed
    return np.where(other, rel, np.nan) if other.any() else None


def _extension(
    x: np.ndarray, frame: int, step: int, ego: EgoMotion, camera: Camera, image_w: int, cfg: MonoConfig
) -> tuple[np.ndarray, np.ndarray]:
    """Frames and constant-velocity states (m, 4) carrying a track beyond its end (``step`` +1:
    after its last frame, -1: before its first) while it recedes from the camera, stays beyond
    ``extend_min_range_m`` and inside the field of view, for at most ``extend_s``: far away the
    detector loses a car before the labels do."""
    frames, states = [], []
    at = {int(f): i for i, f in enumerate(ego.frame)}
    half_fov = 0.5 * image_w / camera.fx
    prev_range = None
    n = int(round(cfg.extend_s * _fps(ego)))
    for k in range(1, n + 1):
        i = at.get(frame + step * k)
        if i is None:
            break
        dt = step * k / _fps(ego)
        px, py = x[0] + x[2] * dt, x[1] + x[3] * dt
        dx, dy = px - ego.x[i], py - ego.y[i]
        c, s = math.cos(ego.yaw[i]), math.sin(ego.yaw[i])
        fwd, left = c * dx + s * dy, -s * dx + c * dy
        rng = math.hypot(fwd, left)
        if fwd < cfg.extend_min_range_m or abs(left) > half_fov * fwd or (prev_range is not None and rng < prev_range):
            break
        prev_range = rng
        frames.append(frame + step * k)
        states.append([px, py, x[2], x[3]])
    return np.array(frames, dtype=int), np.array(states, dtype=float).reshape(-1, 4)


def _measured_span(valid: np.ndarray, det: np.ndarray, frames: np.ndarray, fps: float, carry_s: float) -> slice:
    """Rows of a track from its first to its last measured one (``valid``: indices of the measured rows),
    widened to the farthest detected rows (without a depth cue) at most ``carry_s`` seconds outside them
    (a detector run every few frames leaves predicted rows between them)."""
    reach = carry_s * fps
    near = np.nonzero(det & (np.abs(frames - frames[valid[0]]) <= reach) & (frames <= frames[valid[0]]))[0]
    far = np.nonzero(det & (np.abs(frames - frames[valid[-1]]) <= reach) & (frames >= frames[valid[-1]]))[0]
    first = int(near.min()) if len(near) else int(valid[0])
    return slice(first, int(far.max()) + 1 if len(far) else int(valid[-1]) + 1)


def _frame_clock(frame_times: Sequence[float] | None, last_frame: int, fps: float) -> np.ndarray | None:
    """The video time (s) of every frame index up to ``last_frame`` from a variable-rate video's frame times
    (:func:`deepcrashtest.scenario.frame_video_time`); None where the video's frames are evenly ``1 / fps`` apart
    (``frame_times`` None)."""
    if not frame_times:
        return None
    return np.array([frame_video_time(f, fps, frame_times) for f in range(last_frame + 1)])


def _fps(ego: EgoMotion) -> float:
    return float((len(ego.t) - 1) / max(ego.t[-1] - ego.t[0], 1e-9)) if len(ego.t) > 1 else 10.0


def localize_tracks(
    tracks: pd.DataFrame,
    camera: Camera,
    ego: EgoMotion,
    image_size: tuple[int, int],
    fps: float,
    config: MonoConfig | None = None,
    horizon_v: float | None = None,
    pitch_change: np.ndarray | None = None,
    frame_times: Sequence[float] | None = None,
) -> pd.DataFrame:
    """World-frame states of every track (columns :data:`OUTPUT_COLUMNS`), see the module docstring.

    ``tracks``: the image tracker's rows (``state`` 'detected' rows carry measurements; 'predicted'
    rows between detections are filled by the filter; rows before a track's first and after its last
    measured frame are dropped). ``ego``: the camera path, one entry per video frame in ``ego.frame``;
    rows of other frames are ignored. ``horizon_v``: the horizon row (pixels), else the camera's pitch
    gives it. ``pitch_change``: the camera's downward pitch at each of ``ego``'s frames minus its pitch
    (rad; :func:`~deepcrashtest.geometry.attitude.camera_wobble`), moving the horizon frame by frame.
    ``frame_times``: every video frame's time (s, by index) where the video's frame rate varies (the Scenario's
    ``source.frame_times``): the filter then steps each frame's own interval; None: ``1 / fps`` a frame.
    Positions are in the frame of ``ego.x``/``ego.y``; ``range`` is the camera-to-centre ground distance (m)
    of each row's measurement; ``horizon_v`` the horizon row (px) its box was read against (NaN: no box)."""
    cfg = config or MonoConfig()
    vh = camera.horizon_v() if horizon_v is None else float(horizon_v)
    frame_t = _frame_clock(frame_times, int(np.max(ego.frame, initial=0)), fps)
    r = _rows(tracks, ego)
    out: dict[str, list[np.ndarray]] = {c: [] for c in OUTPUT_COLUMNS}
    if len(r.df) == 0:
        return pd.DataFrame({c: [] for c in OUTPUT_COLUMNS})
    sizes, cues, vh_rows, _ = _sizes_and_cues(r, camera, image_size, np.full(len(r.df), vh), cfg)
    if pitch_change is not None:  # each frame's depth cues against the horizon of its pitch: cy - fy tan(pitch)
        base = math.atan2(camera.cy - vh, camera.fy)
        pitched = camera.cy - camera.fy * np.tan(base + np.asarray(pitch_change, dtype=float)[r.ego_i])
        # the sizes (and classes) stay those of the clip's horizon: they pool a track's frames, and a class
        # flip moves the whole track (ccd_000014's car with a roof box became a car, 4 m nearer, and its
        # crash no longer replayed)
        _, cues, vh_rows, _ = _sizes_and_cues(r, camera, image_size, pitched, cfg)
    for (s0, s1), size, detector_class in zip(r.spans, sizes, r.classes, strict=True):
        rows = np.arange(s0, s1)
        w_sigma = width_cue_sigma(detector_class, cfg)
        meas, covs, rng = _measurements(rows, size, cues, r, ego, camera, cfg, w_sigma)
        valid = np.nonzero(np.isfinite(meas[:, 0]))[0]
        if len(valid) == 0:
            continue
        inside = _measured_span(valid, r.detected[rows], r.frames[rows], fps, cfg.carry_cut_s)
        rows, meas, covs, rng = rows[inside], meas[inside], covs[inside], rng[inside]
        span = r.frames[rows]
        xs = _kalman(span, meas, covs, fps, cfg, frame_t)[1][span - span[0]]
        rel, speed = _heading_against_axis(xs, r.ego_i[rows], ego)
        along = _heading_along(rel, speed, cfg)
        turned = _oblique_yaw(rel, speed, along, cfg)
        if (along is not None and along.any()) or turned is not None:  # again with the heading's width geometry
            meas, covs, rng = _measurements(rows, size, cues, r, ego, camera, cfg, w_sigma, along, turned)
            xs = _kalman(span, meas, covs, fps, cfg, frame_t)[1][span - span[0]]
        standing = None
        if cfg.static_fit:  # the class its standing height fits only where it is placed standing
            trial = size
            if cfg.static_class:
                trial = _standing_class(rows, xs, size, cues, r, ego, camera, cfg, detector_class)
            standing = _static_fit(rows, xs, trial, cues, r, ego, camera, cfg)
            if standing is None and trial is not size:
                standing = _static_fit(rows, xs, size, cues, r, ego, camera, cfg)
            elif standing is not None:
                size = trial
        if standing is not None:
            xs = np.column_stack([np.tile(standing, (len(xs), 1)), np.zeros((len(xs), 2))])
        sub = r.df.iloc[rows]
        t = sub["time"].to_numpy(float)
        boxes = {k: sub[k].to_numpy(float) for k in ("x1", "y1", "x2", "y2", "score")}
        boxes["horizon_v"] = vh_rows[rows]
        det = r.detected[rows]
        if cfg.extend_s > 0:
            t_of = dict(zip(ego.frame.tolist(), ego.t.tolist(), strict=True))
            fb, sb = _extension(xs[0], int(span[0]), -1, ego, camera, image_size[0], cfg)
            fa, sa = _extension(xs[-1], int(span[-1]), 1, ego, camera, image_size[0], cfg)
            fb, sb = fb[::-1], sb[::-1]
            span, xs = np.r_[fb, span, fa], np.vstack([sb, xs, sa])
            t = np.r_[[t_of[int(f)] for f in fb], t, [t_of[int(f)] for f in fa]]
            pad = (np.full(len(fb), np.nan), np.full(len(fa), np.nan))
            boxes = {k: np.r_[pad[0], v, pad[1]] for k, v in boxes.items()}
            rng = np.r_[pad[0], rng, pad[1]]
            det = np.r_[np.zeros(len(fb), bool), det, np.zeros(len(fa), bool)]
        speed = np.hypot(xs[:, 2], xs[:, 3])
        yaw = np.where(speed > 1.5, np.arctan2(xs[:, 3], xs[:, 2]), np.interp(span, ego.frame, ego.yaw))
        n = len(span)
        cls, length, width, height = size[:4]
        cols = {
            "frame": span, "time": t, "track_id": np.full(n, int(sub["track_id"].iloc[0])),
            "category": np.full(n, cls, dtype=object), "x": xs[:, 0], "y": xs[:, 1], "vx": xs[:, 2],
            "vy": xs[:, 3], "yaw": np.unwrap(yaw), "speed": speed, "length": np.full(n, length),
            "width": np.full(n, width), "height": np.full(n, height), "range": rng, "detected": det,
        }  # fmt: skip
        cols |= boxes
        for k, v in cols.items():
            out[k].append(v)
    if not out["frame"]:
        return pd.DataFrame({c: [] for c in OUTPUT_COLUMNS})
    return pd.DataFrame({c: np.concatenate(v) for c, v in out.items()})
