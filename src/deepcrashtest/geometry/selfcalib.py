"""Self-calibration of an unknown camera from what a video gives: many tracked boxes and the ego's motion.

Vehicles stand on the road. A box of a vehicle of height ``H`` (its class prior) at depth ``Z`` has
its bottom row at ``v_b = v_h + fy hc / Z`` and its height ``h = fy H / Z`` pixels, so

    v_b = v_h + hc * (h / H)

for every box: a straight line whose intercept is the **horizon row** ``v_h`` and whose slope is the
**camera height** ``hc`` in metres (the class priors set the metric scale). It is fitted over all
detected, uncut boxes with a robust (Huber) line fit; uncertainties by bootstrap over tracks.

The **focal length** then follows from the ego's motion: a parked vehicle at world position ``P``
is at depth ``Z_k = (P - c_k) . h_k`` from the camera at ``c_k`` heading ``h_k`` (metres, from the
ego path), and ``Z_k = fy hc / (v_b,k - v_h)``, so per track ``P . h_k - A / (v_b,k - v_h) = c_k . h_k``
is linear in ``(P, A = fy hc)``. Each track long enough (and seen over enough ego travel) gives one
``A``; parked vehicles agree, moving ones scatter (a car driving ahead at the ego's speed looks
infinitely far): the mode of ``log A`` over tracks is kept, ``fy = A / hc``. Where too few parked
vehicles agree, vehicles driving along the road at a steady speed stand in for them
(:mod:`deepcrashtest.geometry.selfcalib_moving`). Without ego motion (or too few tracks) the focal
length keeps its prior (the camera given) and says so. With external metric poses the same parked
vehicles also give the **camera height** without any class size (their depth from the ego's travel,
:mod:`deepcrashtest.geometry.selfcalib_height`), fused with the box line's by inverse variance.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any

import numpy as np
import pandas as pd

from deepcrashtest.geometry.camera import cut_sides, undistorted_tracks
from deepcrashtest.geometry.egomotion import EgoMotion
from deepcrashtest.geometry.known_speed import KnownSpeed, ego_speed_term
from deepcrashtest.geometry.lens import refocused
from deepcrashtest.geometry.mono_config import class_size
from deepcrashtest.geometry.selfcalib_axis import axis_column_from_path, axis_column_from_standing
from deepcrashtest.geometry.selfcalib_image import focal_from_level_horizon
from deepcrashtest.geometry.selfcalib_moving import (
    MODE_BAND,
    focal_from_moving,
    parked_fit,
    pose_tracks,
    sightings,
    weighted_log_mode,
)
from deepcrashtest.perception.roadusers import MOTOR_VEHICLES
from deepcrashtest.scenario import Camera

MIN_BOXES = 30
#: With fewer than MIN_BOXES boxes (a short, low-frame-rate crash clip) but at least this many, the
#: horizon alone is measured from the boxes with the camera height kept at its prior.
MIN_HORIZON_BOXES = 3
#: 1-sigma of the camera-height prior (metres) when only the horizon is measured: dashcams sit at
#: 1.1-1.6 m in cars, higher in vans and trucks.
HEIGHT_PRIOR_SIGMA_M = 0.2
#: A vehicle's box is taller than ``fy H / Z`` (its top edge is the roof's far edge): on the 18 KITTI
#: tracking training sequences other than 3, 8, 10 the PointRCNN boxes of labelled cars 10-50 m away
#: imply 1.54-1.55 m at the near corner's depth against the class prior 1.5 m (labels: median 1.51 m).
BOX_HEIGHT_EXCESS = 1.025
MIN_TRACK_FRAMES = 8
MIN_TRAVEL_M = 4.0


@dataclass
class SelfCalibration:
    """Result: the calibrated camera and each quantity's estimate, 1-sigma and source."""

    camera: Camera
    horizon_v: float
    horizon_sigma_px: float
    height_m: float
    height_sigma_m: float
    fy: float
    fy_sigma: float
    boxes: int
    tracks: int
    notes: list[str]
    ego_scale: float = 1.0
    #: what the user is told (a speed they gave that could not be used)
    warnings: list[str] = field(default_factory=list)
    #: the ego's speed known apart from the images that was offered (the user's, the picture's overlay), if any
    known_speed: KnownSpeed | None = None
    #: the image ego-motion's speed is off (:func:`~deepcrashtest.geometry.known_speed.ego_speed_term`): the ego
    #: drives at ``known_speed`` instead (:func:`~deepcrashtest.geometry.known_speed.with_known_speed`)
    replace_ego_speed: bool = False

    def summary(self) -> dict[str, Any]:
        """Plain JSON-able numbers (None where not estimated)."""

        def num(v: float, nd: int) -> float | None:
            return round(v, nd) if math.isfinite(v) else None

        return {
            "horizon_v": num(self.horizon_v, 1), "horizon_sigma_px": num(self.horizon_sigma_px, 2),
            "height_m": num(self.height_m, 3), "height_sigma_m": num(self.height_sigma_m, 3),
            "fy": num(self.fy, 1), "fy_sigma": num(self.fy_sigma, 1), "boxes": self.boxes,
            "focal_tracks": self.tracks, "notes": self.notes,
        } | ({"known_speed": self.known_speed.summary()} if self.known_speed is not None else {})  # fmt: skip


