"""The road's motion between two frames of a moving camera: its metric scale (step 4 of
:mod:`deepcrashtest.geometry.egomotion`).

The plane-induced homography ``R + (|T| / h) t n^T`` of the road (camera height ``h``, road normal ``n``) is fitted to
the road points of a keyframe pair (:func:`fit_plane_motion`: robust Gauss-Newton over ``|T| / h`` and the plane's
tilt, a prior keeping ``n`` near the slowly adapting road normal), or one constant speed to many pairs' road points at
once (:func:`fit_joint_speed`, a diagnosis). Points are undistorted pixels of the working image; metres, seconds,
radians; camera x right, y down, z forward.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import Any

import cv2
import numpy as np

#: Fewer road points than this and the pair's scale is not measured (the filtered speed is kept).
MIN_ROAD_POINTS = 12
#: The share of a keyframe pair's static points under the horizon that lie higher than the ground
#: (:func:`ground_envelope_scale`): the ground is the envelope below them. 0.8 chosen on KITTI odometry seq00 (per-pair
#: scale error against the poses, median / 10-90 %: 0.6 -0.6 % / -8.3..+6.5; 0.7 -1.2 / -9.2..+4.7; 0.8 -1.9 /
#: -10.2..+3.0; 0.9 -3.2 / -11.9..+1.5; the road plane's fit -0.8 / -18.8..+2.9).
ENVELOPE_QUANTILE = 0.8
#: Fewer well-triangulated points than this under the horizon and the envelope gives no scale.
MIN_ENVELOPE_POINTS = 15
#: A point seen from the pair's two camera positions under less than this angle (rad) has no usable depth.
ENVELOPE_MIN_ANGLE_RAD = math.radians(0.3)


def _tilt_basis(n0: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The two unit directions :func:`_tilted` tilts ``n0`` along (about camera x, then about the first)."""
    e1 = np.cross(n0, [1.0, 0.0, 0.0])
    e1 /= np.linalg.norm(e1)
    return e1, np.cross(n0, e1)


def _tilted(n0: np.ndarray, a: float, b: float, basis: tuple[np.ndarray, np.ndarray] | None = None) -> np.ndarray:
    """``n0`` tilted by small angles ``a`` (about camera x: pitch) and ``b`` (roll), unit length.
    ``basis``: :func:`_tilt_basis` of ``n0`` when already known (the same numbers, computed once)."""
    e1, e2 = basis if basis is not None else _tilt_basis(n0)
    n = n0 + a * e1 + b * e2
    return n / np.linalg.norm(n)


@dataclass
class PlaneFit:
    """Road-plane homography fit: ``sigma`` = metres travelled / camera height (unit-free)."""

    sigma: float
    sigma_std: float
    normal: np.ndarray
    inliers: int


def _huber_gauss_newton(
    residuals: Callable[[np.ndarray], np.ndarray],
    p: np.ndarray,
    prior_w: np.ndarray,
    n_numeric: int,
    extra_j: np.ndarray,
    iters: int,
    use: np.ndarray | None = None,
) -> tuple[np.ndarray, np.ndarray, np.ndarray] | None:
    """Robust Gauss-Newton from ``p``: ``residuals(p)`` (N, 2) in noise units, Huber weights at 2 units, a Gaussian
    prior of precision ``prior_w`` around 0 on each parameter; the Jacobian of the first ``n_numeric`` parameters
    by forward differences (1e-4), ``extra_j`` (N, 2, rest) for the others (constant); ``use``: rows that count.
    Stops when the first parameter settles. Returns (parameters, normal matrix, weights) or None if singular."""
    A = np.eye(len(p))
    w = np.ones(len(extra_j))
    for _ in range(iters):
        r = residuals(p)
        J = np.stack([(residuals(p + np.eye(len(p))[k] * 1e-4) - r) / 1e-4 for k in range(n_numeric)], axis=-1)
        J = np.concatenate([J, extra_j], axis=-1)
        e = np.hypot(r[:, 0], r[:, 1])
        w = np.where(e < 2.0, 1.0, 2.0 / np.maximum(e, 1e-9))  # Huber at 2 noise units
        if use is not None:
            w = w * use
        Jw = J * w[:, None, None]
        A = np.einsum("nij,nik->jk", Jw, J) + np.diag(prior_w)
        g = np.einsum("nij,ni->j", Jw, r) + prior_w * p
        try:
            d = np.linalg.solve(A, -g)
        except np.linalg.LinAlgError:
            return None
        p = p + d
        if abs(d[0]) < 1e-6 * max(abs(p[0]), 1e-6):
            break
    return p, A, w


