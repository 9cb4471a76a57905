"""The column of the camera's forward axis (the principal point ``cx`` the localiser needs) from the video.

Every road user's bearing is measured from the column ``cx`` the ego's heading projects to; an
unknown camera's image centre misses it by 1-2 % of the width (KITTI: 11-19 px of 1242), which
turns into a lateral error of ``(cx error / f) Z``: 0.6 m at 40 m for 11 px, enough to miss a 2 m
gate once the range error adds to it (KITTI tracking 0008: world-frame MOTA 50.7 at the image
centre, 60.0 at the calibrated column).

Cue: road users drive along the road and parked ones stand beside it, so each keeps its lateral
offset from the ego's own path (the path is the road's direction; the ego follows it). A box's
outer edge (the side further from the image centre: the near corner of a vehicle ahead on that
side, a fixed point of it) at column ``u`` and depth ``Z = fy H / h`` (class height ``H``, box
height ``h``) lies ``X = (u - cx) Z / fy`` right of the camera; with the ego's pose it becomes a
world point and its signed offset ``d`` from the ego path (arc-length resampled, its tangent
smoothed). A wrong ``cx`` by ``delta`` moves ``d`` by ``delta a`` with ``a = -(r . n) Z / fy``
(``r`` the camera's right, ``n`` the path's left normal): linear. Per track ``d_k + delta a_k =
L`` (its constant offset); ``delta`` is common to all tracks, fitted robustly (Tukey weights, per-
track intercepts, weights ``(fy / Z)^2``: pixel noise). Vehicles turning, crossing or changing lane
are the outliers. The sigma is a bootstrap over tracks. Depth scale errors do not matter (they
scale a constant offset). With image-based ego-motion the path runs along the camera's heading
and ``cx`` becomes the column of the direction of travel, which is what the localiser needs there.
"""

from __future__ import annotations

import numpy as np
import pandas as pd

from deepcrashtest.geometry.egomotion import EgoMotion
from deepcrashtest.geometry.mono_config import class_size
from deepcrashtest.geometry.standing import StandingNoise, Views, fit_standing

#: Rows further than this (m, depth from the box height) are not used (pixel noise and the road's
#: curvature dominate); fewer usable tracks than MIN_TRACKS (of MIN_ROWS rows each) and nothing is
#: measured. Chosen on the 18 KITTI tracking training sequences other than 3, 8, 10 (unknown camera,
#: combined MOTA: 60 m / 3 tracks 38.68 at sigma x 2, 38.87 at x 4; 60 m / 10 tracks x 4 38.90;
#: 40 m / 10 tracks x 2 39.10, x 3 39.29, x 4 39.32 (measured on 9 of the 18); 30 m x 4 39.39 but on 8;
#: the image centre 39.09, the true column 40.13).
MAX_DEPTH_M = 40.0
MIN_ROWS = 8
MIN_TRACKS = 10
#: Rows whose point lies where the path has turned by more than this (deg) from where the camera is are not
#: used: there a depth error (focal length, class height) moves the point along the camera's axis, across
#: the bent path, and both sides' offsets shift the same way, like a column error (on a left bend, a range
#: read long puts every point right of the path). Chosen on the 18 KITTI tracking training sequences
#: other than 3, 8, 10 (``bench/axis_sweep.py``: column error rms over the 9 measured 7.5 px -> 6.7 px at 5 deg;
#: 3 deg 6.9 px, 8 deg 7.1 px; 0020 +6.7 -> +4.4 px, 0009 +3.9 -> +1.4 px).
MAX_PATH_TURN_DEG = 5.0
#: Path resampling step (m) and the Savitzky-Golay window (samples) smoothing its heading.
PATH_STEP_M = 1.0
PATH_SMOOTH = 11
MIN_PATH_M = 10.0
BOOTSTRAP = 30
TUKEY_C = 4.685


def _path(ego: EgoMotion) -> tuple[np.ndarray, np.ndarray, np.ndarray] | None:
    """The ego path resampled every ``PATH_STEP_M`` metres: (x, y, smoothed tangent heading rad)."""
    from scipy.signal import savgol_filter

    xy = np.column_stack([ego.x, ego.y])
    s = np.r_[0.0, np.cumsum(np.hypot(*np.diff(xy, axis=0).T))]
    if len(s) < 2 or s[-1] < MIN_PATH_M:
        return None
    g = np.arange(0.0, s[-1], PATH_STEP_M)
    px, py = np.interp(g, s, xy[:, 0]), np.interp(g, s, xy[:, 1])
    heading = np.unwrap(np.arctan2(np.gradient(py), np.gradient(px)))
    if len(heading) > PATH_SMOOTH:
        heading = savgol_filter(heading, PATH_SMOOTH, 2)
    return px, py, heading