def _huber_line(x: np.ndarray, y: np.ndarray, delta: float = 3.0, iters: int = 20) -> tuple[float, float]:
    """Robust line ``y = a + b x`` (IRLS, Huber weights, scale by the MAD)."""
    w = np.ones_like(x)
    a = b = 0.0
    for _ in range(iters):
        X = np.column_stack([np.ones_like(x), x]) * w[:, None]
        a, b = np.linalg.lstsq(X, y * w, rcond=None)[0]
        r = y - a - b * x
        s = 1.4826 * np.median(np.abs(r)) + 1e-6
        u = np.abs(r) / (delta * s)
        w = np.sqrt(np.where(u <= 1, 1.0, 1.0 / np.maximum(u, 1e-9)))
    return float(a), float(b)


def _usable(tracks: pd.DataFrame, size: tuple[int, int]) -> pd.DataFrame:
    d = tracks
    if "state" in d.columns:
        d = d[d["state"] == "detected"]
    bh = d["y2"] - d["y1"]
    uncut = ~cut_sides(d[["x1", "y1", "x2", "y2"]].to_numpy(dtype=float), size).any(axis=1)
    ok = (bh >= 10).to_numpy() & uncut
    ok &= d["category"].isin(MOTOR_VEHICLES)
    return d[ok]


def horizon_and_height(
    tracks: pd.DataFrame, size: tuple[int, int], boot: int = 30, seed: int = 0
) -> tuple[float, float, float, float, int] | None:
    """(horizon row px, its sigma, camera height m, its sigma, boxes used) or None (too few boxes).

    The height reads 5-24 % low on 8 of the 17 KITTI training sequences with boxes (0004 1.50 m, 0005
    1.47, 0011 1.42, 0019 1.26 against 1.65: taller vehicles typed car, boxes taller than the near face;
    the scale is the class prior's). Tried and dropped (branch monounk, ``bench/selfcalib_diag.py``): a Tukey fit
    with the box-height excess (0004 1.68 m) moved the 18 training sequences' unknown-camera MOTA
    49.69 -> 49.90 only, lost dad_000487's reproduced crash and lowered held-out 0008 52.48 -> 37.60.
    With external poses :func:`_calibrate_height` fuses in the parked vehicles' height, which needs no class
    size (training 0005 1.47 -> 1.62 m, 0007 1.50 -> 1.62, 0020 1.59 -> 1.64; true 1.65)."""
    d = _usable(tracks, size)
    if len(d) < MIN_BOXES:
        return None
    H = np.array([class_size(str(c))[2] for c in d["category"]])
    x = (d["y2"] - d["y1"]).to_numpy(float) / H
    y = d["y2"].to_numpy(float)
    a, b = _huber_line(x, y)
    rng = np.random.default_rng(seed)
    ids = d["track_id"].to_numpy()
    uniq = np.unique(ids)
    groups = [np.nonzero(ids == u)[0] for u in uniq]
    sa, sb = [], []
    for _ in range(boot):
        pick = np.concatenate([groups[i] for i in rng.integers(0, len(groups), len(groups))])
        ai, bi = _huber_line(x[pick], y[pick], iters=8)
        sa.append(ai)
        sb.append(bi)
    prior_rel = 0.07  # the class height prior's spread sets a floor on the metric scale
    sig_h = math.hypot(float(np.std(sb)), prior_rel * b)
    return a, float(np.std(sa)), b, sig_h, len(d)


def horizon_from_few_boxes(
    tracks: pd.DataFrame, size: tuple[int, int], height_m: float
) -> tuple[float, float, int] | None:
    """(horizon row px, its sigma, boxes used) from a few boxes with the camera height known (its prior).

    Each box gives ``v_h = v_b - hc h / H`` (the line of the module docstring at a fixed slope); the
    median over boxes is kept. Sigma: the boxes' spread over the number of tracks, and the height
    prior's spread times the typical ``h / H``. None with fewer than :data:`MIN_HORIZON_BOXES` boxes."""
    d = _usable(tracks, size)
    if len(d) < MIN_HORIZON_BOXES:
        return None
    H = np.array([class_size(str(c))[2] for c in d["category"]])
    ratio = (d["y2"] - d["y1"]).to_numpy(float) / H
    est = d["y2"].to_numpy(float) - height_m * ratio
    vh = float(np.median(est))
    spread = 1.4826 * float(np.median(np.abs(est - vh))) / math.sqrt(d["track_id"].nunique())
    sigma = math.hypot(spread, HEIGHT_PRIOR_SIGMA_M * float(np.median(ratio)))
    return vh, sigma, len(d)


def focal_from_motion(
    tracks: pd.DataFrame, size: tuple[int, int], cx: float, ego: EgoMotion
) -> tuple[float, float, int] | None:
    """(focal length px, relative sigma, tracks used) from parked vehicles and the ego's motion.

    A vehicle of class height ``H`` parked at ``P`` is seen at depth ``Z_k = fy H / h_k`` and lateral
    offset ``X_k = (u_k - cx) Z_k / fy = (u_k - cx) H / h_k`` from the camera at ``c_k`` (heading
    ``f_k``, right ``r_k``): ``P . f_k - B / h_k = c_k . f_k`` with ``B = fy H``, and
    ``P . r_k = c_k . r_k + (u_k - cx) H / h_k``. Least squares per track gives ``P`` and ``B``; the
    mode of ``log B`` over tracks (parked vehicles agree, moving ones scatter) gives ``fy = B / H``."""
    estimates = []
    weights = []
    for g, idx in pose_tracks(_usable(tracks, size), ego, MIN_TRACK_FRAMES):
        s = sightings(g, ego, idx, cx)
        if s.travel_m < MIN_TRAVEL_M:
            continue
        sol = parked_fit(s)
        if sol[2] > 0:
            estimates.append(math.log(sol[2] / (s.H * BOX_HEIGHT_EXCESS)))
            weights.append(len(g))
    if len(estimates) < 3:
        return None
    e, w = np.array(estimates), np.array(weights, float)
    near = np.abs(e - weighted_log_mode(e, w)) < MODE_BAND
    est = float(np.average(e[near], weights=w[near]))
    spread = float(np.sqrt(np.average((e[near] - est) ** 2, weights=w[near])) / math.sqrt(near.sum()))
    return math.exp(est), max(spread, 0.01), int(near.sum())