def _median_scale(x1: np.ndarray, a: np.ndarray, b: np.ndarray) -> float | None:
    """Start of a road-plane fit: the median over points of the scale ``s`` solving ``x1 x (a + s b) = 0`` (each
    (N, 3): the later frame's normalised point, the rotated earlier point, the translation per unit scale); None
    with fewer than ``MIN_ROAD_POINTS`` points that fix it or a non-finite median."""
    c1 = np.cross(x1, a)
    c2 = np.cross(x1, b)
    den = np.sum(c2 * c2, axis=1)
    ok = den > 1e-12
    if ok.sum() < MIN_ROAD_POINTS:
        return None
    start = float(np.median(-np.sum(c1[ok] * c2[ok], axis=1) / den[ok]))
    return start if np.isfinite(start) else None


def fit_plane_motion(
    x0: np.ndarray,
    p1: np.ndarray,
    K: np.ndarray,
    R: np.ndarray,
    t: np.ndarray,
    n_prior: np.ndarray,
    noise_px: float = 0.5,
    tilt_prior_rad: float = 0.02,
    iters: int = 8,
    shift_prior_px: float = 0.0,
) -> PlaneFit | None:
    """Fit ``x1 ~ R x0 + sigma (n . x0) t`` to road points (robust Gauss-Newton, Huber weights).

    ``x0``: (N, 3) normalised homogeneous image points of the earlier frame (``K^-1 [u, v, 1]``),
    ``p1``: (N, 2) pixels in the later frame, ``R``/``t``: rotation and unit translation from the
    essential matrix (``X1 = R X0 + |T| t``), ``n_prior``: road normal (camera frame, pointing down).
    The road ``n . X0 = h`` makes ``sigma = |T| / h``. ``shift_prior_px`` > 0: the road points also get one
    image shift (px, u and v; a Gaussian prior of this 1-sigma) fitted with the rest: the small pitch / yaw by
    which the road's rows differ from the pair's rotation (a rolling shutter, a shaking mount); ``sigma_std``
    then carries that uncertainty. Returns None when the fit is degenerate.
    """
    fx, fy, cx, cy = K[0, 0], K[1, 1], K[0, 2], K[1, 2]
    a = x0 @ R.T
    basis = _tilt_basis(n_prior)
    npar = 5 if shift_prior_px > 0.0 else 3

    def residuals(p: np.ndarray) -> np.ndarray:
        n = _tilted(n_prior, p[1], p[2], basis)
        X = a + p[0] * (x0 @ n)[:, None] * t[None, :]
        z = np.where(np.abs(X[:, 2]) < 1e-9, 1e-9, X[:, 2])
        u, v = fx * X[:, 0] / z + cx - p1[:, 0], fy * X[:, 1] / z + cy - p1[:, 1]
        if npar == 5:
            u, v = u + p[3], v + p[4]
        return np.column_stack([u, v]) / noise_px

    x1 = np.column_stack([(p1[:, 0] - cx) / fx, (p1[:, 1] - cy) / fy, np.ones(len(p1))])
    start = _median_scale(x1, a, (x0 @ n_prior)[:, None] * t[None, :])
    if start is None:
        return None
    p = np.array([start, 0.0, 0.0, 0.0, 0.0][:npar])
    prior_w = np.array([0.0, 1.0 / tilt_prior_rad**2, 1.0 / tilt_prior_rad**2, 0.0, 0.0][:npar])
    if npar == 5:
        prior_w[3:] = (noise_px / shift_prior_px) ** 2  # residuals are in noise units
    solved = _huber_gauss_newton(residuals, p, prior_w, npar, np.zeros((len(x0), 2, 0)), iters)
    if solved is None:
        return None
    p, A, w = solved
    r = residuals(p)
    e = np.hypot(r[:, 0], r[:, 1])
    inl = e < 4.0
    if inl.sum() < MIN_ROAD_POINTS or not np.all(np.isfinite(p)) or p[0] <= 0:
        return None
    s2 = float(np.sum(w[inl] * e[inl] ** 2) / max(1, 2 * int(inl.sum()) - npar))
    var = float(np.linalg.inv(A)[0, 0]) * max(s2, 0.25)
    return PlaneFit(float(p[0]), math.sqrt(max(var, 0.0)), _tilted(n_prior, p[1], p[2], basis), int(inl.sum()))