def _track_offsets(
    g: pd.DataFrame, H: float, fy: float, cx0: float, ego: EgoMotion, idx: np.ndarray, path: tuple
) -> tuple[np.ndarray, np.ndarray, np.ndarray] | None:
    """One track's path offsets ``d`` (m) at ``cx0``, their slopes ``a`` against ``cx`` and weights."""
    px, py, heading = path
    h = (g["y2"] - g["y1"]).to_numpy(float)
    x1, x2 = g["x1"].to_numpy(float), g["x2"].to_numpy(float)
    u = np.where(0.5 * (x1 + x2) > cx0, x2, x1)  # the outer edge
    z = fy * H / h
    yaw = ego.yaw[idx]
    fwd = np.column_stack([np.cos(yaw), np.sin(yaw)])
    right = np.column_stack([np.sin(yaw), -np.cos(yaw)])
    w = np.column_stack([ego.x[idx], ego.y[idx]]) + z[:, None] * fwd + ((u - cx0) * z / fy)[:, None] * right
    j = np.hypot(w[:, :1] - px[None], w[:, 1:] - py[None]).argmin(axis=1)
    normal = np.column_stack([-np.sin(heading[j]), np.cos(heading[j])])
    d = np.sum((w - np.column_stack([px[j], py[j]])) * normal, axis=1)
    a = -np.sum(right * normal, axis=1) * z / fy
    jc = np.hypot(ego.x[idx, None] - px[None], ego.y[idx, None] - py[None]).argmin(axis=1)
    straight = np.abs(heading[j] - heading[jc]) < np.radians(MAX_PATH_TURN_DEG)  # see MAX_PATH_TURN_DEG
    ok = (j > 2) & (j < len(px) - 3) & (z < MAX_DEPTH_M) & straight  # beside the path, not past its ends
    if ok.sum() < MIN_ROWS:
        return None
    return d[ok], a[ok], (fy / z[ok]) ** 2


def _fit(parts: list[tuple[np.ndarray, np.ndarray, np.ndarray]], iters: int = 30) -> float:
    """Common shift ``delta`` (px) with per-track intercepts: ``d + delta a = L_track`` (Tukey IRLS)."""
    track = np.concatenate([np.full(len(p[0]), k) for k, p in enumerate(parts)])
    d, a, w0 = (np.concatenate([p[i] for p in parts]) for i in range(3))
    n = len(parts)
    w = w0.copy()
    delta = 0.0
    for _ in range(iters):
        sw = np.maximum(np.bincount(track, w, n), 1e-12)
        a_c = a - (np.bincount(track, w * a, n) / sw)[track]
        d_c = d - (np.bincount(track, w * d, n) / sw)[track]
        den = float(np.sum(w * a_c * a_c))
        if den <= 0:
            return 0.0
        delta = -float(np.sum(w * a_c * d_c)) / den
        r = (d_c + delta * a_c) * np.sqrt(w0)
        scale = TUKEY_C * (1.4826 * float(np.median(np.abs(r))) + 1e-9)
        w = w0 * np.where(np.abs(r) < scale, (1.0 - (r / scale) ** 2) ** 2, 0.0)
    return delta


def axis_column_from_path(
    boxes: pd.DataFrame, fy: float, cx0: float, ego: EgoMotion, height_excess: float = 1.0, seed: int = 0
) -> tuple[float, float, int] | None:
    """(column px of the ego's heading, its 1-sigma px, tracks used) from road users beside the ego
    path (see the module docstring); None with fewer than :data:`MIN_TRACKS` usable tracks or no path.

    ``boxes``: detected, uncut vehicle boxes of the tracks table; ``height_excess``: box height over
    the class height at the near face; ``cx0``: the current guess (it picks the outer edges; run
    twice to settle)."""
    path = _path(ego)
    if path is None:
        return None
    frame_to_i = {int(f): i for i, f in enumerate(ego.frame)}
    d = boxes[boxes["frame"].isin(frame_to_i.keys())]
    parts = []
    for _, g in d.groupby("track_id"):
        if len(g) < MIN_ROWS:
            continue
        idx = np.array([frame_to_i[int(f)] for f in g["frame"]])
        H = class_size(str(g["category"].iloc[0]))[2] * height_excess
        part = _track_offsets(g, H, fy, cx0, ego, idx, path)
        if part is not None:
            parts.append(part)
    if len(parts) < MIN_TRACKS:
        return None
    delta = _fit(parts)
    rng = np.random.default_rng(seed)
    boots = [_fit([parts[k] for k in rng.integers(0, len(parts), len(parts))], iters=10) for _ in range(BOOTSTRAP)]
    return cx0 + delta, float(np.std(boots)), len(parts)