#: :func:`focal_from_rotation` and :func:`focal_from_pitch` read a track's detections at its cadence, at most this many
#: frames apart (a video's detector runs every 2-6 frames, ``extract``'s MAX_DETECT_GAP_S; before, at every frame only,
#: so neither measured anything at a video's cadence).
MAX_DETECTION_GAP_FRAMES = 6


def _detection_step(frames: np.ndarray) -> int:
    """A track's cadence: the median gap between its detections (frames, sorted; >= 1)."""
    return max(round(float(np.median(np.diff(frames)))), 1) if len(frames) > 1 else 1


def _cadence(d: pd.DataFrame) -> np.ndarray:
    """Per row of ``d`` (sorted by track and frame): its track's :func:`_detection_step`."""
    return d.groupby("track_id")["frame"].transform(lambda f: _detection_step(f.to_numpy(int))).to_numpy(int)


def focal_from_rotation(
    tracks: pd.DataFrame, size: tuple[int, int], cx: float, ego: EgoMotion, fy0: float, min_turn_deg: float = 0.3
) -> tuple[float, float, int] | None:
    """(focal length px, relative sigma, box pairs used) from the ego's turns.

    When the camera yaws by ``dpsi`` between two frames, a distant box moves by
    ``du = f (1 + b^2) dpsi`` (``b = (u - cx) / f``; a left turn moves the scene right); the
    camera's step adds the parallax ``(u - cx) d / Z - f s / Z`` for a forward step ``d`` and a
    step ``s`` to the right at depth ``Z ~ f H / h``. The sideways term is ``s h / H`` pixels
    whatever the focal length; a camera ahead of the rear axle swings out in every turn, in step
    with ``dpsi`` (on the training sequences, leaving it in read the focal length 5-16 % long); the
    forward term is removed with the current focal length ``fy0``. A robust line through
    the origin of ``du`` against ``(1 + b^2) dpsi`` over all consecutive detections of all tracks,
    in frames where the ego turns by more than ``min_turn_deg``, gives ``f``."""
    d = _usable(tracks, size).sort_values(["track_id", "frame"])
    frame_to_i = {int(f): i for i, f in enumerate(ego.frame)}
    d = d[d["frame"].isin(frame_to_i.keys())]
    frames = d["frame"].to_numpy(int)
    step = _cadence(d)[:-1]  # a video's detector runs every few frames: consecutive detections of a track
    same = (np.diff(d["track_id"].to_numpy()) == 0) & (np.diff(frames) == step) & (step <= MAX_DETECTION_GAP_FRAMES)
    if same.sum() < MIN_BOXES:
        return None
    i = np.array([frame_to_i[int(v)] for v in frames])
    u = 0.5 * (d["x1"] + d["x2"]).to_numpy(float) - cx
    h = (d["y2"] - d["y1"]).to_numpy(float)
    H = np.array([class_size(str(c))[2] for c in d["category"]])
    dx, dy, yaw = np.diff(ego.x[i]), np.diff(ego.y[i]), ego.yaw[i][:-1]
    fwd = dx * np.cos(yaw) + dy * np.sin(yaw)  # the camera's step along its heading (m)
    lat = dx * np.sin(yaw) - dy * np.cos(yaw)  # and to its right (a camera ahead of the axle swings out in turns)
    dpsi = np.diff(ego.yaw[i])
    ok = same & (np.abs(dpsi) > math.radians(min_turn_deg))
    if ok.sum() < MIN_BOXES:
        return None
    u0, h0, H0, du = u[:-1][ok], h[:-1][ok], H[:-1][ok] * BOX_HEIGHT_EXCESS, np.diff(u)[ok]
    # remove the translation's parallax: f / Z = h / H (no focal length in it) for the sideways step,
    # (u - cx) / Z = (u - cx) h / (f H) for the forward one
    du_rot = du + lat[ok] * h0 / H0 - u0 * fwd[ok] * h0 / (fy0 * H0)
    f = fy0
    for _ in range(5):  # (1 + b^2) depends on f: iterate
        x = (1.0 + (u0 / f) ** 2) * dpsi[ok]
        w = np.ones_like(x)
        for _ in range(10):
            f = float(np.sum(w * x * du_rot) / np.sum(w * x * x))
            r = du_rot - f * x
            s = 1.4826 * np.median(np.abs(r)) + 1e-6
            w = np.minimum(1.0, 2.0 * s / np.maximum(np.abs(r), 1e-9))
    if not f > 0:
        return None
    resid = du_rot - f * x
    rel = float(np.sqrt(np.sum(w * resid**2) / np.sum(w * x * x)) / max(np.sqrt(ok.sum()), 1.0) / f)
    return f, max(rel, 0.01), int(ok.sum())


#: Savitzky-Golay window (frames, order 2) whose residual is the fast part of a series (pitch bounce).
BOUNCE_WINDOW = 13
#: Sum of squared fast pitch (rad^2) below which there is no bounce to measure.
MIN_BOUNCE_RAD2 = 1e-12