def ground_envelope_scale(
    x0: np.ndarray, x1: np.ndarray, R: np.ndarray, t: np.ndarray, down: np.ndarray, height_m: float
) -> tuple[float, int] | None:
    """(|T| m, points used) of a keyframe pair from the lower envelope of its static points, or None.

    ``x0``, ``x1`` (N, 2): the points' normalised image coordinates in the two frames (undistorted, divided by the
    focal length; camera x right, y down), points under the horizon that moved with the static scene (the essential
    matrix's inliers); ``R``, ``t``: the pair's rotation and unit translation (``x1 ~ R x0 + t``); ``down``: the road
    normal (camera frame, pointing down); ``height_m``: the camera's height over the road. Each point is triangulated
    at unit baseline; its depth below the camera along ``down`` is ``height / |T|`` on the ground and less on anything
    standing on it (kerbs, walls, poles, parked cars), so the ground is the envelope below the points: their
    ``ENVELOPE_QUANTILE`` quantile. Unlike :func:`fit_plane_motion` it needs no texture on the road itself: the foot of
    whatever stands beside it carries the scale (a textureless or hidden road, the verge, parked cars)."""
    p0 = np.hstack([np.eye(3), np.zeros((3, 1))])
    p1 = np.hstack([R, np.asarray(t, dtype=float).reshape(3, 1)])
    hom = cv2.triangulatePoints(p0, p1, x0.T.astype(np.float64), x1.T.astype(np.float64))
    with np.errstate(divide="ignore", invalid="ignore"):
        X = (hom[:3] / hom[3]).T
    centre1 = -R.T @ np.asarray(t, dtype=float).reshape(3)
    r0 = X / np.linalg.norm(X, axis=1, keepdims=True)
    r1 = (X - centre1) / np.linalg.norm(X - centre1, axis=1, keepdims=True)
    angle = np.arccos(np.clip(np.sum(r0 * r1, axis=1), -1.0, 1.0))
    below = X @ np.asarray(down, dtype=float)
    ok = np.isfinite(below) & (X[:, 2] > 0) & (angle > ENVELOPE_MIN_ANGLE_RAD) & (below > 0)
    if ok.sum() < MIN_ENVELOPE_POINTS:
        return None
    ground = float(np.quantile(below[ok], ENVELOPE_QUANTILE))
    return height_m / ground, int(ok.sum())


@dataclass
class JointFit:
    """One speed fitted over many keyframe pairs at once (:func:`fit_joint_speed`)."""

    speed: float  # m/s
    speed_std: float  # m/s, 1-sigma
    pairs: int  # pairs with road points in the fit
    points: int
    inliers: int


def _pair_points(pair: dict[str, Any], height_m: float, mode: str) -> tuple[np.ndarray, ...] | None:
    """One recorded keyframe pair's road points as the joint fit's rows: (a = R x0, x0, t * dt / h, n, p1, K)."""
    road = pair["road"]
    if road.sum() == 0:
        return None
    R, K = pair["R"], pair["K"]
    if mode == "travel":
        if pair["travel"] is None:
            return None
        t = -R @ (pair["travel"] / np.linalg.norm(pair["travel"]))  # the camera moves along the travel
    else:
        t = pair["t"]
    p0 = pair["p0"][road].astype(np.float64)
    x0 = np.column_stack([(p0[:, 0] - K[0, 2]) / K[0, 0], (p0[:, 1] - K[1, 2]) / K[1, 1], np.ones(len(p0))])
    dt = max(pair["t1"] - pair["t0"], 1e-3)
    m = len(x0)
    return (
        x0 @ R.T,
        x0,
        np.tile(t * dt / height_m, (m, 1)),
        np.tile(pair["normal"], (m, 1)),
        pair["p1"][road].astype(np.float64),
        np.tile(K[[0, 1, 0, 1], [0, 1, 2, 2]], (m, 1)),
    )