#: Standing vehicles (:func:`axis_column_from_standing`): a track's fit counts where its mean squared
#: normalised residual, its height scale against the class's (log) and the turn of its line of sight (rad) pass
#: these (the gates of :class:`~deepcrashtest.geometry.mono_config.MonoConfig`'s standing-vehicle fit); the fewest
#: such tracks; the fit's row errors (bearing px, box height px and relative, the height scale's prior).
STANDING_MAX_CHI2 = 1.0
STANDING_MAX_SIZE_DEV = 0.3
STANDING_MIN_PARALLAX_RAD = 0.3
STANDING_MIN_TRACKS = 3
STANDING_NOISE_PX = (3.0, 0.4, 0.05, 0.15)


def _standing_column(
    g: pd.DataFrame, fx: float, fy: float, cx0: float, ego: EgoMotion, idx: np.ndarray
) -> float | None:
    """The forward axis column (px) one track's boxes give as a standing vehicle with a free bearing offset, or
    None (the fit fails its gates: a moving vehicle, too little parallax)."""
    length, width, height = class_size(str(g["category"].iloc[0]))
    h = (g["y2"] - g["y1"]).to_numpy(float)
    bearing = (0.5 * (g["x1"] + g["x2"]).to_numpy(float) - cx0) / fx
    views = Views(ego.x[idx], ego.y[idx], ego.yaw[idx], bearing, h)
    k = len(h) // 2
    z = fy * height / h[k]
    c, s = np.cos(ego.yaw[idx[k]]), np.sin(ego.yaw[idx[k]])
    p0 = np.array([ego.x[idx[k]] + c * z + s * bearing[k] * z, ego.y[idx[k]] + s * z - c * bearing[k] * z])
    b, hp, hr, sr = STANDING_NOISE_PX
    fit = fit_standing(views, (length, width), np.log(fy * height), p0, StandingNoise(b / fx, hp, hr, sr), True)
    if fit is None or fit.chi2 > STANDING_MAX_CHI2 or abs(fit.log_scale) > STANDING_MAX_SIZE_DEV:
        return None
    return cx0 - fit.offset * fx if fit.parallax_rad >= STANDING_MIN_PARALLAX_RAD else None


def axis_column_from_standing(
    boxes: pd.DataFrame, fx: float, fy: float, cx0: float, ego: EgoMotion, seed: int = 0
) -> tuple[float, float, int] | None:
    """(column px of the ego's heading, its 1-sigma px, tracks used) from vehicles standing beside the ego's path:
    each track fitted as one standing point seen from the ego's poses with a bearing offset common to its boxes
    (:func:`~deepcrashtest.geometry.standing.fit_standing`); a column error ``delta`` shifts every bearing by
    ``delta / fx``, and the parallax of the ego's travel separates that from the point's position. The median over
    the tracks that pass the fit's gates (fewer than :data:`STANDING_MIN_TRACKS`: None); the sigma is a bootstrap
    of that median over tracks. ``boxes``: detected, uncut vehicle boxes of the tracks table; ``cx0``: the current
    guess (px)."""
    frame_to_i = {int(f): i for i, f in enumerate(ego.frame)}
    d = boxes[boxes["frame"].isin(frame_to_i.keys())]
    cols = []
    for _, g in d.groupby("track_id"):
        if len(g) >= MIN_ROWS:
            g = g.sort_values("frame")
            col = _standing_column(g, fx, fy, cx0, ego, np.array([frame_to_i[int(f)] for f in g["frame"]]))
            if col is not None:
                cols.append(col)
    if len(cols) < STANDING_MIN_TRACKS:
        return None
    v = np.array(cols)
    rng = np.random.default_rng(seed)
    boots = [float(np.median(v[rng.integers(0, len(v), len(v))])) for _ in range(BOOTSTRAP)]
    return float(np.median(v)), float(np.std(boots)), len(v)