def _fast_part(a: np.ndarray, window: int) -> np.ndarray:
    """``a`` minus its local quadratic trend (Savitzky-Golay, ``window`` frames): the fast wobble."""
    from scipy.signal import savgol_filter

    return a - savgol_filter(a, window, 2)


def focal_from_pitch(
    tracks: pd.DataFrame, size: tuple[int, int], ego: EgoMotion, window: int = BOUNCE_WINDOW
) -> tuple[float, float, int] | None:
    """(focal length px, relative sigma, frames used) from the camera's pitch bounce (needs ``ego.pitch``).

    When the camera pitches up by ``dtheta`` every box in the image moves down by ``fy dtheta``
    pixels, whatever the vehicle does; the vehicles' own motion (and the ego's travel towards them)
    changes their rows slowly. So the fast part (:func:`_fast_part`) of each track's box-centre row,
    averaged over the tracks of each frame, is a line through the origin against the fast part of
    the pitch with slope ``fy`` (robust fit); its standard error gives the sigma. Only external
    poses carry a pitch measured independently of the focal length (``EgoMotion.pitch``)."""
    if ego.pitch is None:
        return None
    d = _usable(tracks, size).sort_values(["track_id", "frame"])
    frame_to_i = {int(f): i for i, f in enumerate(ego.frame)}
    d = d[d["frame"].isin(frame_to_i.keys())]
    frames, rows, pitch = [], [], []
    for _, g in d.groupby("track_id"):
        f = g["frame"].to_numpy(int)
        v = 0.5 * (g["y1"] + g["y2"]).to_numpy(float)
        step = _detection_step(f)  # the detector's cadence (frames)
        if step > MAX_DETECTION_GAP_FRAMES:
            continue
        samples = max(5, 2 * int(round(window / step / 2)) + 1)  # the window's span at that cadence (odd)
        for seg in np.split(np.arange(len(f)), np.nonzero(np.diff(f) != step)[0] + 1):
            if len(seg) < samples + 2:
                continue
            i = np.array([frame_to_i[int(k)] for k in f[seg]])
            frames.append(f[seg])
            rows.append(_fast_part(v[seg], samples))
            pitch.append(_fast_part(ego.pitch[i], samples))
    if not frames:
        return None
    uniq, inv = np.unique(np.concatenate(frames), return_inverse=True)
    if len(uniq) < MIN_BOXES:
        return None
    n = np.bincount(inv).astype(float)
    y = np.bincount(inv, np.concatenate(rows)) / n
    x = np.bincount(inv, np.concatenate(pitch)) / n
    if float(np.sum(x * x)) < MIN_BOUNCE_RAD2:  # poses without any pitch wobble (e.g. planar)
        return None
    w = np.ones_like(x)
    slope = 0.0
    for _ in range(15):  # line through the origin, Huber-like weights (scale by the MAD)
        slope = float(np.sum(w * x * y) / np.sum(w * x * x))
        r = y - slope * x
        s = 1.4826 * float(np.median(np.abs(r))) + 1e-9
        w = np.minimum(1.0, 2.0 * s / np.maximum(np.abs(r), 1e-12))
    if not slope > 0:
        return None
    se = float(np.sqrt(np.sum(w * r**2) / max(np.sum(w) - 1.0, 1.0) / np.sum(w * x * x)))
    return slope, se / slope, len(uniq)


#: Relative 1-sigma of the focal-length prior (the unknown-dashcam default) and of each estimate
#: when its support is thin; chosen on the 18 KITTI tracking training sequences other than 3, 8, 10.
FOCAL_PRIOR_REL = 0.35
MOTION_MIN_TRACKS = 10
#: Fewer tracks agreeing on the parked-vehicle estimate and it is ignored (on the training sequences
#: 13, 15 and 18 one or two agreeing tracks gave 1228, 147 and 3087 px against the true 707-722).
MOTION_MIN_AGREEING = 3
ROTATION_MIN_PAIRS = 200


#: The pitch-bounce estimate's standard error is inflated by this (the fast parts of neighbouring
#: frames are correlated) and floored at PITCH_MIN_REL; chosen on the 18 KITTI tracking training
#: sequences other than 3, 8, 10 (errors -12..+19 %, median |error| 3 %, within 2-3 inflated sigmas).
PITCH_SE_INFLATION = 2.0
PITCH_MIN_REL = 0.03
#: Floor of the turn estimate's relative sigma. With the camera's sideways step removed it reads
#: -23..+36 % on the 18 KITTI tracking training sequences other than 3, 8, 10 (median +5 %, median
#: |error| 6 %; before, 5-44 % high and a floor of 0.25); combined MOTA with the unknown camera:
#: 0.25 40.20, 0.15 42.36, 0.10 46.09, 0.07 48.76, 0.05 48.52. On image-based ego-motion the yaw
#: was itself measured with the assumed focal length (not used there).
ROTATION_MIN_REL = 0.07
#: A dashcam is mounted near level: a horizon further from the image centre than this pitch (at the
#: prior focal length) hints at a longer focal length or a principal point off the image centre
#: (ccd_000014: 540 px against 360, 16 deg at 640 px, but its poles stay vertical where a 16 deg pitch
#: would tilt them ~13 deg at the edges: a level camera, a cropped frame); said in the notes. The
#: level-camera term (:mod:`deepcrashtest.geometry.selfcalib_image`) weighs such horizons softly.
STEEP_PITCH_RAD = math.radians(8.0)
#: A parked-vehicle estimate further than this (log) from a trusted pitch-bounce estimate (inflated
#: relative sigma under PITCH_TRUSTED_REL) is a mode of moving vehicles and is dropped (training
#: sequence 4: 367 px from 11 agreeing tracks against 725 px from the bounce, true 721).
MOTION_PITCH_MAX_LOG = 0.2
PITCH_TRUSTED_REL = 0.12