def fit_joint_speed(
    pairs: Sequence[dict[str, Any]],
    height_m: float,
    mode: str = "travel",
    noise_px: float = 0.5,
    min_cond: float = 0.0,
    free_shift: bool = False,
    tilt_prior_rad: float = 0.02,
) -> JointFit | None:
    """One constant speed (m/s) over many keyframe pairs' road points at once (robust Gauss-Newton, Huber).

    Each pair ``k`` (a dict: ``t0``, ``t1`` s, ``p0``/``p1`` work px (N, 2), ``road`` bool (N,), ``R``, ``t``,
    ``K``, ``normal`` (camera frame, down), ``travel`` (camera frame or None); as ``EgoMotionEstimator(...,
    keep_pairs=True).pairs`` records them) contributes its road points to ``x1 ~ R x0 + (v dt_k / h) (n . x0) t_k``;
    ``v`` and a tilt of the road normal shared by all pairs are fitted (``tilt_prior_rad``: the tilt's 1-sigma
    prior). ``mode``: ``"travel"`` takes each pair's translation along the learned direction of travel, ``"pair"``
    its essential matrix's. ``min_cond``: pairs whose own information on ``v`` (the squared sensitivity of their
    points to ``v``, per noise px^2, at the first estimate) is under this share of the best pair's are left out
    (ill-conditioned). ``free_shift``: each pair's road points also get their own image shift (px; the small
    pitch / yaw by which the rows of the road differ from the pair's rotation, a rolling shutter or a shaking
    mount), fitted with the rest. None when fewer than ``MIN_ROAD_POINTS`` points."""
    rows = [r for r in (_pair_points(p, height_m, mode) for p in pairs) if r is not None]
    if not rows:
        return None
    pair_id = np.concatenate([np.full(len(r[0]), k) for k, r in enumerate(rows)])
    a, x0, tb, n0, p1, kk = (np.concatenate([r[j] for r in rows]) for j in range(6))
    if len(a) < MIN_ROAD_POINTS:
        return None
    basis = _tilt_basis(np.mean(n0, axis=0) / np.linalg.norm(np.mean(n0, axis=0)))

    npair = len(rows)

    def residuals(p: np.ndarray) -> np.ndarray:
        n = n0 + p[1] * basis[0] + p[2] * basis[1]
        n = n / np.linalg.norm(n, axis=1, keepdims=True)
        X = a + p[0] * np.sum(x0 * n, axis=1)[:, None] * tb
        z = np.where(np.abs(X[:, 2]) < 1e-9, 1e-9, X[:, 2])
        u = kk[:, 0] * X[:, 0] / z + kk[:, 2] - p1[:, 0]
        v = kk[:, 1] * X[:, 1] / z + kk[:, 3] - p1[:, 1]
        if free_shift:
            u = u + p[3 : 3 + npair][pair_id]
            v = v + p[3 + npair :][pair_id]
        return np.column_stack([u, v]) / noise_px

    x1 = np.column_stack([(p1[:, 0] - kk[:, 2]) / kk[:, 0], (p1[:, 1] - kk[:, 3]) / kk[:, 1], np.ones(len(p1))])
    start = _median_scale(x1, a, np.sum(x0 * n0, axis=1)[:, None] * tb)
    if start is None:
        return None
    nshift = 2 * npair if free_shift else 0
    p = np.r_[start, 0.0, 0.0, np.zeros(nshift)]
    use = np.ones(len(a), bool)
    if min_cond > 0.0:
        r0 = residuals(p)
        jv = (residuals(p + np.eye(len(p))[0] * 1e-3) - r0) / 1e-3
        info = np.bincount(pair_id, weights=np.sum(jv * jv, axis=1), minlength=len(rows))
        use = info[pair_id] >= min_cond * info.max()
    prior_w = np.r_[0.0, 1.0 / tilt_prior_rad**2, 1.0 / tilt_prior_rad**2, np.full(nshift, 1e-6)]
    shift_j = np.zeros((len(a), 2, nshift))
    if free_shift:
        shift_j[np.arange(len(a)), 0, pair_id] = 1.0 / noise_px
        shift_j[np.arange(len(a)), 1, npair + pair_id] = 1.0 / noise_px
    solved = _huber_gauss_newton(residuals, p, prior_w, 3, shift_j, 10, use)
    if solved is None:
        return None
    p, A, w = solved
    e = np.hypot(*residuals(p).T)
    inl = (e < 4.0) & use
    if inl.sum() < MIN_ROAD_POINTS or not np.all(np.isfinite(p)) or p[0] <= 0:
        return None
    s2 = float(np.sum(w[inl] * e[inl] ** 2) / max(1, 2 * int(inl.sum()) - len(p)))
    std = math.sqrt(max(float(np.linalg.inv(A)[0, 0]) * max(s2, 0.25), 0.0))
    return JointFit(float(p[0]), std, len(set(pair_id[use].tolist())), int(use.sum()), int(inl.sum()))
