"""Reference motions for path following: a smoothed, time-indexed path per vehicle.

A vehicle's trajectory (box centre samples, world frame) becomes

* a geometric path resampled every ``PATH_DS_M`` metres of arc length, with heading and curvature,
  extended straight along its final heading (so a follower can always look ahead);
* a station profile ``s_ref(t)``, speed ``v_ref(t)`` and acceleration ``a_ref(t)`` on the simulation
  time grid (before the first sample: the initial values; after the last: constant speed).

Raw (label-derived) trajectories are noisy, so positions are smoothed with a cubic smoothing spline
(SciPy ``make_smoothing_spline``) whose cut-off is ``SMOOTH_CUTOFF_HZ``; speeds come from the
derivative of that spline, so path and speed profile are consistent. A vehicle that moves less
than ``STATIC_PATH_M`` in total is static: it holds its mean position and median label heading.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.interpolate import make_interp_spline, make_smoothing_spline

from deepcrashtest.scenario import Trajectory

PATH_DS_M = 0.25
SMOOTH_CUTOFF_HZ = 0.8
STATIC_PATH_M = 1.5
EXTENSION_M = 60.0


@dataclass
class Reference:
    """One reference motion on the simulation grid (all lengths in metres, times in steps of ``dt``)."""

    path: np.ndarray  # (P, 2) arc-length-uniform path (spacing PATH_DS_M)
    s_ref: np.ndarray  # (T,) station of the centre along ``path``
    v_ref: np.ndarray  # (T,) m/s
    start: int  # first grid index where the vehicle exists
    end: int  # last grid index of its samples
    init: np.ndarray  # (4,) x, y, yaw, speed at ``start``
    static: bool


def grid_index(t: float, dt: float) -> int:
    """Nearest simulation grid index of time ``t`` (s)."""
    return int(round(t / dt))


def _smooth_positions(t: np.ndarray, x: np.ndarray, y: np.ndarray, smooth: bool):
    """Return callables (pos(tq) -> (n, 2), vel(tq) -> (n, 2)) fitted to the samples."""
    n = len(t)
    if n >= 5 and smooth:
        h = float(np.median(np.diff(t)))
        lam = h / (2.0 * np.pi * SMOOTH_CUTOFF_HZ) ** 4
        sx, sy = make_smoothing_spline(t, x, lam=lam), make_smoothing_spline(t, y, lam=lam)
    elif n >= 4:
        sx, sy = make_interp_spline(t, x, k=3), make_interp_spline(t, y, k=3)
    else:
        k = 1 if n >= 2 else 0
        if k == 0:
            return (lambda tq: np.tile([x[0], y[0]], (len(np.atleast_1d(tq)), 1))), (
                lambda tq: np.zeros((len(np.atleast_1d(tq)), 2))
            )
        sx, sy = make_interp_spline(t, x, k=1), make_interp_spline(t, y, k=1)
    dx, dy = sx.derivative(), sy.derivative()
    return (lambda tq: np.column_stack([sx(tq), sy(tq)])), (lambda tq: np.column_stack([dx(tq), dy(tq)]))


def resample_path(points: np.ndarray, end_heading: float, extension: float, ds: float = PATH_DS_M) -> np.ndarray:
    """Resample a polyline every ``ds`` metres and extend it straight by ``extension`` metres."""
    seg = np.hypot(*np.diff(points, axis=0).T) if len(points) > 1 else np.zeros(0)
    s = np.concatenate([[0.0], np.cumsum(seg)])
    keep = np.r_[True, seg > 1e-9]
    s, pts = s[keep], points[keep]
    grid = np.arange(0.0, s[-1] + 1e-9, ds)
    if len(s) > 1:
        base = np.column_stack([np.interp(grid, s, pts[:, 0]), np.interp(grid, s, pts[:, 1])])
    else:
        base = pts[:1].copy()
    n_ext = int(np.ceil(extension / ds)) + 2
    last = base[-1]
    # continue from the grid point past the true end so spacing stays ds
    steps = (np.arange(1, n_ext + 1) * ds)[:, None]
    ext = last + steps * np.array([np.cos(end_heading), np.sin(end_heading)])
    return np.vstack([base, ext])


def path_heading_curvature(path: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Heading (rad, unwrapped) and curvature (1/m) along an arc-length-uniform path."""
    d = np.gradient(path, axis=0)
    heading = np.unwrap(np.arctan2(d[:, 1], d[:, 0]))
    curv = np.gradient(heading) / PATH_DS_M
    # curvature of a smoothed vehicle path: bounded by the minimum turning radius (~4 m)
    return heading, np.clip(curv, -0.25, 0.25)


