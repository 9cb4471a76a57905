"""Reference motions for path following: a smoothed, time-indexed path per vehicle.

A vehicle's trajectory (box centre samples, world frame) becomes

* a geometric path resampled every ``PATH_DS_M`` metres of arc length, with its heading,
  extended straight along its final heading (so a follower can always look ahead);
* a station profile ``s_ref(t)``, speed ``v_ref(t)`` and acceleration ``a_ref(t)`` on the simulation
  time grid (before the first sample: the initial values; after the last: constant speed).

Raw (label-derived) trajectories are noisy, so positions are smoothed with a cubic smoothing spline
(:func:`~deepcrashtest.sim.splines.smoothing_spline`, SciPy's ``make_smoothing_spline`` in NumPy) whose
cut-off is ``SMOOTH_CUTOFF_HZ``; speeds come from the
derivative of that spline, so path and speed profile are consistent. A vehicle that moves less
than ``STATIC_PATH_M`` in total is static: it holds its mean position and median label heading. Exact
(``smooth=False``, already smooth) waypoints are static only below ``STATIC_EXACT_PATH_M``: a processed ego
creeping 0.9 m into its crash was held still and missed it (ccd_000080).
"""

from __future__ import annotations

import functools
from dataclasses import dataclass

import numpy as np

from deepcrashtest.errors import ScenarioError
from deepcrashtest.scenario import Trajectory
from deepcrashtest.sim.splines import (
    BSpline,
    NaturalCubic,
    interp_inverse,
    interp_spline,
    not_a_knot,
    one_thread,
    smoothing_spline,
)

PATH_DS_M = 0.25
SMOOTH_CUTOFF_HZ = 0.8
STATIC_PATH_M = 1.5
STATIC_EXACT_PATH_M = 0.05
EXTENSION_M = 60.0
#: Longest path (m, with its straight continuation) a reference may have: 600 s (the longest run) at
#: ~300 km/h. Longer ones are no road user's motion and would be resampled into millions of points.
MAX_PATH_M = 50_000.0


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


def _median(v: np.ndarray) -> float:
    """``float(np.median(v))`` of a non-empty 1-D array of finite numbers, the same value: the middle element, or
    the mean of the two middle ones, ``(a + b) / 2`` as ``np.mean`` computes it. (``np.median`` imports
    ``numpy.ma`` for its NaN check: ~25 ms of CPU in the serial start of every search.)"""
    a = np.sort(np.asarray(v, float))
    m = len(a) // 2
    return float(a[m]) if len(a) % 2 else float((a[m - 1] + a[m]) / 2)


def _smooth_positions(t: np.ndarray, x: np.ndarray, y: np.ndarray, smooth: bool):
    """Return callables (pos(tq) -> (n, 2), vel(tq) -> (n, 2)) fitted to the samples."""
    n = len(t)
    sx: BSpline | NaturalCubic
    sy: BSpline | NaturalCubic
    if n >= 5 and smooth:
        h = _median(np.diff(t))
        lam = h / (2.0 * np.pi * SMOOTH_CUTOFF_HZ) ** 4
        sx, sy = smoothing_spline(t, x, lam), smoothing_spline(t, y, lam)
    elif n >= 4:
        sx, sy = interp_spline(t, x, 3), interp_spline(t, y, 3)
    else:
        k = 1 if n >= 2 else 0
        if k == 0:
            return (lambda tq: np.tile([x[0], y[0]], (len(np.atleast_1d(tq)), 1))), (
                lambda tq: np.zeros((len(np.atleast_1d(tq)), 2))
            )
        sx, sy = interp_spline(t, x, 1), interp_spline(t, y, 1)
    dx, dy = sx.derivative(), sy.derivative()
    return (lambda tq: np.column_stack([sx(tq), sy(tq)])), (lambda tq: np.column_stack([dx(tq), dy(tq)]))


