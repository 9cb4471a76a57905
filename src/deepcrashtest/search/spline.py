"""The ego path as a time B-spline, its perturbation, and the trajectory of a perturbed path.

Frames and units: world frame (x forward at t=0, y left), metres, seconds, radians. The spline is
``x(t), y(t) = BSpline(knots, cx | cy, degree)`` exactly as stored in ``Vehicle.spline``
(``scenario.SplineParams``). Scenarios from stage 2 carry it; for raw scenarios (KITTI ground
truth, ``Vehicle.spline is None``) a least-squares cubic B-spline is fitted here
(:mod:`deepcrashtest.sim.splines`: SciPy's splines in NumPy, without SciPy's import time).
"""

from __future__ import annotations

import functools

import numpy as np

from deepcrashtest.errors import UserError
from deepcrashtest.scenario import MAX_COORD_M, SplineParams, Trajectory, Vehicle
from deepcrashtest.sim.splines import BSpline, lsq_spline

#: Spacing of the interior knots of a fitted ego spline, seconds (one control point per ~second).
DEFAULT_KNOT_SPACING_S = 1.0


def fit_spline(t: np.ndarray, xy: np.ndarray, knot_spacing_s: float = DEFAULT_KNOT_SPACING_S, degree: int = 3):
    """Least-squares clamped B-spline through ``xy`` (K, 2) sampled at times ``t`` (K,), seconds.

    Interior knots are spaced ``knot_spacing_s`` apart (fewer when the samples are too few for
    the Schoenberg-Whitney conditions). Returns a ``SplineParams``.
    """
    t = np.asarray(t, dtype=float)
    xy = np.asarray(xy, dtype=float)
    if len(t) < degree + 1:
        raise UserError(f"ego trajectory has {len(t)} samples; a degree-{degree} spline needs >= {degree + 1}")
    span = t[-1] - t[0]
    n_interior = max(0, min(int(span / knot_spacing_s) - 1, len(t) - degree - 1))
    interior = np.linspace(t[0], t[-1], n_interior + 2)[1:-1]
    knots = np.concatenate([np.full(degree + 1, t[0]), interior, np.full(degree + 1, t[-1])])
    c = lsq_spline(t, xy, knots, degree).c
    reach = float(np.abs(c).max())
    if not reach <= MAX_COORD_M:  # samples that jump far apart: the least-squares fit overshoots them
        raise UserError(
            f"ego trajectory: its fitted spline leaves the world's +-{MAX_COORD_M:g} m (a control point at "
            f"{reach:.0f} m); the ego's samples jump too far for the search to bend its path"
        )
    return SplineParams(knots=knots.tolist(), cx=c[:, 0].tolist(), cy=c[:, 1].tolist(), degree=degree)


def ego_spline(ego: Vehicle, knot_spacing_s: float = DEFAULT_KNOT_SPACING_S) -> SplineParams:
    """The ego's stored spline, or one fitted to its trajectory when the scenario has none."""
    if ego.spline is not None:
        return ego.spline
    a = ego.trajectory.arrays()
    return fit_spline(a["t"], np.column_stack([a["x"], a["y"]]), knot_spacing_s)


def control_points(sp: SplineParams) -> np.ndarray:
    """(M, 2) control points, metres."""
    return np.column_stack([sp.cx, sp.cy]).astype(float)


def evaluate_paths(sp: SplineParams, ctrl: np.ndarray, t: np.ndarray, nu: int = 0) -> np.ndarray:
    """Evaluate the spline (or its ``nu``-th time derivative) for many control-point sets.

    ``ctrl`` is (B, M, 2) (or (M, 2)); returns (B, K, 2) (or (K, 2)) at times ``t`` (K,), clamped
    to the knot span. At most ``degree + 1`` basis functions are non-zero at a time: thousands of variants cost
    a few array operations.
    """
    knots = np.asarray(sp.knots, dtype=float)
    tt = np.clip(np.asarray(t, dtype=float), knots[0], knots[-1])
    first, weights = _band(knots.tobytes(), int(sp.degree), tt.tobytes(), int(nu))
    c = np.asarray(ctrl, dtype=float)
    # sum_m basis[k, m] * ctrl[..., m, :] over the band of non-zero basis functions of each row, in the order of m
    # from 0.0: ``np.einsum("km,...md->...kd", basis, ctrl)``'s sum (the terms outside the band are exact zeros)
    out = np.zeros(c.shape[:-2] + (len(first), c.shape[-1]))
    term = np.empty_like(out)
    for j in range(weights.shape[1]):
        np.take(c, first + j, axis=-2, out=term)
        term *= weights[:, j, None]
        out += term
    return out


