"""Trajectory smoothing: Savitzky-Golay, then a two-level spline fit.

1. The observed positions (world frame, metres) are put on a uniform time grid of the video's
   frame period (gaps are bridged linearly) and filtered with a Savitzky-Golay filter whose
   window is given in seconds.
2. Local level: overlapping windows (``local_window_s`` long, half overlap) are each fitted with
   a parametric smoothing spline x(t), y(t) allowed a high RMS deviation (``local_sigma_m``);
   the window fits are blended with tapered weights. A window is short, so a sudden swerve or
   brake lasting about a second is kept, while frame-to-frame jitter is removed.
3. Global level: one parametric spline through the blended curve with a low allowed deviation
   (``global_sigma_m``): a single smooth C2 parameterisation of the whole track.

A smoothing factor is always stated as an RMS deviation in metres: FITPACK's ``s`` is the sum of
squared residuals, so ``s = n * sigma**2``.
"""

from __future__ import annotations

import warnings
from dataclasses import dataclass
from typing import Any

import numpy as np
from scipy.interpolate import splev, splprep
from scipy.signal import savgol_filter

from deepcrashtest.errors import UserError
from deepcrashtest.scenario import SplineParams
from deepcrashtest.trajectory.params import Stage2Params

Tck = tuple[np.ndarray, list[np.ndarray], int]


def fit_xy_spline(t: np.ndarray, x: np.ndarray, y: np.ndarray, sigma_m: float, degree: int = 3) -> Tck:
    """Parametric smoothing spline x(t), y(t) with shared knots; RMS deviation <= ``sigma_m`` (metres).

    Degree is lowered for very short inputs (2 samples give a straight segment).
    """
    t = np.asarray(t, dtype=float)
    if len(t) < 2:
        raise UserError("a trajectory needs at least 2 samples to fit a spline")
    k = min(degree, len(t) - 1)
    s = len(t) * sigma_m**2
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # FITPACK's "s too small" notes: the fit is still the closest it can do
        (knots, coefs, k_out), _ = splprep([np.asarray(x, float), np.asarray(y, float)], u=t, s=s, k=k)
    n = len(knots) - k_out - 1
    return np.asarray(knots, float), [np.asarray(c, float)[:n] for c in coefs], int(k_out)


def eval_xy(tck: Tck, t: np.ndarray, der: int = 0) -> np.ndarray:
    """(N, 2) positions (der=0, metres) or derivatives (m/s, m/s^2 ...) of a spline at times ``t``."""
    x, y = splev(np.asarray(t, dtype=float), tck, der=der)
    return np.column_stack([x, y])


def spline_params(tck: Tck) -> SplineParams:
    knots, (cx, cy), k = tck
    return SplineParams(knots=knots.tolist(), cx=cx.tolist(), cy=cy.tolist(), degree=k)


def uniform_grid(t: np.ndarray, x: np.ndarray, y: np.ndarray, fps: float) -> tuple[np.ndarray, ...]:
    """Resample a (possibly gappy) track onto a uniform grid of step 1/fps from its first sample."""
    dt = 1.0 / fps
    n = int(np.floor((t[-1] - t[0]) / dt + 1e-6)) + 1
    tg = t[0] + dt * np.arange(n)
    if tg[-1] < t[-1] - 1e-6:
        tg = np.append(tg, t[-1])
    return tg, np.interp(tg, t, x), np.interp(tg, t, y)


def savgol_xy(x: np.ndarray, y: np.ndarray, fps: float, window_s: float, polyorder: int) -> tuple[np.ndarray, ...]:
    """Savitzky-Golay filter of uniformly sampled positions; window in seconds (odd number of frames)."""
    w = int(round(window_s * fps)) | 1
    w = min(w, len(x) if len(x) % 2 else len(x) - 1)
    if w <= polyorder:
        return x.copy(), y.copy()
    return (
        savgol_filter(x, w, polyorder, mode="interp"),
        savgol_filter(y, w, polyorder, mode="interp"),
    )


def local_blend(t: np.ndarray, x: np.ndarray, y: np.ndarray, window_s: float, sigma_m: float) -> np.ndarray:
    """Blend of smoothing-spline fits in half-overlapping windows of ``window_s`` seconds -> (N, 2)."""
    n = len(t)
    dt = float(np.median(np.diff(t))) if n > 1 else 1.0
    w = max(4, int(round(window_s / dt)))
    if n <= w:
        return eval_xy(fit_xy_spline(t, x, y, sigma_m), t)
    starts = list(range(0, n - w, max(1, w // 2))) + [n - w]
    acc = np.zeros((n, 2))
    wsum = np.zeros(n)
    taper = np.hanning(w + 2)[1:-1]
    for i0 in starts:
        sl = slice(i0, i0 + w)
        fit = eval_xy(fit_xy_spline(t[sl], x[sl], y[sl], sigma_m), t[sl])
        acc[sl] += fit * taper[:, None]
        wsum[sl] += taper
    return acc / wsum[:, None]


@dataclass(frozen=True)
class SmoothTrack:
    """The smoothed observed part of one track: a spline over [t0, t1] (seconds, video time)."""

    tck: Tck
    t0: float
    t1: float
    sigma_scale: float = 1.0

    def pos(self, t: Any) -> np.ndarray:
        return eval_xy(self.tck, np.atleast_1d(t))

    def vel(self, t: Any) -> np.ndarray:
        return eval_xy(self.tck, np.atleast_1d(t), der=1)


def two_level_spline(
    t: np.ndarray, x: np.ndarray, y: np.ndarray, fps: float, p: Stage2Params, scale: float = 1.0
) -> Tck:
    """Savitzky-Golay + local spline blend + global spline (see the module docstring)."""
    tg, xg, yg = uniform_grid(t, x, y, fps)
    xs, ys = savgol_xy(xg, yg, fps, p.savgol_window_s * scale, p.savgol_polyorder)
    blended = local_blend(tg, xs, ys, p.local_window_s, p.local_sigma_m * scale)
    return fit_xy_spline(tg, blended[:, 0], blended[:, 1], p.global_sigma_m * scale)


def max_tangential_accel(tck: Tck, t0: float, t1: float, dt: float) -> float:
    """Largest |d speed / dt| of a spline sampled every ``dt`` seconds on [t0, t1], m/s^2."""
    if t1 - t0 < 2 * dt:
        return 0.0
    tg = np.arange(t0, t1 + 1e-9, dt)
    v = np.hypot(*eval_xy(tck, tg, der=1).T)
    return float(np.abs(np.diff(v) / np.diff(tg)).max())


def smooth_track(t: np.ndarray, x: np.ndarray, y: np.ndarray, fps: float, p: Stage2Params) -> SmoothTrack:
    """Smooth one observed track; if it still brakes harder than ``max_smoothing_accel_mps2`` (noise,
    not physics), the smoothing is repeated with doubled windows and tolerances (up to 3 times)."""
    t = np.asarray(t, float)
    scale = 1.0
    for _ in range(4):
        tck = two_level_spline(t, np.asarray(x, float), np.asarray(y, float), fps, p, scale)
        if max_tangential_accel(tck, t[0], t[-1], 1.0 / fps) <= p.max_smoothing_accel_mps2:
            break
        scale *= 2.0
    return SmoothTrack(tck, float(t[0]), float(t[-1]), scale)