def reference_from_trajectory(traj: Trajectory, times: np.ndarray, dt: float, smooth: bool = True) -> Reference:
    """Reference of one Scenario trajectory on the grid ``times`` (uniform, step ``dt``)."""
    a = traj.arrays()
    return build_reference(a["t"], np.column_stack([a["x"], a["y"]]), a["yaw"], times, dt, smooth)


def build_reference(
    t: np.ndarray, xy: np.ndarray, yaw_label: np.ndarray, times: np.ndarray, dt: float, smooth: bool = True
) -> Reference:
    """Reference from samples ``t`` (n,) s, ``xy`` (n, 2) m and headings ``yaw_label`` (n,) rad.

    ``smooth=False`` interpolates the samples exactly (cubic), for already smooth waypoints.
    """
    t = np.asarray(t, float)
    xy = np.asarray(xy, float)
    start, end, tq = _span(t, times, dt)
    pos_f, vel_f = _smooth_positions(t, xy[:, 0], xy[:, 1], smooth)
    return _reference(pos_f(tq), vel_f(tq), xy, np.asarray(yaw_label, float), times, start, end)


def build_references(
    t: np.ndarray, xys: np.ndarray, yaw_label: np.ndarray, times: np.ndarray, dt: float
) -> list[Reference]:
    """References of ``B`` paths ``xys`` (B, n, 2) sampled at the same times ``t`` (n,), interpolated exactly.

    The same as ``[build_reference(t, xy, yaw_label, times, dt, smooth=False) for xy in xys]``, with
    one cubic-spline solve for all paths (SciPy solves each column the same way; bit-identical).
    """
    t = np.asarray(t, float)
    xys = np.asarray(xys, float)
    if len(t) < 4:
        return [build_reference(t, xy, yaw_label, times, dt, smooth=False) for xy in xys]
    B, n = xys.shape[:2]
    start, end, tq = _span(t, times, dt)
    spline = make_interp_spline(t, xys.transpose(1, 0, 2).reshape(n, 2 * B), k=3)
    pos = spline(tq).reshape(len(tq), B, 2)
    vel = spline.derivative()(tq).reshape(len(tq), B, 2)
    yaw = np.asarray(yaw_label, float)
    return [_reference(pos[:, b], vel[:, b], xys[b], yaw, times, start, end) for b in range(B)]


def _span(t: np.ndarray, times: np.ndarray, dt: float) -> tuple[int, int, np.ndarray]:
    """First and last grid index of samples at ``t`` and the grid times between them (clipped to ``t``)."""
    T = len(times)
    start = min(max(grid_index(t[0], dt), 0), T - 1)
    end = min(max(grid_index(t[-1], dt), start), T - 1)
    return start, end, np.clip(times[start : end + 1], t[0], t[-1])


