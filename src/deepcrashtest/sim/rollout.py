"""The replayed ego's whole run for many variants at once: path following + bicycle model, in place.

The same arithmetic as one :meth:`~deepcrashtest.sim.follow.Follower.command`,
:func:`~deepcrashtest.sim.vehicle.limit_commands` and :func:`~deepcrashtest.sim.vehicle.bicycle_step`
per grid step (every operation on the same operands in the same order, so the states are bit for bit
the loop's), rearranged for speed: the states are separate contiguous arrays (x, y, yaw, speed,
steering: (T, B) each, metres, radians, m/s; world frame), every step writes into preallocated
buffers (no temporary arrays), the path tables the follower reads are packed per point (x, y, cos
and sin of the heading, the heading: looked up instead of computed per step), laid out point-major (the
variants, advancing alike, read neighbouring rows: half the gather's cost of one table per variant)
and gathered once per step instead of three times (the first index update reads the previous step's
row; the final row is fetched again only where the second update moved the index), and ``tan(steer)``
is computed once per step instead of twice.
What remains is bound by ~9 transcendental functions per variant and step.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from deepcrashtest.sim.follow import K_E, K_I, K_P, K_S, V_CORR, V_SOFT
from deepcrashtest.sim.reference import PATH_DS_M, PathSet
from deepcrashtest.sim.vehicle import VehicleLimits


@dataclass
class EgoRun:
    """Ego states on the whole grid, (T, B) each: x, y (m), yaw (rad), speed (m/s), road-wheel steer (rad), and
    the cosine and sine of the yaw (computed by the steps anyway; the contact geometry reuses them)."""

    x: np.ndarray
    y: np.ndarray
    yaw: np.ndarray
    v: np.ndarray
    steer: np.ndarray
    cos_yaw: np.ndarray
    sin_yaw: np.ndarray

    def state(self, i: np.ndarray, r: np.ndarray) -> np.ndarray:
        """(n, 4) x, y, yaw, speed at grid indices ``i`` of rows ``r``."""
        return np.column_stack([self.x[i, r], self.y[i, r], self.yaw[i, r], self.v[i, r]])


@dataclass
class PackedPaths:
    """A :class:`PathSet` as the roll-out reads it, for one wheelbase: the follower's path tables packed point-major
    (:func:`_path_table`, (P * Q, 5)) and the (Q, T) station, speed and acceleration profiles. Holding this instead
    of the path set lets the paths' own arrays (points and headings: ~28 MB per 1,000 variants) go before
    the roll-out allocates its states: a fresh worker's page faults follow its peak of memory."""

    table: np.ndarray
    shape: tuple[int, int]  # (Q, P): references, points per path
    wheelbase: float
    s_ref: np.ndarray
    v_ref: np.ndarray
    a_ref: np.ndarray

    @classmethod
    def pack(cls, paths: PathSet, wheelbase: float) -> PackedPaths:
        """The tables of ``paths`` for an ego of ``wheelbase`` (m)."""
        Q, P = paths.path.shape[:2]
        return cls(_path_table(paths), (Q, P), wheelbase, paths.s_ref, paths.v_ref, paths.a_ref)

    def release(self) -> None:
        """Drop the tables and profiles (no roll-out reads them any more: a batch's only chunk has rolled out), so
        that what is computed next reuses their memory instead of touching fresh pages."""
        self.table = np.empty((0, 5))
        self.s_ref = self.v_ref = self.a_ref = np.empty((0, 0))