def resample_path(points: np.ndarray, end_heading: float, extension: float, ds: float = PATH_DS_M) -> np.ndarray:
    """Resample a polyline every ``ds`` metres and extend it straight by ``extension`` metres."""
    seg = np.hypot(*np.diff(points, axis=0).T) if len(points) > 1 else np.zeros(0)
    s = np.concatenate([[0.0], np.cumsum(seg)])
    keep = np.r_[True, seg > 1e-9]
    s, pts = s[keep], points[keep]
    if not s[-1] + extension <= MAX_PATH_M:
        raise ScenarioError(
            f"a path of {(s[-1] + extension) / 1000:.0f} km (with its continuation): longer than any road "
            f"user drives in a scenario (at most {MAX_PATH_M / 1000:.0f} km)"
        )
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


def path_heading(path: np.ndarray) -> np.ndarray:
    """Heading (rad, unwrapped) along arc-length-uniform paths ``(..., P, 2)`` -> ``(..., P)``."""
    d = np.gradient(path, axis=-2)
    return _unwrap(np.arctan2(d[..., 1], d[..., 0]))


def _unwrap(p: np.ndarray) -> np.ndarray:
    """``np.unwrap(p, axis=-1)``, bit for bit, skipping its corrections where no step reaches pi (the usual case).

    Where no correction applies numpy adds a cumulative sum of zeros (+0.0) to ``p[..., 1:]``; so does this.
    """
    if p.shape[-1] < 2 or (np.abs(np.diff(p, axis=-1)) < np.pi).all():
        up = p.copy()
        up[..., 1:] += 0.0
        return up
    return np.unwrap(p, axis=-1)


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
    static_m = STATIC_PATH_M if smooth else STATIC_EXACT_PATH_M
    return _reference(pos_f(tq), vel_f(tq), xy, np.asarray(yaw_label, float), times, start, end, static_m)


def build_references(
    t: np.ndarray, xys: np.ndarray, yaw_label: np.ndarray, times: np.ndarray, dt: float
) -> list[Reference]:
    """References of ``B`` paths ``xys`` (B, n, 2) sampled at the same times ``t`` (n,), interpolated exactly.

    The same as ``[build_reference(t, xy, yaw_label, times, dt, smooth=False) for xy in xys]``, with
    one interpolation matrix for all paths (equal to the per-path splines to rounding).
    """
    t = np.asarray(t, float)
    xys = np.asarray(xys, float)
    if len(t) < 4:
        return [build_reference(t, xy, yaw_label, times, dt, smooth=False) for xy in xys]
    start, end, pos, vel = _interp_paths(t, xys, times, dt)
    yaw = np.asarray(yaw_label, float)
    return [_reference(pos[:, b], vel[:, b], xys[b], yaw, times, start, end) for b in range(len(xys))]


def _interp_paths(
    t: np.ndarray, xys: np.ndarray, times: np.ndarray, dt: float
) -> tuple[int, int, np.ndarray, np.ndarray]:
    """Grid span and cubic-interpolated positions and velocities (L, B, 2) of ``B`` paths sampled at ``t``.

    One spline for all paths (their coefficients from one cached inverse of the collocation matrix).
    """
    B, n = xys.shape[:2]
    start, end, tq = _span(t, times, dt)
    ys = xys.transpose(1, 0, 2).reshape(n, 2 * B)
    knots, inverse = _interp_inverse(t.tobytes())
    with one_thread():
        spline = BSpline(knots, inverse @ ys, 3)
        pos = spline(tq).reshape(len(tq), B, 2)
        vel = spline.derivative()(tq).reshape(len(tq), B, 2)
    return start, end, pos, vel


@functools.lru_cache(maxsize=4)
def _interp_inverse(t_b: bytes) -> tuple[np.ndarray, np.ndarray]:
    """Knots and inverse collocation matrix of the not-a-knot cubic spline through samples at ``t`` (kept: every
    batch of a search asks the same)."""
    t = np.frombuffer(t_b)
    return not_a_knot(t, 3), interp_inverse(t)


