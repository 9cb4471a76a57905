"""A standing road user seen from a moving camera: one ground point fitted to its boxes over a track.

From each frame's camera pose (world x forward, y left, metres; yaw radians) a road user standing at the
ground point ``P`` is seen at bearing ``tan b = X / Z`` (camera x right, z forward) and its box is ``h = fy H /
Z_near`` pixels tall (``Z_near``: the depth of its near face, ``Z`` less half its extent along the line of
sight). Over a track the ego's own motion turns the line of sight to ``P`` (parallax), which fixes ``P``'s
range without the class's size: :func:`fit_standing` finds ``P`` and the height scale ``B = fy H`` (a log-
normal prior pulls ``B`` to the class's) by robust least squares (SciPy's ``least_squares``, soft-L1), and
optionally a bearing offset common to every frame: a camera whose principal column ``cx`` is off by
``delta`` px sees every bearing shifted by ``delta / fx`` (its forward axis column, see
:mod:`deepcrashtest.geometry.selfcalib_axis`).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True)
class Views:
    """One track's detected, uncut boxes and the camera poses they were seen from (one row each)."""

    x: np.ndarray  # camera position, world m
    y: np.ndarray
    yaw: np.ndarray  # camera heading, rad (left of world x)
    bearing: np.ndarray  # tan of the box centre's angle right of the camera's axis
    box_h: np.ndarray  # box height, px


@dataclass(frozen=True)
class StandingFit:
    """:func:`fit_standing`'s result."""

    xy: np.ndarray  # the ground point, world m
    log_scale: float  # log of the fitted height scale over the prior's (0: the class's size)
    offset: float  # the bearing offset (tan; 0 unless fitted)
    chi2: float  # mean squared normalised residual of the bearing and height rows
    parallax_rad: float  # how far the line of sight to ``xy`` turned over the rows


@dataclass(frozen=True)
class StandingNoise:
    """1-sigma errors of :func:`fit_standing`'s rows."""

    bearing: float  # tan (pixels over fx)
    height_px: float  # box height, px
    height_rel: float  # box height, relative (the box's own variation)
    size_rel: float  # the prior on the height scale, relative


def fit_standing(
    v: Views,
    extent: tuple[float, float],
    log_b0: float,
    p0: np.ndarray,
    noise: StandingNoise,
    free_offset: bool = False,
) -> StandingFit | None:
    """The standing point that explains the views ``v`` of a road user of ``extent`` (length, width, m) whose
    height scale ``log(fy H)`` has the prior mean ``log_b0``; ``p0``: a starting point (world m). None when a view
    or the start has no finite value, or the solver fails."""
    from scipy.optimize import least_squares

    c, s = np.cos(v.yaw), np.sin(v.yaw)
    length, width = extent
    sig_h = np.hypot(noise.height_px / v.box_h, noise.height_rel)

    def sight(p: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        dx, dy = p[0] - v.x, p[1] - v.y
        return np.maximum(c * dx + s * dy, 0.5), -s * dx + c * dy  # forward, left (m)

    def residuals(p: np.ndarray) -> np.ndarray:
        fwd, left = sight(p)
        a = np.arctan2(-left, fwd)
        near = fwd - 0.5 * (length * np.abs(np.cos(a)) + width * np.abs(np.sin(a))) * np.cos(a)
        offset = p[3] if free_offset else 0.0
        rb = (-left / fwd - v.bearing - offset) / noise.bearing
        rh = (np.log(v.box_h) - (p[2] - np.log(np.maximum(near, 0.5)))) / sig_h
        return np.r_[rb, rh, (p[2] - log_b0) / noise.size_rel]

    start = np.r_[p0, log_b0, 0.0] if free_offset else np.r_[p0, log_b0]
    if not np.isfinite(residuals(start)).all():  # a pose or box without a value: nothing to fit
        return None
    fit = least_squares(residuals, start, loss="soft_l1", f_scale=2.0)
    if not fit.success:
        return None
    fwd, left = sight(fit.x)
    return StandingFit(
        xy=np.asarray(fit.x[:2], dtype=float),
        log_scale=float(fit.x[2] - log_b0),
        offset=float(fit.x[3]) if free_offset else 0.0,
        chi2=float(np.mean(residuals(fit.x)[:-1] ** 2)),
        parallax_rad=float(np.ptp(np.arctan2(left, fwd))),
    )