def rollout(
    paths: PathSet | PackedPaths,
    q: np.ndarray,
    offset: np.ndarray,
    init: np.ndarray,
    wheelbase: float,
    dt: float,
    steps: int,
    limits: VehicleLimits,
) -> EgoRun:
    """Drive ``B`` egos (initial states ``init`` (B, 4), zero steering) along ``paths[q]`` (translated by
    ``offset`` (B, 2), m) for ``steps`` grid steps; the grid has ``steps + 1`` indices. ``paths``: a path set, or
    one already packed for this ``wheelbase``."""
    if isinstance(paths, PathSet):
        paths = PackedPaths.pack(paths, wheelbase)
    elif paths.wheelbase != wheelbase:
        raise ValueError(f"paths packed for a wheelbase of {paths.wheelbase} m, not {wheelbase} m")
    B = len(init)
    T = steps + 1
    run = EgoRun(*(np.empty((T, B)) for _ in range(7)))
    X, Y, YAW, V, STEER, COS, SIN = run.x, run.y, run.yaw, run.v, run.steer, run.cos_yaw, run.sin_yaw
    X[0], Y[0], YAW[0], V[0] = (np.asarray(init[:, c], float) for c in range(4))
    STEER[0] = 0.0
    q = np.asarray(q, np.intp)
    Q, P = paths.shape
    table = paths.table
    identity = len(q) == paths.s_ref.shape[0] and bool((q == np.arange(len(q))).all())
    profiles = (paths.s_ref, paths.v_ref, paths.a_ref)
    s_tab, v_tab, a_tab = (np.ascontiguousarray(a.T if identity else a[q].T) for a in profiles)
    last = P - 2
    half = 0.5 * wheelbase
    off = np.asarray(offset, float)
    shifted = bool(np.any(off != 0.0))
    ox, oy = np.ascontiguousarray(off[:, 0]), np.ascontiguousarray(off[:, 1])
    idx = np.zeros(B, np.intp)
    integral = np.zeros(B)
    # buffers
    f = np.empty(B, np.intp)
    di = np.empty(B, np.intp)
    moved = np.empty(B, np.intp)
    g = np.empty((B, 5))
    gx, gy, gc, gs, gh = (g[:, c] for c in range(5))
    np.take(table, q, axis=0, out=g)  # index 0 of every path
    fx, fy, t1, t2, t3 = (np.empty(B) for _ in range(5))
    steer_c, acc, tan_s, beta, tau = (np.empty(B) for _ in range(5))
    braking = np.empty(B, bool)
    nan = np.empty(B, bool)
    two_pi = 2 * np.pi
    rate = limits.max_steer_rate * dt
    for k in range(steps):
        x, y, yaw, v, steer = X[k], Y[k], YAW[k], V[k], STEER[k]
        # ---- Follower.command: front axle, projection onto the path
        np.cos(yaw, out=COS[k])
        np.multiply(COS[k], half, out=t1)
        np.add(x, t1, out=fx)
        np.sin(yaw, out=SIN[k])
        np.multiply(SIN[k], half, out=t1)
        np.add(y, t1, out=fy)
        if shifted:
            np.subtract(fx, ox, out=fx)
            np.subtract(fy, oy, out=fy)
        # two updates of the path index from the along-track offset; ``g`` holds the table row at the index
        _index_update(fx, fy, g, idx, last, di, t1, t2)  # first: at the previous step's index, already gathered
        np.multiply(idx, Q, out=f)
        np.add(f, q, out=f)
        np.take(table, f, axis=0, out=g)
        np.copyto(moved, idx)
        _index_update(fx, fy, g, idx, last, di, t1, t2)
        np.not_equal(idx, moved, out=nan)
        if nan.any():  # rare: the second update moved the index; fetch those rows again
            rows = np.flatnonzero(nan)
            g[rows] = table[idx[rows] * Q + q[rows]]
        np.subtract(fx, gx, out=t1)  # dx
        np.subtract(fy, gy, out=t2)  # dy
        # lateral = -dx * s + dy * c (``dy * c - dx * s`` bit for bit)
        np.multiply(t2, gc, out=t3)
        np.multiply(t1, gs, out=steer_c)
        np.subtract(t3, steer_c, out=t3)  # lateral
        # along = dx * c + dy * s
        np.multiply(t1, gc, out=t1)
        np.multiply(t2, gs, out=t2)
        np.add(t1, t2, out=t1)  # along
        # heading error and Stanley steering
        np.subtract(gh, yaw, out=t2)
        np.add(t2, np.pi, out=t2)
        _remainder_two_pi(t2, two_pi)
        np.subtract(t2, np.pi, out=t2)  # head_err
        np.multiply(t3, K_E, out=t3)
        np.add(v, V_SOFT, out=steer_c)
        np.divide(t3, steer_c, out=t3)
        np.arctan(t3, out=t3)
        np.subtract(t2, t3, out=steer_c)  # steering command
        # station and speed: s_centre = i * ds + along - half
        np.multiply(idx, PATH_DS_M, out=t2)
        np.add(t2, t1, out=t2)
        np.subtract(t2, half, out=t2)
        np.subtract(s_tab[k], t2, out=t2)
        if K_S != 1.0:
            np.multiply(t2, K_S, out=t2)
        np.maximum(t2, -V_CORR, out=t2)
        np.minimum(t2, V_CORR, out=t2)
        np.add(v_tab[k], t2, out=t2)  # v_cmd
        np.maximum(t2, 0.0, out=t2)
        np.subtract(t2, v, out=t2)  # err
        np.multiply(t2, dt, out=t1)
        np.add(integral, t1, out=integral)
        np.maximum(integral, -2.0, out=integral)
        np.minimum(integral, 2.0, out=integral)
        np.multiply(t2, K_P, out=t2)
        np.add(a_tab[k], t2, out=acc)
        np.multiply(integral, K_I, out=t1)
        np.add(acc, t1, out=acc)  # acceleration command
        # ---- limit_commands
        _clip_nan_zero(acc, -limits.max_brake, limits.max_accel, nan)
        _clip_nan_zero(steer_c, -limits.max_steer, limits.max_steer, nan)
        np.subtract(steer_c, steer, out=steer_c)
        np.maximum(steer_c, -rate, out=steer_c)
        np.minimum(steer_c, rate, out=steer_c)
        st = STEER[k + 1]
        np.add(steer, steer_c, out=st)
        # ---- bicycle_step
        np.less(acc, 0.0, out=braking)
        tau.fill(dt)
        if braking.any():
            np.negative(acc, out=t1)
            np.divide(v, t1, out=t1, where=braking)
            np.minimum(t1, dt, out=tau, where=braking)
        np.multiply(v, tau, out=t1)
        np.multiply(acc, 0.5, out=t2)
        np.multiply(t2, tau, out=t2)
        np.multiply(t2, tau, out=t2)
        np.add(t1, t2, out=t1)  # dist
        vn = V[k + 1]
        np.multiply(acc, tau, out=t2)
        np.add(v, t2, out=vn)
        np.maximum(vn, 0.0, out=vn)
        np.tan(st, out=tan_s)
        np.multiply(tan_s, 0.5, out=beta)
        np.arctan(beta, out=beta)
        np.divide(t1, dt, out=t2)  # v_mean
        np.cos(beta, out=t3)
        np.multiply(t2, t3, out=t2)
        np.multiply(t2, tan_s, out=t2)
        np.divide(t2, wheelbase, out=t2)
        np.multiply(t2, dt, out=t2)
        yn = YAW[k + 1]
        np.add(yaw, t2, out=yn)
        np.add(yaw, yn, out=t2)
        np.multiply(t2, 0.5, out=t2)
        np.add(t2, beta, out=t2)  # course
        np.cos(t2, out=t3)
        np.multiply(t1, t3, out=t3)
        np.add(x, t3, out=X[k + 1])
        np.sin(t2, out=t3)
        np.multiply(t1, t3, out=t3)
        np.add(y, t3, out=Y[k + 1])
    np.cos(YAW[steps], out=COS[steps])
    np.sin(YAW[steps], out=SIN[steps])
    return run