#: Floor of the steadily-moving-vehicle estimate's relative sigma (its tracks' own least-squares sigma
#: is 1-3 %; on the 18 KITTI tracking training sequences other than 3, 8, 10 it reads -6..+4 % where
#: it is the one used: 0002 -5.8 %, 0015 +1.0 %, 0018 -1.1 %). It reads 2-10 % below the parked-vehicle
#: estimate where both exist; counting both there brought 0001, 0007, 0009, 0020 within 1.5 % but the
#: unknown-camera combined MOTA on those 18 down from 58.49 to 55.47: it stands in for it only.
MOVING_MIN_REL = 0.04


def _trusted_bounce_disagrees(est: tuple[float, float, int] | None, pitch: tuple[float, float, int] | None) -> bool:
    """True when a trusted pitch-bounce estimate (:data:`PITCH_TRUSTED_REL`) is further than
    :data:`MOTION_PITCH_MAX_LOG` (log) from ``est``."""
    if est is None or pitch is None or pitch[1] * PITCH_SE_INFLATION >= PITCH_TRUSTED_REL:
        return False
    return abs(math.log(est[0] / pitch[0])) > MOTION_PITCH_MAX_LOG


def combine_focal(
    prior: float,
    motion: tuple[float, float, int] | None,
    rotation: tuple[float, float, int] | None,
    pitch: tuple[float, float, int] | None = None,
    moving: tuple[float, float, int] | None = None,
    level: tuple[float, float, int] | None = None,
    speed: tuple[float, float, int] | None = None,
) -> tuple[float, float, int] | None:
    """Inverse-variance (log) combination of the prior and the estimates -> (f, rel sigma, support).

    The parked-vehicle estimate needs :data:`MOTION_MIN_AGREEING` agreeing tracks, and counts fully
    from :data:`MOTION_MIN_TRACKS` on (relative sigma at least 4 %), thinner support as 25 %; the
    pitch-bounce estimate counts with its inflated standard error (:data:`PITCH_SE_INFLATION`,
    :data:`PITCH_MIN_REL`); the turn estimate at :data:`ROTATION_MIN_REL` at best (30 % below
    :data:`ROTATION_MIN_PAIRS` box pairs). The steadily-moving-vehicle estimate
    (:mod:`deepcrashtest.geometry.selfcalib_moving`, parked vehicles included) stands in for the
    parked-vehicle one where that is missing or dropped (they share the parked tracks), at
    :data:`MOVING_MIN_REL` at best; both are dropped when a trusted bounce disagrees. ``level``: the
    level-camera term of the horizon (:mod:`deepcrashtest.geometry.selfcalib_image`), at its own sigma; ``speed``: the
    ego's speed known apart from the images (:func:`~deepcrashtest.geometry.known_speed.focal_from_ego_speed`), at
    its own sigma."""
    terms = [(math.log(prior), FOCAL_PRIOR_REL)]
    support = 0
    if _trusted_bounce_disagrees(motion, pitch):
        motion = None  # a mode of moving vehicles (all parked-vehicle estimates are for the same car kind)
    if motion is not None and motion[2] >= MOTION_MIN_AGREEING:
        terms.append((math.log(motion[0]), max(motion[1], 0.04) if motion[2] >= MOTION_MIN_TRACKS else 0.25))
        support += motion[2]
    elif moving is not None and not _trusted_bounce_disagrees(moving, pitch):
        terms.append((math.log(moving[0]), max(moving[1], MOVING_MIN_REL)))
        support += moving[2]
    if pitch is not None:
        terms.append((math.log(pitch[0]), max(PITCH_SE_INFLATION * pitch[1], PITCH_MIN_REL)))
        support += pitch[2]
    if rotation is not None:
        rel = max(3 * rotation[1], ROTATION_MIN_REL) if rotation[2] >= ROTATION_MIN_PAIRS else 0.3
        terms.append((math.log(rotation[0]), rel))
        support += rotation[2]
    if level is not None:
        terms.append((math.log(level[0]), level[1]))
    if speed is not None:
        terms.append((math.log(speed[0]), speed[1]))
        support += speed[2]
    if len(terms) == 1:
        return None
    w = np.array([1.0 / r**2 for _, r in terms])
    v = np.array([m for m, _ in terms])
    return math.exp(float(np.sum(w * v) / np.sum(w))), float(1.0 / np.sqrt(np.sum(w))), support


#: 1-sigma (fraction of the image width) of the principal point's column about the image centre
#: (KITTI: 8-20 px of 1242 off), and the factor inflating the bootstrap sigma of the path estimate
#: (:mod:`deepcrashtest.geometry.selfcalib_axis`; on the 18 KITTI tracking training sequences other
#: than 3, 8, 10 its errors reach 3-4 bootstrap sigmas; x 4 chosen there, see its MAX_DEPTH_M), with
#: a floor (px). Chosen again on those 18 with the tracker of round axis34 (unknown camera, combined MOTA: x 1
#: 64.75, x 2 64.78, x 3 64.73, x 4 64.63; x 2 / x 4 at 60 m 64.74 / 64.66; column error rms over the 9 sequences
#: measured 5.1 px at x 4, 3.8 px at x 2: 0018 11.0 -> 5.3 px, 0019 6.3 -> -1.7 px, 0004 -4.4 -> -6.5 px).
AXIS_PRIOR_REL = 0.02
AXIS_SIGMA_INFLATION = 2.0
AXIS_MIN_SIGMA_PX = 3.0
#: The column from standing vehicles as well (:func:`~deepcrashtest.geometry.selfcalib_axis.axis_column_from_standing`,
#: its bootstrap sigma inflated alike).
AXIS_FROM_STANDING = True


