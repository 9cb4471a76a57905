"""Focal length from the ground's rigid motion while the ego yaws (issue 14 item 4, candidate (a)).

A level camera at height ``h`` above a ground plane sees a ground point at forward distance ``X`` and
lateral offset ``Y`` (metres, camera x right, y down, z forward) at image column ``x`` and row ``y``:

    X = f h / (y - y_h),     Y = h (x - c_x) / (y - y_h)

(``y_h`` the horizon row, ``c_x`` the principal column, ``f`` the focal length in pixels). In the
focal-free bird's-eye coordinates ``u = 1 / (y - y_h)``, ``w = (x - c_x) / (y - y_h)`` the true ground
is ``(X, Y) = h (f u, w)``: the focal length only stretches the forward axis. Between two frames the
ground moves rigidly, ``(X, Y) -> R(psi) (X, Y) + t``; in ``(u, w)`` that motion reads
``M = S^-1 R S`` with ``S = diag(f, 1)``, i.e. ``M01 = -f^-1 sin psi`` and ``M10 = f sin psi``, so

    f^2 = -M10 / M01

for every frame pair that turns (``psi != 0``; under a straight drive ``M`` is the identity and says
nothing). ``M`` comes from the image: the ground points' frame-to-frame homography ``H`` (RANSAC on
tracked corners below the horizon) conjugated into ``(u, w)`` coordinates. Each pair gives one
``log f``; pairs are weighted by ``sin^2 psi`` (a pair's ``f^2`` error goes as its tracking noise over
its yaw) and combined by a weighted median; the stated 1-sigma of ``log f`` is a bootstrap over pairs.
The camera height drops out; the horizon row and a level camera (no roll) are assumed.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Sequence
from dataclasses import dataclass

import cv2
import numpy as np

#: Pairs whose yaw shift ``|M10| = f |sin psi|`` is below this are left out: a straight drive's ``M``
#: is the identity and its ``f`` is noise. Pixels.
MIN_YAW_SHIFT_PX = 8.0
#: The ground region starts this many pixels below the horizon (far ground is too compressed).
HORIZON_MARGIN_PX = 20.0
#: Minimum RANSAC inliers of a ground homography.
MIN_INLIERS = 40
#: Bootstrap resamples for the stated sigma (seeded).
BOOTSTRAP = 200


@dataclass(frozen=True)
class GroundFocal:
    """Focal length (pixels) from the ground's rigid motion, with its 1-sigma of ``log f``.

    ``focal_px`` is None when fewer than ``min_pairs`` frame pairs turned enough; ``pairs`` counts the
    pairs used, ``yaw_rad`` is their median absolute yaw (radians), ``per_pair`` each pair's focal (px),
    ``horizon_row`` the horizon row used (pixels), ``roll_rad`` the camera roll fitted with it (radians;
    NaN when not fitted).
    """

    focal_px: float | None
    sigma_log: float
    pairs: int
    yaw_rad: float
    per_pair: tuple[float, ...]
    horizon_row: float = math.nan
    roll_rad: float = math.nan


def bird_matrix(cx: float, horizon_row: float) -> np.ndarray:
    """Homogeneous map from image pixels ``(x, y, 1)`` to focal-free bird's-eye ``(1, x - c_x, y - y_h)``."""
    return np.array([[0.0, 0.0, 1.0], [1.0, 0.0, -cx], [0.0, 1.0, -horizon_row]])


def pair_terms(homography: np.ndarray, cx: float, horizon_row: float) -> tuple[float, float, float]:
    """``(M10, M01, d)`` of one ground homography (image to image, pixels) in focal-free bird's-eye terms.

    ``M10 = f sin(psi)`` is the yaw's uniform image shift (pixels), ``M01 = -sin(psi) / f`` (1/pixels),
    ``d`` the forward shift of ``u`` (``-T / (f h)`` for a travel ``T`` metres; 1/pixels, negative forward).
    """
    b = bird_matrix(cx, horizon_row)
    g = b @ homography @ np.linalg.inv(b)
    g = g / g[2, 2]
    return float(g[1, 0]), float(g[0, 1]), float(g[0, 2])