def _path_table(paths: PathSet, block: int = 64) -> np.ndarray:
    """The follower's path tables, (P * Q, 5) flat over (point, reference): row ``p * Q + q`` holds point ``p`` of
    reference ``q`` (the variants' rows at one step lie close together, as they advance alike), packed per point:
    x, y (m), cos and sin of the heading, the heading (rad). Built in blocks of points, each block's columns
    transposed through a small contiguous copy (cache-sized)."""
    Q, P = paths.path.shape[:2]
    table = np.empty((P, Q, 5))
    for p0 in range(0, P, block):
        sl = slice(p0, min(p0 + block, P))
        rows = table[sl]
        rows[..., 0] = paths.path[:, sl, 0].T
        rows[..., 1] = paths.path[:, sl, 1].T
        h = np.ascontiguousarray(paths.heading[:, sl].T)
        rows[..., 2], rows[..., 3], rows[..., 4] = np.cos(h), np.sin(h), h
    return table.reshape(P * Q, 5)


def _remainder_two_pi(a: np.ndarray, two_pi: float) -> None:
    """``np.remainder(a, two_pi, out=a)``, skipped when every element is in [0, two_pi) already (the usual case:
    small heading errors), where it changes nothing that matters: it returns each such ``a`` itself, except
    ``-0.0`` -> ``+0.0``, and the caller subtracts pi next (both give ``-pi``). Two reductions cost ~2 us per
    1,000 variants, the remainder ~40 us (numpy's floating-point divmod), one of the step's costliest calls."""
    if not (a.min() >= 0.0 and a.max() < two_pi):  # NaN fails both: the full remainder
        np.remainder(a, two_pi, out=a)


def _clip_nan_zero(a: np.ndarray, lo: float, hi: float, nan: np.ndarray) -> None:
    """``vehicle._clip_nan_zero`` in place: ``a`` clipped to [lo, hi], NaN -> 0 (``nan``: a bool buffer)."""
    np.maximum(a, lo, out=a)
    np.minimum(a, hi, out=a)
    np.isnan(a, out=nan)
    if nan.any():
        a[nan] = 0.0


def _index_update(
    fx: np.ndarray,
    fy: np.ndarray,
    g: np.ndarray,
    idx: np.ndarray,
    last: int,
    di: np.ndarray,
    t1: np.ndarray,
    t2: np.ndarray,
) -> None:
    """``idx = clip(idx + rint(along / ds), 0, last)`` in place, ``along`` the front axle's offset along the path
    at the gathered rows ``g`` (x, y, cos, sin of the heading, ...); ``di``, ``t1``, ``t2``: buffers."""
    np.subtract(fx, g[:, 0], out=t1)
    np.multiply(t1, g[:, 2], out=t1)
    np.subtract(fy, g[:, 1], out=t2)
    np.multiply(t2, g[:, 3], out=t2)
    np.add(t1, t2, out=t1)
    np.divide(t1, PATH_DS_M, out=t1)
    np.rint(t1, out=di, casting="unsafe")  # ``np.rint(t1).astype(np.intp)``: rounded in double, then cast
    np.add(idx, di, out=di)
    np.maximum(di, 0, out=di)
    np.minimum(di, last, out=idx)