def _calibrate_axis(
    tracks: pd.DataFrame, size: tuple[int, int], cam: Camera, ego: EgoMotion, notes: list[str]
) -> Camera:
    """The camera with ``cx`` (and ``fx`` unchanged) moved to the column of the ego's heading measured
    from the road users beside its path and from the vehicles standing there, combined with the image-centre
    prior by inverse variance."""
    boxes = _usable(tracks, size)
    path = axis_column_from_path(boxes, cam.fy, cam.cx, ego, BOX_HEIGHT_EXCESS)
    if path is not None:
        path = axis_column_from_path(boxes, cam.fy, path[0], ego, BOX_HEIGHT_EXCESS)
    standing = axis_column_from_standing(boxes, cam.fx, cam.fy, cam.cx, ego) if AXIS_FROM_STANDING else None
    terms = [(e[0], max(AXIS_SIGMA_INFLATION * e[1], AXIS_MIN_SIGMA_PX)) for e in (path, standing) if e is not None]
    if not terms:
        notes.append("forward axis column not measurable (too few road users beside the ego path): image centre kept")
        return cam
    terms.append((cam.cx, AXIS_PRIOR_REL * size[0]))
    w = np.array([1.0 / sig**2 for _, sig in terms])
    cx_post = float(np.sum(w * np.array([c for c, _ in terms])) / np.sum(w))
    said = [
        f"{what}: {e[0]:.1f} +- {e[1]:.1f} px, {e[2]} tracks"
        for what, e in (("road users beside the ego path", path), ("standing vehicles", standing))
        if e is not None
    ]
    notes.append(f"forward axis column {cx_post:.1f} px ({'; '.join(said)})")
    return cam.model_copy(update={"cx": cx_post})


def _level_term(camera: Camera, vh: float, sig_v: float, notes: list[str]) -> tuple[float, float, int] | None:
    """The level-camera term of the horizon row ``vh`` (px, 1-sigma ``sig_v``) for the unknown-dashcam
    default's focal length (:func:`~deepcrashtest.geometry.selfcalib_image.focal_from_level_horizon`);
    None for a camera whose intrinsics were given, or a horizon near the centre row."""
    if camera.intrinsics_source != "default":
        return None
    term = focal_from_level_horizon(vh - camera.cy, sig_v, camera.fy, FOCAL_PRIOR_REL)
    if term is not None:
        notes.append(
            f"horizon {vh - camera.cy:+.0f} px from the centre row: a level camera says {term[0]:.0f} px +- "
            f"{100 * term[1]:.0f} % (or the frame is cropped)"
        )
    return term


#: 1-sigma (relative) of the box line's camera height for the vehicles about being taller or lower than
#: the class prior on the whole: the labelled cars' mean height spans 1.45-1.83 m over the 18 KITTI
#: tracking training sequences other than 3, 8, 10 (about 10 %; combined unknown-camera MOTA there, in
#: a first version: 0 58.67, 0.1 58.85, 0.2 58.93; this one at 0.1: 58.57 with the tracks' plain mode,
#: 59.14 with their mode weighted by the box line's height as a prior; the box line alone 58.49);
#: the parked-vehicle height's bootstrap sigma is floored at PARKED_MIN_SIGMA_M, and it is dropped
#: further than PARKED_MAX_SIGMAS combined bare
#: sigmas (bootstrap; the box line's without this spread) from the box line (training 0004: 0.91 m
#: +- 0.02 from 11 tracks moving in step, against 1.50 m +- 0.13).
FLEET_HEIGHT_REL = 0.1
PARKED_MIN_SIGMA_M = 0.03
PARKED_MAX_SIGMAS = 3.0
#: Floor (rad, times the focal length: px) of the box line's horizon 1-sigma, added in quadrature to its
#: bootstrap over tracks: the road under the vehicles is not one plane (a slope change of 0.17 deg is
#: 2 px at KITTI's 721 px). Chosen on the 18 KITTI tracking training sequences other than 3, 8, 10
#: against the labelled cars' road (``bench/selfcalib_sigma.py``): median |error| / sigma 1.11 -> 0.67,
#: within 1 / 2 sigmas 47 / 88 % -> 76 / 94 % (the bootstrap alone was too tight: 0002 -7.9 +- 2.4 px,
#: 0009 -5.0 +- 1.7 px). Reported only: the level-camera focal term keeps the bootstrap sigma (with the
#: floor it moved 5 dashcam clips' focal lengths by 0.05-0.08 % and ccd_000014's replay IoU 0.6824 -> 0.6822).
HORIZON_FLOOR_RAD = 0.003