def ground_homography(
    a: np.ndarray, b: np.ndarray, horizon_row: float, bottom_rows: int, mask: np.ndarray | None = None
) -> np.ndarray | None:
    """Ground-plane homography from greyscale frame ``a`` to ``b`` (pixels), or None.

    Corners below ``horizon_row + HORIZON_MARGIN_PX`` and above the last ``bottom_rows`` rows (a
    dashboard, a burned-in overlay), optionally only where ``mask`` is non-zero, tracked with pyramidal
    Lucas-Kanade (forward-backward checked); the homography by RANSAC at 1.5 px.
    """
    h, w = a.shape
    region = np.zeros((h, w), np.uint8)
    top = int(max(0, min(h - 1, horizon_row + HORIZON_MARGIN_PX)))
    region[top : h - bottom_rows] = 255
    if mask is not None:
        region &= mask
    p0 = cv2.goodFeaturesToTrack(a, 600, 0.005, 6, mask=region)
    if p0 is None or len(p0) < MIN_INLIERS:
        return None
    p1, st, _ = cv2.calcOpticalFlowPyrLK(a, b, p0, None, winSize=(21, 21), maxLevel=3)  # type: ignore[call-overload]
    back, st2, _ = cv2.calcOpticalFlowPyrLK(b, a, p1, None, winSize=(21, 21), maxLevel=3)  # type: ignore[call-overload]
    good = (st[:, 0] == 1) & (st2[:, 0] == 1) & (np.linalg.norm(back - p0, axis=2)[:, 0] < 0.5)
    if int(good.sum()) < MIN_INLIERS:
        return None
    hom, inl = cv2.findHomography(p0[good], p1[good], cv2.RANSAC, 1.5, maxIters=2000, confidence=0.999)
    if hom is None or inl is None or int(inl.sum()) < MIN_INLIERS:
        return None
    return np.asarray(hom, float)


def combine(terms: Sequence[tuple[float, float, float]], min_pairs: int, seed: int) -> GroundFocal:
    """``f = q^-1/2`` from the weighted median of ``q = -M01 / M10`` (= ``f^-2``) over the pairs.

    Only pairs whose yaw shift ``|M10|`` is at least :data:`MIN_YAW_SHIFT_PX`; weights ``M10^2``
    (``M10`` is the well-measured term, so the ratio is formed in the direction whose noise is in the
    numerator: no attenuation bias). 1-sigma of ``log f`` by a seeded bootstrap over pairs.
    """
    kept = [(m10, m01) for m10, m01, _ in terms if abs(m10) >= MIN_YAW_SHIFT_PX]
    if len(kept) < min_pairs:
        return GroundFocal(None, math.inf, len(kept), 0.0, ())
    m10 = np.array([a for a, _ in kept])
    q = -np.array([b for _, b in kept]) / m10
    wts = m10**2
    rng = np.random.default_rng(seed)
    boots = np.array([_weighted_median(q[i], wts[i]) for i in rng.integers(0, len(kept), (BOOTSTRAP, len(kept)))])
    med = _weighted_median(q, wts)
    if med <= 0.0:
        return GroundFocal(None, math.inf, len(kept), 0.0, ())
    logs = -0.5 * np.log(np.clip(boots, med * 1e-3, None))
    focal = 1.0 / math.sqrt(med)
    per_pair = tuple(float(1.0 / math.sqrt(x)) if x > 0 else math.nan for x in q)
    return GroundFocal(focal, float(np.std(logs)), len(kept), float(np.median(np.abs(m10)) / focal), per_pair)


def combine_with_roll(terms: Sequence[tuple[float, float, float]], min_pairs: int, seed: int) -> GroundFocal:
    """``f`` and a static camera roll from all segments at once: ``M01 = -M10 / f^2 + rho d``.

    A camera rolled by ``rho`` (radians) tilts the horizon, ``y - y_h`` gains ``-rho (x - c_x)``, and a
    forward travel ``d`` then reads ``M01 = rho d`` without any turn: on a fast, gently curving road
    that term outweighs the yaw's. Straight segments measure ``rho``, turning ones ``f``: a Huber
    (IRLS) linear fit over every segment; ``None`` unless ``min_pairs`` segments turn
    (:data:`MIN_YAW_SHIFT_PX`) and the fit's ``-1/f^2`` is negative. 1-sigma of ``log f``: seeded
    bootstrap over segments.
    """
    arr = np.array(terms, float).reshape(-1, 3)
    turning = int(np.sum(np.abs(arr[:, 0]) >= MIN_YAW_SHIFT_PX))
    if turning < min_pairs:
        return GroundFocal(None, math.inf, turning, 0.0, ())
    coef = _huber_fit(arr[:, [0, 2]], arr[:, 1])
    if coef[0] >= 0.0:
        return GroundFocal(None, math.inf, turning, 0.0, ())
    rng = np.random.default_rng(seed)
    boots = [_huber_fit(arr[i][:, [0, 2]], arr[i][:, 1])[0] for i in rng.integers(0, len(arr), (BOOTSTRAP, len(arr)))]
    logs = -0.5 * np.log(np.clip(-np.array(boots), -coef[0] * 1e-3, None))
    focal = 1.0 / math.sqrt(-coef[0])
    yaw = float(np.median(np.abs(arr[np.abs(arr[:, 0]) >= MIN_YAW_SHIFT_PX, 0])) / focal)
    return GroundFocal(focal, float(np.std(logs)), turning, yaw, (), roll_rad=float(coef[1]))