def _reference(
    pos: np.ndarray,
    vel: np.ndarray,
    xy: np.ndarray,
    yaw_label: np.ndarray,
    times: np.ndarray,
    start: int,
    end: int,
) -> Reference:
    """Reference from positions ``pos`` and velocities ``vel`` (m, m/s) at grid steps ``start..end``."""
    T = len(times)
    seg = np.hypot(*np.diff(pos, axis=0).T) if len(pos) > 1 else np.zeros(0)
    s_span = np.concatenate([[0.0], np.cumsum(seg)])
    static = bool(s_span[-1] < STATIC_PATH_M)
    if static:
        centre = xy.mean(axis=0)
        yaw0 = float(np.median(yaw_label))
        path = resample_path(centre[None, :], yaw0, 5.0)
        s_ref = np.zeros(T)
        v_ref = np.zeros(T)
        init = np.array([centre[0], centre[1], yaw0, 0.0])
        return Reference(path, s_ref, v_ref, start, end, init, True)
    speed = np.hypot(vel[:, 0], vel[:, 1])
    moving = speed > 0.5
    head = np.arctan2(vel[:, 1], vel[:, 0])
    end_heading = float(head[moving][-1]) if moving.any() else float(yaw_label[-1])
    v_end = float(speed[-1])
    extension = EXTENSION_M + v_end * max(0.0, times[-1] - times[end])
    path = resample_path(pos, end_heading, extension)
    # station and speed profiles on the full grid
    s_ref = np.empty(T)
    s_ref[: start + 1] = 0.0
    s_ref[start : end + 1] = s_span
    s_ref[end:] = s_span[-1] + v_end * (times[end:] - times[end])
    v_ref = np.empty(T)
    v_ref[:start] = speed[0]
    v_ref[start : end + 1] = speed
    v_ref[end:] = v_end
    heading0, _ = path_heading_curvature(path[:3])
    init = np.array([pos[0, 0], pos[0, 1], float(head[0]) if moving[0] else float(heading0[0]), speed[0]])
    return Reference(path, s_ref, v_ref, start, end, init, False)


@dataclass
class PathSet:
    """Q references stacked and padded for vectorised following (paths extended straight to equal length)."""

    path: np.ndarray  # (Q, P, 2)
    heading: np.ndarray  # (Q, P)
    curvature: np.ndarray  # (Q, P)
    s_ref: np.ndarray  # (Q, T)
    v_ref: np.ndarray  # (Q, T)
    a_ref: np.ndarray  # (Q, T)

    @classmethod
    def stack(cls, refs: list[Reference], dt: float) -> PathSet:
        P = max(len(r.path) for r in refs)
        paths, heads, curvs = [], [], []
        for r in refs:
            p = r.path
            if len(p) < P:
                d = p[-1] - p[-2]
                d = d / max(float(np.hypot(*d)), 1e-12) * PATH_DS_M
                p = np.vstack([p, p[-1] + np.arange(1, P - len(p) + 1)[:, None] * d])
            h, c = path_heading_curvature(p)
            paths.append(p)
            heads.append(h)
            curvs.append(c)
        v_ref = np.stack([r.v_ref for r in refs])
        a_ref = np.gradient(v_ref, dt, axis=1) if v_ref.shape[1] > 1 else np.zeros_like(v_ref)
        return cls(np.stack(paths), np.stack(heads), np.stack(curvs), np.stack([r.s_ref for r in refs]), v_ref, a_ref)

    def pose_at(self, k: int) -> np.ndarray:
        """(Q, 4) x, y, heading, speed of every reference at grid step ``k`` (position at ``s_ref``)."""
        P = self.path.shape[1]
        u = np.clip(self.s_ref[:, k] / PATH_DS_M, 0.0, P - 1.0)
        i = np.minimum(u.astype(np.intp), P - 2) if P > 1 else np.zeros(len(u), np.intp)
        f = (u - i)[:, None] if P > 1 else np.zeros((len(u), 1))
        q = np.arange(len(u))
        j = np.minimum(i + 1, P - 1)
        xy = self.path[q, i] * (1.0 - f) + self.path[q, j] * f
        return np.column_stack([xy, self.heading[q, i], self.v_ref[:, k]])