def _calibrate_height(
    tracks: pd.DataFrame,
    size: tuple[int, int],
    cam: Camera,
    ego: EgoMotion,
    horizon_v: float,
    bare_sigma_m: float,
    notes: list[str],
) -> Camera:
    """The camera with its box-line height fused (inverse variance) with the parked vehicles' height
    (:func:`~deepcrashtest.geometry.selfcalib_height.height_from_parked`), which needs no class size.

    ``cam.height_sigma_m``: the box line's 1-sigma with the fleet's spread (:data:`FLEET_HEIGHT_REL`);
    ``bare_sigma_m``: its bootstrap alone (the disagreement test). The parked vehicles measure ``fy hc``:
    their height's 1-sigma carries the focal length's relative 1-sigma (``cam.focal_sigma_px``) too."""
    from deepcrashtest.geometry.selfcalib_height import height_from_parked

    hc0, sig0 = cam.height_m, cam.height_sigma_m or 0.0
    est = height_from_parked(_usable(tracks, size), cam.cx, ego, cam.fy, horizon_v, prior=(hc0, sig0))
    if est is None:
        notes.append("camera height from the boxes alone (fewer parked vehicles than needed along the ego path)")
        return cam
    # hc = (fy hc) / fy carries the focal length's relative 1-sigma: on the 18 KITTI tracking training
    # sequences other than 3, 8, 10 the height erred up to 6.4 stated sigmas without it (0000: 1.40 +-
    # 0.04 m against 1.65, its focal length +7.6 %; bench/selfcalib_sigma.py); training MOTA 60.98 -> 61.00
    focal_rel = (cam.focal_sigma_px or 0.0) / cam.fy
    hc, sig = est[0], math.hypot(max(est[1], PARKED_MIN_SIGMA_M), est[0] * focal_rel)
    if abs(hc - hc0) > PARKED_MAX_SIGMAS * math.hypot(est[1], bare_sigma_m):  # the bare sigmas
        notes.append(f"parked-vehicle camera height {hc:.2f} m ({est[2]} tracks) disagrees with the boxes': dropped")
        return cam
    w, w0 = 1.0 / sig**2, 1.0 / sig0**2
    fused = (w * hc + w0 * hc0) / (w + w0)
    notes.append(
        f"camera height {fused:.2f} m: boxes {hc0:.2f} +- {sig0:.2f} m, parked vehicles {hc:.2f} +- {sig:.2f} m "
        f"({est[2]} tracks)"
    )
    return cam.model_copy(update={"height_m": fused, "height_sigma_m": 1.0 / math.sqrt(w + w0)})