@functools.lru_cache(maxsize=16)
def _band(knots_b: bytes, degree: int, t_b: bytes, nu: int) -> tuple[np.ndarray, np.ndarray]:
    """The basis matrix (K, M) of :func:`basis_matrix` as bands of W columns: each row's first column ``first`` (K,)
    and its values there (K, W); W is the widest run of non-zero columns of a row (at most ``degree + 1``), bands
    ending past column M - 1 start earlier (their extra columns hold zeros). Read-only, kept as the matrix is."""
    basis = _basis_cached(knots_b, degree, t_b, nu)
    K, M = basis.shape
    nz = basis != 0
    first = np.argmax(nz, axis=1)  # 0 for a row of zeros
    last = np.where(nz.any(axis=1), M - 1 - np.argmax(nz[:, ::-1], axis=1), 0)
    width = min(int((last - first).max(initial=0)) + 1, M)
    first = np.minimum(first, M - width)
    weights = basis[np.arange(K)[:, None], first[:, None] + np.arange(width)[None, :]]
    first.flags.writeable = False
    weights.flags.writeable = False
    return first, weights


def basis_matrix(knots: np.ndarray, degree: int, t: np.ndarray, nu: int = 0) -> np.ndarray:
    """(K, M) matrix of B-spline basis functions (or their derivatives) at times ``t`` (read-only; the last
    few are kept: a search asks the same ones for every batch and every variant file)."""
    k = np.asarray(knots, dtype=float)
    tt = np.asarray(t, dtype=float)
    return _basis_cached(k.tobytes(), int(degree), tt.tobytes(), int(nu))


@functools.lru_cache(maxsize=16)
def _basis_cached(knots_b: bytes, degree: int, t_b: bytes, nu: int) -> np.ndarray:
    out = _basis(np.frombuffer(knots_b), degree, np.frombuffer(t_b), nu)
    out.flags.writeable = False
    return out


def _basis(knots: np.ndarray, degree: int, t: np.ndarray, nu: int) -> np.ndarray:
    m = len(knots) - degree - 1
    return BSpline(knots, np.eye(m), degree).derivative(nu)(t)


def trajectory_from_path(sp: SplineParams, ctrl: np.ndarray, t: np.ndarray, min_speed_mps: float = 0.05) -> Trajectory:
    """Trajectory (x, y, yaw, speed) of the spline with control points ``ctrl`` (M, 2) at times ``t``.

    Speed is |d(x, y)/dt|; yaw is the direction of motion, unwrapped, held over samples slower
    than ``min_speed_mps`` (a standing vehicle keeps its heading).
    """
    xy, yaw, speed = path_kinematics(sp, np.asarray(ctrl, dtype=float)[None], t, min_speed_mps)
    return Trajectory.from_arrays(t, xy[0, :, 0], xy[0, :, 1], yaw[0], speed[0])


def path_kinematics(
    sp: SplineParams, ctrl: np.ndarray, t: np.ndarray, min_speed_mps: float = 0.05
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """:func:`trajectory_from_path`'s arrays for ``B`` control-point sets ``ctrl`` (B, M, 2) at once: positions
    (B, K, 2) in metres, yaw (B, K) in radians and speed (B, K) in m/s at times ``t`` (K,); each path's are the bits
    it gets alone (every step is element by element or runs along a path)."""
    xy = evaluate_paths(sp, ctrl, t)
    vel = evaluate_paths(sp, ctrl, t, nu=1)
    speed = np.hypot(vel[..., 0], vel[..., 1])
    yaw = np.arctan2(vel[..., 1], vel[..., 0])
    moving = speed >= min_speed_mps
    k = np.arange(len(t))
    idx = np.maximum.accumulate(np.where(moving, k, 0), axis=1)  # the last moving sample so far
    first = np.argmax(moving, axis=1)[:, None]
    idx = np.where(k < first, first, idx)  # before the first moving sample: its heading
    yaw = np.where(moving.any(axis=1)[:, None], np.take_along_axis(yaw, idx, axis=1), 0.0)
    return xy, np.unwrap(yaw, axis=-1), speed
