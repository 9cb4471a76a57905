"""A rolling shutter's trace in a frame pair: the camera's rotation changing from the top rows to the bottom ones.

A static point's translation flow runs along the line from the focus of expansion (the direction of travel), so
its flow across that line is the camera's rotation only. A global shutter exposes every row at once: one small
rotation (3 rates, the instantaneous-motion model) explains that flow up to the tracking noise. A rolling shutter
exposes the rows one after another: while the camera shakes, the rotation between two frames differs from the top
rows to the bottom ones, which a second set of 3 rates scaled by the row (``row / height - 0.5``) takes up. Both
are fitted by iteratively reweighted least squares (Huber weights); the residuals' robust sigmas and the change
of the rotation over the frame are returned. Neither the essential matrix nor the road-plane fit of
:mod:`deepcrashtest.geometry.egomotion` models it: the road plane (bottom rows) is scaled with the rotation of the
scene above it.

Measured (issue 14 item 5, ``bench/rolling_shutter.py``, the first 50 frames, keyframe pairs of the ego-motion
estimator): KITTI odometry seq00 / seq06 (global shutter) 0.15 -> 0.15 px, the row-varying rotation lowering the
residual by >= 15 % on 2 / 6 % of the pairs, its top-to-bottom change 1.0 / 0.6 px (noise); the Udacity highway
clip (smooth road) 0.12 -> 0.11 px, 21 %, 1.4 px; the 10 fps crash clips ccd_000014 1.07 -> 0.79 px, 69 %, 12 px,
ccd_000080 0.80 -> 0.63, 58 %, 8 px, ccd_000755 1.14 -> 0.88, 56 %, 31 px. Taking the row-varying part out of
the pairs before the essential matrix did not bring ccd_000014's speed nearer its overlay (README).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

#: Fewer points than this (off the focus of expansion) and nothing is fitted.
MIN_POINTS = 40


@dataclass(frozen=True)
class RollingShutterFit:
    """One rotation against a row-varying one, fitted to a frame pair's flow across the direction of travel."""

    global_px: float  #: robust 1-sigma (px) of the across-travel flow one rotation leaves
    rolling_px: float  #: the same with the rotation varying linearly with the row
    row_rates: np.ndarray  #: change (rad) of the rotation about camera x, y, z from the top row to the bottom one
    points: int  #: points fitted

    def row_flow(self, p0: np.ndarray, K: np.ndarray, height: int) -> np.ndarray:
        """(N, 2) px: the flow the row-varying part adds to each point of ``p0`` (px), against the middle row."""
        ju, jv = rotation_flow(p0, K)
        rate = (p0[:, 1] / height - 0.5)[:, None] * self.row_rates[None, :]
        return np.column_stack([np.sum(ju * rate, axis=1), np.sum(jv * rate, axis=1)])

    def change_px(self, K: np.ndarray) -> float:
        """The row-varying rotation's size as image flow (px at the focal length of ``K``)."""
        return float(np.linalg.norm(self.row_rates) * K[0, 0])


def rotation_flow(p: np.ndarray, K: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(N, 3) each for u and v: the image flow (px) of each point ``p`` (px, N x 2; camera matrix ``K``) per
    small camera rotation (rad) about camera x (right), y (down) and z (forward)."""
    x, y = (p[:, 0] - K[0, 2]) / K[0, 0], (p[:, 1] - K[1, 2]) / K[1, 1]
    ju = np.stack([x * y, -(1.0 + x * x), y], axis=1) * K[0, 0]
    jv = np.stack([1.0 + y * y, -x * y, -x], axis=1) * K[1, 1]
    return ju, jv


def rolling_shutter_fit(
    p0: np.ndarray,
    p1: np.ndarray,
    K: np.ndarray,
    foe: tuple[float, float],
    height: int,
    search_px: float = 0.0,
    steps: int = 4,
) -> RollingShutterFit | None:
    """Fit one rotation and a row-varying rotation to a frame pair (see the module docstring).

    ``p0`` -> ``p1``: (N, 2) px of static points in the earlier and later frame; ``K``: their camera matrix;
    ``foe``: the focus of expansion (px; the direction of travel); ``height``: the image height (px).
    ``search_px``: each model is also fitted with the focus moved on a grid of ``2 steps + 1`` x ``2 steps + 1``
    points within this many px of ``foe`` and keeps its best (a focus of expansion off by some tens of px moves
    near points across the line from it, which a row-varying rotation would partly take up). Points within 5 %
    of the height from the focus are left out (their direction across the travel is undefined). None with fewer
    than :data:`MIN_POINTS` points left."""
    offsets = np.linspace(-search_px, search_px, 2 * steps + 1) if search_px > 0 else np.zeros(1)
    best3: float | None = None
    best6: tuple[float, np.ndarray, int] | None = None
    for du in offsets:
        for dv in offsets:
            fit = _fit_at(p0, p1, K, (foe[0] + du, foe[1] + dv), height)
            if fit is None:
                continue
            s3, s6, rates, n = fit
            if best3 is None or s3 < best3:
                best3 = s3
            if best6 is None or s6 < best6[0]:
                best6 = (s6, rates, n)
    if best3 is None or best6 is None:
        return None
    return RollingShutterFit(best3, best6[0], best6[1], best6[2])


def _fit_at(
    p0: np.ndarray, p1: np.ndarray, K: np.ndarray, foe: tuple[float, float], height: int
) -> tuple[float, float, np.ndarray, int] | None:
    """(one rotation's robust residual px, the row-varying rotation's, its row rates, points) at one focus."""
    rad = p0 - np.asarray(foe, dtype=float)
    dist = np.linalg.norm(rad, axis=1)
    use = dist > 0.05 * height
    if use.sum() < MIN_POINTS:
        return None
    ju, jv = rotation_flow(p0[use], K)
    n = np.stack([-rad[use, 1], rad[use, 0]], axis=1) / dist[use, None]  # across the line from the focus
    a3 = n[:, :1] * ju + n[:, 1:] * jv
    b = np.sum(n * (p1[use] - p0[use]), axis=1)
    _, s3 = _robust_lstsq(a3, b)
    w6, s6 = _robust_lstsq(np.hstack([a3, a3 * (p0[use, 1:2] / height - 0.5)]), b)
    return s3, s6, w6[3:], int(use.sum())


def _robust_lstsq(a: np.ndarray, b: np.ndarray, iters: int = 15) -> tuple[np.ndarray, float]:
    """``a x ~ b`` by iteratively reweighted least squares (Huber weights at 1.5 robust sigmas) -> (x, the
    residuals' robust sigma: 1.4826 x their median absolute value)."""
    w = np.ones(len(b))
    x: np.ndarray = np.zeros(a.shape[1])
    s = 0.0
    for _ in range(iters):
        x = np.linalg.lstsq(a * w[:, None], b * w, rcond=None)[0]
        r = np.abs(b - a @ x)
        s = 1.4826 * float(np.median(r)) + 1e-9
        w = np.sqrt(np.minimum(1.0, 1.5 * s / np.maximum(r, 1e-12)))
    return x, s