def self_calibrate(
    tracks: pd.DataFrame,
    camera: Camera,
    size: tuple[int, int],
    ego: EgoMotion | None = None,
    ego_scaled_by_height: bool = False,
    known_speed: KnownSpeed | None = None,
) -> SelfCalibration:
    """Horizon, camera height and focal length of an uncalibrated camera (see the module docstring).

    ``camera``: the prior (e.g. the unknown-dashcam default); ``tracks``: the image tracker's table;
    ``ego``: the ego path (metres), for the focal length. ``ego_scaled_by_height``: the ego path's
    metric scale came from ``camera.height_m`` and the camera's focal length (monocular ego-motion: the
    road plane's scale is proportional to focal length x camera height): it cannot calibrate the focal
    length, and ``SelfCalibration.ego_scale`` is the factor (measured over assumed focal x height) that
    rescales it. ``known_speed``: the ego's speed known apart from the images (the user's, a GPS overlay or log:
    :class:`~deepcrashtest.geometry.known_speed.KnownSpeed`), which image ego-motion scaled by height then reads the
    focal length from (:func:`~deepcrashtest.geometry.known_speed.focal_from_ego_speed`). What cannot be measured
    keeps the prior."""
    notes: list[str] = []
    warns: list[str] = []
    image_ego = ego  # the path the user's speed is read against (``ego`` is dropped below where it is the images')
    tracks = undistorted_tracks(tracks, camera, size)  # a lens's distortion known: boxes in its pinhole image
    hh = horizon_and_height(tracks, size)
    cam = camera
    if hh is None:
        few = horizon_from_few_boxes(tracks, size, cam.height_m)
        upd: dict[str, Any] = {}
        if few is None:
            vh, sig_v, n = cam.horizon_v(), float("nan"), 0
        else:
            vh, sig_v, n = few
            notes.append(
                f"fewer than {MIN_BOXES} uncut vehicle boxes: horizon from {n} boxes at the prior camera height "
                f"{cam.height_m:.2f} m (was row {cam.horizon_v():.0f}, {cam.pitch_source}); the height keeps its prior"
            )
            upd = {"pitch_source": "self_calibration", "horizon_sigma_px": sig_v}
        level = _level_term(camera, vh, sig_v, notes) if n else None
        speed, replace_speed = ego_speed_term(
            image_ego, camera, known_speed, ego_scaled_by_height, cam.height_m, notes, warns, size[0]
        )
        if few is None and speed is None:
            notes.append(f"fewer than {MIN_HORIZON_BOXES} uncut vehicle boxes: the camera keeps its priors")
            nan = float("nan")
            return SelfCalibration(
                cam, vh, nan, cam.height_m, nan, cam.fy, nan, 0, 0, notes, 1.0, warns, known_speed, replace_speed
            )
        if few is None:  # no horizon from boxes, but the user's speed gives the focal length
            notes.append(f"fewer than {MIN_HORIZON_BOXES} uncut vehicle boxes: horizon and height keep their priors")
        focal = combine_focal(cam.fy, None, None, level=level, speed=speed)
        fy, sig_f = cam.fy, float("nan")
        if focal is not None:
            fy, sig_f = focal[0], focal[0] * focal[1]
            upd |= {"fx": cam.fx * fy / cam.fy, "fy": fy, "intrinsics_source": "self_calibration"}
            upd["distortion"] = refocused(cam.distortion, cam.fx, upd["fx"])
            upd["focal_sigma_px"] = sig_f
        cam = cam.model_copy(update=upd | {"pitch_rad": math.atan2(cam.cy - vh, fy)})
        scale = fy / camera.fy if ego_scaled_by_height else 1.0
        return SelfCalibration(
            cam, vh, sig_v, cam.height_m, float("nan"), fy, sig_f, n, 0, notes, scale, warns, known_speed, replace_speed
        )
    vh, sig_v, hc, bare_h, n = hh
    # the level-camera term takes the bootstrap sigma: its mounting-pitch prior, set from box horizons on
    # cameras of known focal length, already holds the road's departure from one plane
    level = _level_term(camera, vh, sig_v, notes)
    sig_v = math.hypot(sig_v, HORIZON_FLOOR_RAD * cam.fy)
    sig_h = math.hypot(bare_h, FLEET_HEIGHT_REL * hc)  # the vehicles about taller or lower than the prior
    fy, sig_f, used = cam.fy, float("nan"), 0
    focal = None
    ego_scale = hc / cam.height_m if ego_scaled_by_height else 1.0
    if ego is not None and ego_scaled_by_height:
        # the road-plane scale of image ego-motion is proportional to the assumed focal length (and its
        # rotations were measured with it): parked vehicles and turns on that path give it back unchanged
        notes.append("the ego path was measured from the images with the assumed focal length: it cannot calibrate it")
        ego = None
    speed, replace_speed = ego_speed_term(
        image_ego, camera, known_speed, ego_scaled_by_height, hc, notes, warns, size[0]
    )
    if ego is not None:
        motion = focal_from_motion(tracks, size, cam.cx, ego)
        bounce = focal_from_pitch(tracks, size, ego)
        moving = focal_from_moving(_usable(tracks, size), cam.cx, ego, cam.fy, BOX_HEIGHT_EXCESS)
        rotation = focal_from_rotation(tracks, size, cam.cx, ego, cam.fy)
        focal = combine_focal(cam.fy, motion, rotation, bounce, moving, level)
        if focal is not None:  # the turn estimate removes the parallax with the focal length: redo it with the new one
            rotation = focal_from_rotation(tracks, size, cam.cx, ego, focal[0])
            focal = combine_focal(cam.fy, motion, rotation, bounce, moving, level)
            sources = {"parked": motion, "moving": moving, "turns": rotation, "bounce": bounce}
            notes.append(
                "focal length estimates (px, relative 1-sigma, support): "
                + ", ".join(f"{k} {v[0]:.0f} {100 * v[1]:.1f} % {v[2]}" for k, v in sources.items() if v is not None)
            )
    elif level is not None or speed is not None:  # no ego motion that can calibrate it: the level-camera horizon,
        focal = combine_focal(cam.fy, None, None, level=level, speed=speed)  # the user's speed
    if focal is not None:
        fy, rel, used = focal
        sig_f = fy * rel
        notes.append(
            f"focal length {fy:.0f} px +- {100 * rel:.0f} %: {used} parked or moving tracks / turn box pairs / "
            f"bounce frames{', the level-camera horizon' if level is not None else ''}"
            f"{', the ego speed known' if speed is not None else ''}"
        )
    elif camera.intrinsics_source == "default":  # the unknown-dashcam default: its spread is the uncertainty
        sig_f = FOCAL_PRIOR_REL * fy
        notes.append(
            f"focal length not measurable (no external ego motion, no parked vehicles, no turns): the default "
            f"{fy:.0f} px kept, 1-sigma {100 * FOCAL_PRIOR_REL:.0f} % (dashcams span ~60-140 deg of view); "
            "distances and the ego's speed scale with it"
        )
    else:
        notes.append("focal length not measurable (no ego motion, no parked vehicles, no turns): prior kept")
    scale = fy / cam.fy
    if ego_scaled_by_height:
        ego_scale *= scale  # image ego-motion's metric scale goes with focal length x camera height
    update: dict[str, Any] = {
        "height_m": hc, "height_source": "self_calibration", "height_sigma_m": sig_h,
        "pitch_source": "self_calibration", "horizon_sigma_px": sig_v,
    }  # fmt: skip
    if focal is not None:
        update |= {"fx": cam.fx * scale, "fy": fy, "intrinsics_source": "self_calibration", "focal_sigma_px": sig_f}
        update["distortion"] = refocused(cam.distortion, cam.fx, update["fx"])
    elif math.isfinite(sig_f):
        update["focal_sigma_px"] = sig_f
    cam = cam.model_copy(update=update)
    if ego is not None:  # external poses only: not yet checked on image ego-motion (dashcam clips)
        cam = _calibrate_height(tracks, size, cam, ego, vh, bare_h, notes)
        hc, sig_h = cam.height_m, cam.height_sigma_m or sig_h
        cam = _calibrate_axis(tracks, size, cam, ego, notes)
    cam = cam.model_copy(update={"pitch_rad": math.atan2(cam.cy - vh, cam.fy)})
    if focal is None and abs(cam.pitch_rad) > STEEP_PITCH_RAD:
        notes.append(
            f"horizon {abs(vh - cam.cy):.0f} px from the image centre: {math.degrees(abs(cam.pitch_rad)):.0f} deg of "
            f"pitch at the assumed focal length {cam.fy:.0f} px, a longer focal length, or a level camera whose "
            "principal point is off the image centre (a cropped frame: ccd_000014's verticals stay parallel, "
            "bench/vertical_lines.py): distances and the ego's speed scale with the focal length"
        )
    return SelfCalibration(
        cam, vh, sig_v, hc, sig_h, fy, sig_f, n, used, notes, ego_scale, warns, known_speed, replace_speed
    )