def build_pathset(
    t: np.ndarray, xys: np.ndarray, yaw_label: np.ndarray, times: np.ndarray, dt: float
) -> tuple[PathSet, np.ndarray]:
    """``PathSet`` and initial states (B, 4: x, y, yaw, speed) of ``B`` paths ``xys`` (B, n, 2) at times ``t``.

    Bit-identical to ``PathSet.stack(build_references(...))`` and the references' ``init``, vectorised
    over the paths (only the arc-length resampling runs per path): thousands of search variants cost
    milliseconds. Falls back to the per-path construction when a path is static or ``n < 4``.
    """
    t = np.asarray(t, float)
    xys = np.asarray(xys, float)
    if len(t) < 4:
        refs = build_references(t, xys, yaw_label, times, dt)
        return PathSet.stack(refs, dt), np.stack([r.init for r in refs])
    start, end, pos, vel = _interp_paths(t, xys, times, dt)
    seg = np.hypot(*np.diff(pos, axis=0).T)  # (B, L-1)
    s_span = np.concatenate([np.zeros((len(xys), 1)), np.cumsum(seg, axis=1)], axis=1)
    if (s_span[:, -1] < STATIC_PATH_M).any():
        refs = build_references(t, xys, yaw_label, times, dt)
        return PathSet.stack(refs, dt), np.stack([r.init for r in refs])
    speed = np.hypot(vel[..., 0], vel[..., 1]).T  # (B, L)
    moving = speed > 0.5
    last_moving = speed.shape[1] - 1 - np.argmax(moving[:, ::-1], axis=1)
    rows = np.arange(len(xys))
    # the direction of motion only where it is used: at the start and at each path's last moving sample
    v_end_moving = vel[last_moving, rows]
    head_end = np.arctan2(v_end_moving[:, 1], v_end_moving[:, 0])
    end_heading = np.where(moving.any(axis=1), head_end, float(np.asarray(yaw_label, float)[-1]))
    v_end = speed[:, -1]
    extension = EXTENSION_M + v_end * max(0.0, times[-1] - times[end])
    paths, lengths = _resample_paths(pos, seg, s_span, end_heading, extension)
    T = len(times)
    # (Q, T) views of time-major (T, Q) arrays: the roll-out reads them a step at a time (no transposed copies)
    s_ref = np.empty((T, len(xys))).T
    s_ref[:, : start + 1] = 0.0
    s_ref[:, start : end + 1] = s_span
    s_ref[:, end:] = s_span[:, -1:] + v_end[:, None] * (times[end:] - times[end])
    v_ref = np.empty((T, len(xys))).T
    v_ref[:, :start] = speed[:, :1]
    v_ref[:, start : end + 1] = speed
    v_ref[:, end:] = v_end[:, None]
    heading0 = float(np.asarray(yaw_label, float)[0])  # at rest: the trajectory's own heading (as _reference)
    head0 = np.arctan2(vel[0, :, 1], vel[0, :, 0])
    init = np.column_stack([pos[0, :, 0], pos[0, :, 1], np.where(moving[:, 0], head0, heading0), speed[:, 0]])
    # the interpolated samples (~50 MB per 1,000 variants) are not needed for the headings and curvatures: freed
    # first, their memory holds those (a fresh worker's page faults follow its peak of memory)
    del pos, vel, seg, s_span, speed, moving
    return PathSet.from_padded(paths, lengths, s_ref, v_ref, dt), init