def _huber_fit(x: np.ndarray, y: np.ndarray, iters: int = 20) -> np.ndarray:
    """Linear fit ``y ~ x c`` (no intercept) by iteratively reweighted least squares, Huber at 1.345 MAD."""
    scale = np.std(x, axis=0) + 1e-30
    xs, w = x / scale, np.ones(len(y))
    coef = np.zeros(x.shape[1])
    for _ in range(iters):
        sw = np.sqrt(w)
        coef = np.linalg.lstsq(xs * sw[:, None], y * sw, rcond=None)[0]
        r = y - xs @ coef
        mad = 1.4826 * float(np.median(np.abs(r))) + 1e-30
        w = np.minimum(1.0, 1.345 * mad / np.maximum(np.abs(r), 1e-30))
    return coef / scale


def _weighted_median(values: np.ndarray, weights: np.ndarray) -> float:
    """Weighted median (the value where the cumulative weight passes half)."""
    order = np.argsort(values)
    cum = np.cumsum(weights[order])
    return float(values[order][int(np.searchsorted(cum, 0.5 * cum[-1]))])


def composed_terms(
    homographies: Sequence[np.ndarray | None], cx: float, horizon_row: float, target_px: float, max_pairs: int
) -> list[tuple[float, float, float]]:
    """``(M10, M01, d)`` (:func:`pair_terms`) of ground homographies chained up to a yaw shift ``target_px``.

    A gentle curve turns too little between two frames; chaining (``H_0k = H_k-1,k ... H_01``) lets the
    yaw grow linearly while the tracking noise grows as a random walk. A chain restarts after
    ``max_pairs`` homographies or at a missing one.
    """
    out: list[tuple[float, float, float]] = []
    acc, n = np.eye(3), 0
    for hom in homographies:
        if hom is None:
            acc, n = np.eye(3), 0
            continue
        acc, n = hom @ acc, n + 1
        terms = pair_terms(acc, cx, horizon_row)
        if abs(terms[0]) >= target_px or n >= max_pairs:
            out.append(terms)
            acc, n = np.eye(3), 0
    return out


def horizon_from_ground(homographies: Sequence[np.ndarray | None], cx: float, rows: np.ndarray) -> float:
    """Horizon row (pixels, one of ``rows``) at which the ground's motion keeps its scale on both axes.

    A rigid ground motion has ``M00 = M11`` (both ``cos psi``) in bird's-eye terms; with the horizon
    ``delta`` rows off, a forward travel ``d`` (in ``u``) reads ``M00 / M11 = 1 - d delta``: first order
    in ``delta`` and free of the focal length. The row whose median ``|M00 / M11 - 1|`` over the
    homographies is smallest.
    """
    homs = [h for h in homographies if h is not None]
    cost = []
    for row in rows:
        b = bird_matrix(cx, float(row))
        binv = np.linalg.inv(b)
        ratios = []
        for hom in homs:
            g = b @ hom @ binv
            ratios.append(g[0, 0] / g[1, 1] - 1.0)
        cost.append(abs(float(np.median(ratios))) if ratios else math.inf)
    return float(rows[int(np.argmin(cost))])


def focal_from_ground(
    frames: Sequence[np.ndarray],
    horizon_row: float,
    cx: float | None = None,
    gap: int = 2,
    bottom_rows: int = 0,
    min_pairs: int = 3,
    seed: int = 0,
    target_px: float = 25.0,
    max_pairs: int = 10,
    horizon_search_px: float = 0.0,
    masks: Sequence[np.ndarray | None] | None = None,
    fit_roll: bool = False,
) -> GroundFocal:
    """Focal length (pixels) of a level camera from greyscale ``frames`` of a drive that turns.

    ``horizon_row`` and ``cx`` (default: the image's centre column) in pixels; homographies between
    frames ``gap`` apart, chained (:func:`composed_terms`) up to a yaw shift of ``target_px`` pixels or
    ``max_pairs`` links; ``bottom_rows`` image rows at the bottom left out (dashboard, overlay text).
    With ``horizon_search_px`` > 0 the horizon is refined within that many rows above / below
    ``horizon_row`` (:func:`horizon_from_ground`; the ground region stays the one below ``horizon_row``).
    ``masks`` (one per frame, uint8, non-zero where corners may start; None for none) keep road users out.
    ``fit_roll``: a static camera roll fitted together with the focal length (:func:`combine_with_roll`).
    """
    centre = frames[0].shape[1] / 2.0 if cx is None else cx
    homs = [
        ground_homography(frames[k], frames[k + gap], horizon_row, bottom_rows, None if masks is None else masks[k])
        for k in range(0, len(frames) - gap, gap)
    ]
    if horizon_search_px > 0:
        rows = horizon_row + np.arange(-horizon_search_px, horizon_search_px + 1.0, 2.0)
        horizon_row = horizon_from_ground(homs, centre, rows)
    terms = composed_terms(homs, centre, horizon_row, target_px, max_pairs)
    est = (combine_with_roll if fit_roll else combine)(terms, min_pairs, seed)
    return dataclasses.replace(est, horizon_row=horizon_row)