def _resample_paths(
    pos: np.ndarray, seg: np.ndarray, s_span: np.ndarray, end_heading: np.ndarray, extension: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """``resample_path`` of ``B`` polylines ``pos`` (L, B, 2) at once: (B, P, 2) paths, each extended straight
    to the longest, and each one's own length (before that extension).

    ``seg`` (B, L-1) and ``s_span`` (B, L) are the polylines' segment lengths and stations (m).
    """
    B = pos.shape[1]
    keep = np.concatenate([np.ones((B, 1), bool), seg > 1e-9], axis=1)
    last_kept = keep.shape[1] - 1 - np.argmax(keep[:, ::-1], axis=1)
    s_last = s_span[np.arange(B), last_kept]
    n_base = np.ceil((s_last + 1e-9) / PATH_DS_M).astype(np.intp)  # len(np.arange(0, s_last + 1e-9, ds))
    n_ext = np.ceil(extension / PATH_DS_M).astype(np.intp) + 2
    lengths = n_base + n_ext
    out = np.empty((B, int(lengths.max()), 2))
    grid = np.arange(0.0, float(s_last.max()) + 1e-9, PATH_DS_M)
    xy = np.ascontiguousarray(pos.transpose(1, 2, 0))  # (B, 2, L)
    all_kept = np.all(keep, axis=1).tolist()
    for b in range(B):  # np.interp per polyline: their stations differ
        n, s, px, py = n_base[b], s_span[b], xy[b, 0], xy[b, 1]
        if not all_kept[b]:
            k = keep[b]
            s, px, py = s[k], px[k], py[k]
        if len(s) > 1:
            out[b, :n, 0] = np.interp(grid[:n], s, px)
            out[b, :n, 1] = np.interp(grid[:n], s, py)
        else:
            out[b, :n] = (px[0], py[0])
    last = out[np.arange(B), n_base - 1]
    direction = np.column_stack([np.cos(end_heading), np.sin(end_heading)])
    _continue_straight(out, n_base - 1, n_ext, last, direction)
    return out, lengths


def _continue_straight(
    paths: np.ndarray, end: np.ndarray, count: np.ndarray, origin: np.ndarray, step: np.ndarray
) -> None:
    """Write ``paths[b, end[b] + m] = origin[b] + (m * PATH_DS_M) * step[b]`` for m = 1..count[b], in place.

    ``paths`` (B, P, 2); only the written tail is computed (not the whole (B, P) padding).
    """
    n = int(count.max()) if len(count) else 0
    if n <= 0:
        return
    steps = (np.arange(1, n + 1) * PATH_DS_M)[:, None]  # (n, 1) metres along each tail
    # one slice per path (each tail's points are consecutive): no (total points,) index and value temporaries
    for b, (e, c) in enumerate(zip(end.tolist(), count.tolist(), strict=True)):
        paths[b, e + 1 : e + 1 + c] = origin[b] + steps[:c] * step[b]


def _continue_straight_units(
    paths: np.ndarray, end: np.ndarray, count: np.ndarray, origin: np.ndarray, step: np.ndarray
) -> None:
    """Write ``paths[b, end[b] + m] = origin[b] + m * step[b]`` for m = 1..count[b], in place (``step`` in metres
    per point)."""
    n = int(count.max()) if len(count) else 0
    if n <= 0:
        return
    m = np.arange(1, n + 1)
    rows, k = np.nonzero(m[None, :] <= count[:, None])
    paths[rows, end[rows] + m[k]] = origin[rows] + m[k][:, None] * step[rows]


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
    static_m: float = STATIC_PATH_M,
) -> Reference:
    """Reference from positions ``pos`` and velocities ``vel`` (m, m/s) at grid steps ``start..end``; static
    (held at its mean position) when its path is shorter than ``static_m``."""
    T = len(times)
    seg = np.hypot(*np.diff(pos, axis=0).T) if len(pos) > 1 else np.zeros(0)
    s_span = np.concatenate([[0.0], np.cumsum(seg)])
    static = bool(s_span[-1] < static_m)
    if static:
        centre = xy.mean(axis=0)
        yaw0 = _median(yaw_label)
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
    # at rest: the trajectory's own heading (a processed ego's is the camera's measured yaw; the first
    # direction of a path that starts at rest is noise: ccd_000882's replay started 2 deg off, 031's 16 deg)
    init = np.array([pos[0, 0], pos[0, 1], float(head[0]) if moving[0] else float(yaw_label[0]), speed[0]])
    return Reference(path, s_ref, v_ref, start, end, init, False)


@dataclass
class PathSet:
    """Q references stacked and padded for vectorised following (paths extended straight to equal length)."""

    path: np.ndarray  # (Q, P, 2)
    heading: np.ndarray  # (Q, P)
    s_ref: np.ndarray  # (Q, T); build_pathset's: views of time-major (T, Q) arrays, as the roll-out reads them
    v_ref: np.ndarray  # (Q, T)
    a_ref: np.ndarray  # (Q, T)
    yaw_ref: np.ndarray | None = None
    """(Q, T) heading (rad) a reference's pose takes at each grid step instead of its path's (NaN: the path's):
    an agent replayed exactly faces where the scenario says (its heading fitted to its boxes), not along its
    path (see :func:`~deepcrashtest.sim.world.build_world`)."""

    @classmethod
    def stack(cls, refs: list[Reference], dt: float, yaw_ref: np.ndarray | None = None) -> PathSet:
        """The references ``refs`` stacked; ``yaw_ref`` (Q, T): their own headings (see the field), or None."""
        out = cls.from_arrays(
            [r.path for r in refs], np.stack([r.s_ref for r in refs]), np.stack([r.v_ref for r in refs]), dt
        )
        out.yaw_ref = yaw_ref
        return out

    @classmethod
    def from_arrays(cls, paths: list[np.ndarray], s_ref: np.ndarray, v_ref: np.ndarray, dt: float) -> PathSet:
        """Stack paths (each (P_q, 2)), extending the shorter ones straight, with their (Q, T) profiles."""
        lengths = np.array([len(p) for p in paths])
        out = np.empty((len(paths), int(lengths.max()), 2))
        for q, p in enumerate(paths):
            out[q, : len(p)] = p
        return cls.from_padded(out, lengths, s_ref, v_ref, dt)

    @classmethod
    def from_padded(
        cls, paths: np.ndarray, lengths: np.ndarray, s_ref: np.ndarray, v_ref: np.ndarray, dt: float
    ) -> PathSet:
        """From paths (Q, P, 2) of which only the first ``lengths[q]`` points are set: the rest continue
        each path straight along its last segment, ``PATH_DS_M`` apart."""
        Q, P = paths.shape[:2]
        lengths = np.asarray(lengths, np.intp)
        short = lengths < P
        if short.any():
            q = np.arange(Q)
            p1, p2 = paths[q, lengths - 1], paths[q, np.maximum(lengths - 2, 0)]
            d = p1 - p2
            d = d / np.maximum(np.hypot(d[:, 0], d[:, 1]), 1e-12)[:, None] * PATH_DS_M
            _continue_straight_units(paths, lengths - 1, P - lengths, p1, d)
        a_ref = np.gradient(v_ref, dt, axis=1) if v_ref.shape[1] > 1 else np.zeros_like(v_ref)
        return cls(paths, path_heading(paths), s_ref, v_ref, a_ref)

    def pose_at(self, k: int) -> np.ndarray:
        """(Q, 4) x, y, heading, speed of every reference at grid step ``k`` (position at ``s_ref``)."""
        return self.poses(np.array([k]))[0]

    def poses(self, ks: np.ndarray) -> np.ndarray:
        """(K, Q, 4) :meth:`pose_at` at each grid step of ``ks`` (K,), element for element the same arithmetic."""
        P = self.path.shape[1]
        u = np.clip(self.s_ref[:, ks].T / PATH_DS_M, 0.0, P - 1.0)  # (K, Q)
        i = np.minimum(u.astype(np.intp), P - 2) if P > 1 else np.zeros(u.shape, np.intp)
        f = (u - i)[..., None] if P > 1 else np.zeros(u.shape + (1,))
        q = np.arange(u.shape[1])[None, :]
        j = np.minimum(i + 1, P - 1)
        xy = self.path[q, i] * (1.0 - f) + self.path[q, j] * f
        head = self.heading[q, i]
        if self.yaw_ref is not None:
            own = self.yaw_ref[:, ks].T
            head = np.where(np.isnan(own), head, own)
        return np.concatenate([xy, head[..., None], self.v_ref[:, ks].T[..., None]], axis=-1)
