"""Crash-consistent corrections: make two road users touch at the crash time, keep everyone else apart.

World frame (metres, x forward, y left), scenario time (seconds). A correction is a smooth
displacement ``delta(t)`` (metres) added to a vehicle's dense path: a cubic B-spline in time whose
coefficients are found by least squares (size + ``smooth_s4`` x acceleration, both squared) under
constraints solved with SciPy's SLSQP:

* the pair's signed box separation (:func:`separation`) is ``-penetration_m`` at the crash time and
  >= 0 up to ``touch_tol_s`` before it (so their first contact lies within that tolerance);
* the correction's own acceleration stays under ``accel_limit_mps2`` on each axis (the braking /
  steering a driver can add);
* the corrected path stays within the road user's kinematics (``scenario.Kinematics``, the limits of
  the simulator's vehicle model): curvature within the steering angle, steering rate, traction and
  braking (a pedestrian: its acceleration), with a ``kin_margin`` of headroom for the replay's path
  follower, so that a replay follows it (no further outside them than the uncorrected path);
* a participant's correction starts at zero value, speed and acceleration ``window_s`` before the
  crash (only its last seconds move); a bystander's may shift its whole track (``nudge_apart``).

SLSQP is given the analytic derivative of every function (the cost is quadratic in the coefficients,
the acceleration bound linear; the separation's is that of its active separating axis through the
boxes' interpolated positions and headings; the kinematic rows' through the corrected velocity and
acceleration), so an iteration costs one evaluation of the corrected paths, not one per coefficient.
"""

from __future__ import annotations

import functools
import math
from collections.abc import Callable
from dataclasses import dataclass, replace
from typing import Any

import numpy as np
from scipy import sparse
from scipy.interpolate import BSpline, make_interp_spline
from scipy.optimize import minimize

from deepcrashtest.scenario import VEHICLE_KINEMATICS, Kinematics
from deepcrashtest.trajectory.collision import BoxTrack, heading_sources, headings, within_reach


def separation(a: BoxTrack, b: BoxTrack, t: np.ndarray) -> np.ndarray:
    """Signed separation (m) of the two oriented boxes at times ``t`` (s), separating-axis test.

    > 0: apart (the largest gap along the four box axes, a lower bound of the distance);
    < 0: overlapping (minus the penetration depth). Each track is linearly interpolated.
    """
    return _separation(a, b, t)[0]


def separation_on_joining(a: BoxTrack, b: BoxTrack, tol_s: float = 0.0) -> tuple[float, float] | None:
    """(the first moment both boxes exist, s; their :func:`separation` then, m), or None where they never coexist (the
    later one starts more than ``tol_s`` after the other ends)."""
    t0 = max(float(a.t[0]), float(b.t[0]))
    if t0 > min(float(a.t[-1]), float(b.t[-1])) + tol_s:
        return None
    return t0, float(separation(a, b, np.array([t0]))[0])


def overlap_samples(a: BoxTrack, b: BoxTrack, t_end: float = math.inf, step_s: float = 0.05) -> np.ndarray:
    """Whether the two boxes overlap (:func:`separation` < 0), every ``step_s`` (s) of the time both exist, up to
    ``t_end`` (s); empty where they never coexist before it."""
    t = np.arange(max(a.t[0], b.t[0]), min(a.t[-1], b.t[-1], t_end), step_s)
    return separation(a, b, t) < 0.0 if len(t) else np.zeros(0, bool)


def _separation(a: BoxTrack, b: BoxTrack, t: np.ndarray, partials: bool = False) -> tuple[np.ndarray, np.ndarray]:
    """:func:`separation` and, ``partials``, its derivatives (len(t), 6) with respect to the two boxes'
    interpolated states (xa, ya, ha, xb, yb, hb) (m, rad): those of the axis whose gap is the largest
    (the separation is piecewise smooth; elsewhere the derivative of the active piece)."""
    t = np.atleast_1d(np.asarray(t, float))
    return _separation_of_states(a, b, a.at(t), b.at(t), partials)


States = tuple[np.ndarray, np.ndarray, np.ndarray]
"""A box track's centre x, y (m) and heading (rad) at some times (:meth:`BoxTrack.at`)."""


def _separation_of_states(
    a: BoxTrack, b: BoxTrack, sa: States, sb: States, partials: bool = False
) -> tuple[np.ndarray, np.ndarray]:
    """:func:`_separation` from the two tracks' states at the times (``sa``, ``sb``: :meth:`BoxTrack.at`)."""
    (xa, ya, ha), (xb, yb, hb) = sa, sb
    if not partials:  # SLSQP's constraint values, ~10,000 calls a crash: the same arithmetic without the stacked arrays
        return _separation_value(a, b, xb - xa, yb - ya, ha, hb), np.zeros((len(xa), 0))
    return _separation_partials(a, b, xb - xa, yb - ya, ha, hb)


def _gap_along(
    n: tuple[np.ndarray, np.ndarray],
    d: tuple[np.ndarray, np.ndarray],
    heads: tuple[np.ndarray, ...],
    a: BoxTrack,
    b: BoxTrack,
) -> np.ndarray:
    """The two boxes' gap (m) along the axis ``n`` (unit 2-vector per time): the centres' offset ``d`` projected on it
    less each box's half extent there (``heads``: cos and sin of each box's heading, a's then b's). Each dot product
    of two 2-vectors is written out (``p0 q0 + p1 q1``, NumPy's own order for a sum of two), so the numbers are those
    of the stacked-array form to the last bit (SLSQP follows the last bit)."""
    (n0, n1), (dx, dy), (ca, sa, cb, sb) = n, d, heads
    ra = 0.5 * a.length * np.abs(ca * n0 + sa * n1) + 0.5 * a.width * np.abs(-sa * n0 + ca * n1)
    rb = 0.5 * b.length * np.abs(cb * n0 + sb * n1) + 0.5 * b.width * np.abs(-sb * n0 + cb * n1)
    return np.abs(dx * n0 + dy * n1) - ra - rb


def _separation_value(
    a: BoxTrack, b: BoxTrack, dx: np.ndarray, dy: np.ndarray, ha: np.ndarray, hb: np.ndarray
) -> np.ndarray:
    """:func:`_separation`'s value from the centres' offset (``dx``, ``dy``, m) and the headings (rad): the largest
    gap along the four box axes, :func:`_gap_along` on the four axes at once (rows ua, va, ub, vb: each box's length
    and width axes; elementwise the same operations, so the same numbers to the last bit)."""
    heads = (np.cos(ha), np.sin(ha), np.cos(hb), np.sin(hb))
    ca, sa, cb, sb = heads
    axes = (np.stack([ca, -sa, cb, -sb]), np.stack([sa, ca, sb, cb]))
    return np.max(_gap_along(axes, (dx, dy), heads, a, b), axis=0)


def _separation_partials(
    a: BoxTrack, b: BoxTrack, dx: np.ndarray, dy: np.ndarray, ha: np.ndarray, hb: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """:func:`_separation` with ``partials``: the value and, per time, the derivatives (6,) of the axis whose gap is
    the largest. An axis n = (cos th, sin th) turns with its owner's heading th: dn/dth = perp(n); likewise each box
    edge e. The gaps are :func:`_gap_along`'s; each other dot product is written out alike and every term added in the
    order of the stacked-array form it replaced (SLSQP follows the last bit of a Jacobian)."""
    heads = (np.cos(ha), np.sin(ha), np.cos(hb), np.sin(hb))
    ca, sa, cb, sb = heads
    ua, va, ub, vb = (ca, sa), (-sa, ca), (cb, sb), (-sb, cb)
    perp = {id(ua): va, id(va): (-ca, -sa), id(ub): vb, id(vb): (-cb, -sb)}
    hla, hwa, hlb, hwb = 0.5 * a.length, 0.5 * a.width, 0.5 * b.length, 0.5 * b.width
    boxes = ((2, ((ua, hla), (va, hwa))), (5, ((ub, hlb), (vb, hwb))))
    gaps, parts = [], np.empty((4, len(dx), 6))
    for k, (n, own) in enumerate(((ua, 2), (va, 2), (ub, 5), (vb, 5))):
        n0, n1 = n
        gaps.append(_gap_along(n, (dx, dy), heads, a, b))
        p0, p1 = perp[id(n)]
        sgn = np.sign(dx * n0 + dy * n1)
        col: list[Any] = [-sgn * n0, -sgn * n1, 0.0, sgn * n0, sgn * n1, 0.0]
        col[own] = col[own] + sgn * (dx * p0 + dy * p1)
        for c, edges in boxes:
            for e, half in edges:
                e0, e1 = e
                q0, q1 = perp[id(e)]
                se = half * np.sign(e0 * n0 + e1 * n1)
                col[c] = col[c] - se * (q0 * n0 + q1 * n1)
                col[own] = col[own] - se * (e0 * p0 + e1 * p1)
        for j, v in enumerate(col):
            parts[k, :, j] = v
    stacked = np.stack(gaps)
    return np.max(stacked, axis=0), parts[np.argmax(stacked, axis=0), np.arange(len(dx))]


@dataclass(frozen=True)
class ContactParams:
    """Knobs of the crash-consistent correction (seconds, metres, m/s^2)."""

    windows_s: tuple[float, ...] = (2.0, 3.0, 4.5)
    """Tried in turn: how long before the crash a participant's correction may start."""
    knot_step_s: float = 0.5
    """Spacing of the correction spline's knots."""
    smooth_s4: float = 0.1
    """Weight of the correction's squared acceleration against its squared size (s^4)."""
    sight_across: float = 10.0
    """Cost of moving a road user the camera placed across its line of sight, per m^2, against 1 along it
    (:func:`sight_metric`): a crash correction lengthens or shortens the monocular depth rather than
    sliding the road user sideways off its box in the image."""
    accel_limit_mps2: float = 4.0
    """Largest acceleration the correction may add on each axis (driver braking/steering)."""
    penetration_s: float = 0.1
    """How far the boxes overlap at the crash time, in seconds of their closing speed (so a replay,
    which tracks the path with a small lag, still touches), clipped to ``penetration_m``."""
    penetration_m: tuple[float, float] = (0.15, 0.4)
    touch_tol_s: float = 0.1
    """The pair must be apart until this long before the crash time."""
    clearance_m: float = 0.5
    """Bystanders are kept at least this far from everyone before the crash (a replay tracks each
    path within a few decimetres)."""
    near_miss_m: float = 0.15
    """Bystanders closer than this (m) before the crash count as touching (and are moved apart to
    ``clearance_m``): the replay tracks each path within decimetres, and contacts are checked at the
    paths' samples (a graze between two frames is missed). Chosen on the crash clips mirrored and scaled to
    854x480 (``bench/fidelity_perturbed.py``): 0.25 nudged a bystander of ccd_000755 and lowered its replay IoU."""
    large_m: float = 2.0
    """A correction larger than this is reported as a warning."""
    kin_margin: float = 0.85
    """Share of the steering angle/rate and acceleration limits a corrected path may use (the rest is
    the replay's path follower's headroom)."""
    v_soft_mps: float = 0.5
    """Speed (m/s) below which curvature is not asked for: a vehicle crawling this slowly turns by
    ``kappa_max * v_soft^3 / (v^2 + v_soft^2)^(3/2)`` at most, the lateral noise of a near-still track."""


@dataclass
class Movable:
    """A vehicle's dense path that a correction may move: t (s), xy (N, 2) m, box size, heading fallback."""

    t: np.ndarray
    xy: np.ndarray
    length: float
    width: float
    heading: float
    weight: float = 1.0
    """Cost of moving this vehicle (larger = trusted more, e.g. the ego)."""
    rigid: bool = False
    """Only a constant shift of the whole track (a parked car's depth error), never a motion."""
    kin: Kinematics | None = VEHICLE_KINEMATICS
    """Limits a corrected path must keep (None: none, e.g. a parked car that only shifts)."""
    lateral_weight: float = 1.0
    """Cost factor of the part of the correction across the vehicle's heading (the ego: its heading is the
    camera's measured yaw, its speed scale the weak part of monocular ego-motion, so it is moved along its
    path before sideways)."""
    yaw: np.ndarray | None = None
    """Box headings (rad) per sample that a correction does not turn (a crawling ego: the camera's
    measured yaw, its path's direction being noise); None: the heading of the (corrected) motion."""
    metric: np.ndarray | None = None
    """(N, 2, 2) per-sample cost of a displacement ``d`` (m): ``d @ metric[k] @ d`` (symmetric, the
    identity = isotropic; None: isotropic). A road user localised by one camera is placed far better
    across the camera's line of sight than along it (:func:`sight_metric`)."""


def sight_metric(xy: np.ndarray, camera_xy: np.ndarray, across: float, min_range_m: float = 1.0) -> np.ndarray:
    """(N, 2, 2) :attr:`Movable.metric` of a road user at ``xy`` (N, 2) seen from ``camera_xy`` (N, 2),
    metres: a displacement along the line of sight costs 1 per m^2 (the monocular depth error), one
    across it ``across`` (its bearing is measured to a few pixels). Within ``min_range_m``: isotropic."""
    d = np.asarray(xy, float) - np.asarray(camera_xy, float)
    r = np.hypot(d[:, 0], d[:, 1])
    n = d / np.maximum(r, 1e-9)[:, None]
    along = n[:, :, None] * n[:, None, :]
    out = along + across * (np.eye(2) - along)
    out[r < min_range_m] = np.eye(2)
    return out


@dataclass(frozen=True)
class Correction:
    """The result: one displacement (N, 2) per movable vehicle, its largest size (m) and the window (s)."""

    deltas: list[np.ndarray]
    max_m: float
    rms_m: float
    window_s: float
    ok: bool
    message: str = ""
    kinematic: bool = True
    """Whether the corrected paths keep the movers' kinematics (else only the per-axis bound)."""


def box_track(m: Movable, xy: np.ndarray | None = None) -> BoxTrack:
    """The movable's box track (heading of the motion, ``heading`` where it is still)."""
    p = m.xy if xy is None else xy
    yaw = headings(m.t, p, m.heading) if m.yaw is None else m.yaw
    return BoxTrack(m.t, p[:, 0], p[:, 1], yaw, m.length, m.width)


@dataclass(frozen=True)
class _Basis:
    """A displacement basis on [lo, hi]: cubic B-splines (``anchored``: value, slope and curvature zero
    at ``lo``, constant continuation after ``hi``) or, ``rigid``, one constant shift."""

    lo: float
    hi: float
    knots: np.ndarray
    first: int
    rigid: bool = False

    @property
    def size(self) -> int:
        return 1 if self.rigid else len(self.knots) - 4 - self.first

    def at(self, t: np.ndarray, der: int = 0) -> np.ndarray:
        """(len(t), size): the basis (or its ``der``-th time derivative) at times ``t`` (s)."""
        if self.rigid:
            return np.ones((len(t), 1)) if der == 0 else np.zeros((len(t), 1))
        inside = (t >= self.lo) & (t <= self.hi)
        tt = np.clip(t, self.lo, self.hi)
        out = np.zeros((len(t), self.size))
        for j in range(self.size):
            c = np.zeros(len(self.knots) - 4)
            c[self.first + j] = 1.0
            spl = BSpline(self.knots, c, 3)
            out[:, j] = spl(tt) if der == 0 else spl.derivative(der)(tt) * inside
        return out


def _basis(lo: float, hi: float, step: float, anchored: bool) -> _Basis:
    """Cubic B-splines with knots every ~``step`` s on [lo, hi]; ``anchored``: the first three dropped."""
    n_in = max(0, int(round((hi - lo) / step)) - 1)
    inner = np.linspace(lo, hi, n_in + 2)[1:-1]
    knots = np.concatenate([[lo] * 4, inner, [hi] * 4])
    return _Basis(lo, hi, knots, 3 if anchored else 0)


def _rigid(m: Movable) -> _Basis:
    return _Basis(float(m.t[0]), float(m.t[-1]), np.zeros(0), 0, rigid=True)


KIN_STEP_S = 0.05  # grid on which the kinematic limits are checked (s)
KIN_TOL = 0.02  # share of a limit a solution may exceed it by (SLSQP stops just short)
MAX_ITER = 80  # SLSQP iterations per round: a correction that needs more is not found (stage 2 stays seconds)
LONG_MAX_ITER = 500
"""make_contact's last try, where every window stopped unsatisfied: each window again, without the steering limits,
with this many iterations per round. ccd_000330 at 30 fps (its frames repeated x3) stopped at the 80-iteration limit
with 5.5 cm of planned overlap and its replay missed; with 500 the 3.1 s window is satisfied (round iter23). Not the
first try's limit: more iterations there find larger optima in earlier windows (KITTI 0002's pair 4-6 moved 6.1 m
where it moves < 3.5)."""
# Box-track evaluations (~1 ms each) one make_contact / nudge_apart call may spend over all its windows and
# rounds: bounds stage 2's time on pathological tracks (a wrong pair once ran > 10 min). Measured on the 19
# labelled crash clips (2026-12-01): at most 64,186 box tracks built for a correction that was found, so none is cut;
# with analytic derivatives (one build per iterate) at most 1,177 (bench/contact_speed.py): MAX_ITER bounds the time.
MAX_EVALS = 100_000
APART_STEP_S = 0.05  # make_contact(apart_margin_m > 0): the grid (s) on which the pair is kept apart,
APART_MARGIN_S = 0.3  # ... by the margin until this long before the crash (s)
APART_FLOOR_M = 0.02
"""... and at least this far (m) until then where they were nearer: SLSQP ends on its active constraints, and a pair
kept apart by exactly 0 m touches (a car turning across the ego at 5 fps, ``tests/test_trajectory_crash.py``: on an
AMD EPYC host the corrected corner met the ego at 0.000 m 0.5 s before the crash, the replay's contact; an Intel host's
solution stopped a hair short of it)."""
TOUCH_SLACK_S = 0.02  # make_contact(overlap_s > 0): apart until this long before the first touch (s)


class _OutOfBudget(Exception):
    """Raised inside the optimiser when a call's :data:`MAX_EVALS` are spent."""


class _Budget:
    """Deterministic evaluation budget (a count, not a clock: the same input gives the same output)."""

    def __init__(self, evals: int | None = None) -> None:
        self.left = MAX_EVALS if evals is None else evals

    def spend(self) -> None:
        self.left -= 1
        if self.left < 0:
            raise _OutOfBudget

    @property
    def spent(self) -> bool:
        return self.left < 0


class _Kin:
    """The kinematic rows of one mover: normalised so that each must be >= 0 (0 = at the limit).

    On a uniform grid over the part of the track its correction can change; the corrected path's
    derivatives are the original's (cubic interpolation of the samples) plus the basis's.
    """

    def __init__(self, m: Movable, basis: _Basis, cp: ContactParams) -> None:
        assert m.kin is not None
        self.kin, self.cp = m.kin, cp
        lo, hi = max(basis.lo, float(m.t[0])), min(basis.hi, float(m.t[-1]))
        n = max(2, int(np.ceil((hi - lo) / KIN_STEP_S)) + 1)
        self.t = np.linspace(lo, hi, n)
        keep = np.r_[np.diff(m.t) > 0.02, True]  # drop near-duplicate samples (a cut adds one)
        t, xy = m.t[keep], m.xy[keep]
        k = min(3, len(t) - 1)
        spl = make_interp_spline(t, xy, k=k) if k >= 1 else None
        self.v0 = spl.derivative(1)(self.t) if spl is not None else np.zeros((n, 2))
        self.a0 = spl.derivative(2)(self.t) if spl is not None and k >= 2 else np.zeros((n, 2))
        self.b1, self.b2 = basis.at(self.t, 1), basis.at(self.t, 2)
        self.wb = self.kin.wheelbase_fraction * m.length

    def rows(self, c: np.ndarray) -> np.ndarray:
        """Normalised constraint values (>= 0 within the limits) for coefficients ``c`` (2, K)."""
        v = self.v0 + (self.b1 @ c.T)
        a = self.a0 + (self.b2 @ c.T)
        kin, g = self.kin, self.cp.kin_margin
        if kin.holonomic:
            return np.atleast_1d(1.0 - np.sum(a * a, 1) / (g * kin.max_accel_mps2) ** 2)
        soft2 = np.sum(v * v, 1) + self.cp.v_soft_mps**2
        kappa = (v[:, 0] * a[:, 1] - v[:, 1] * a[:, 0]) / soft2**1.5
        k_max = np.tan(g * kin.max_steer_rad) / self.wb
        steer = np.arctan(self.wb * kappa)
        rate = np.diff(steer) / np.diff(self.t) / (g * kin.max_steer_rate_rps)
        along = np.sum(v * a, 1) / np.sqrt(soft2)
        return np.concatenate(
            [
                1.0 - kappa / k_max,
                1.0 + kappa / k_max,
                1.0 - rate,
                1.0 + rate,
                1.0 - along / (g * kin.max_accel_mps2),
                1.0 + along / kin.max_brake_mps2,
            ]
        )

    def jac(self, c: np.ndarray) -> np.ndarray:
        """Derivatives (rows, 2K) of :meth:`rows` with respect to ``c`` (x coefficients first)."""
        v = self.v0 + (self.b1 @ c.T)
        a = self.a0 + (self.b2 @ c.T)
        b1, b2 = self.b1, self.b2
        kin, g = self.kin, self.cp.kin_margin

        def d(cx: np.ndarray, cy: np.ndarray) -> np.ndarray:
            """(n, 2K) from per-sample coefficients of the x and y bases' rows."""
            return np.hstack([cx, cy])

        if kin.holonomic:
            s = -2.0 / (g * kin.max_accel_mps2) ** 2
            return d(s * a[:, :1] * b2, s * a[:, 1:] * b2)
        vx, vy, ax, ay = v[:, :1], v[:, 1:], a[:, :1], a[:, 1:]
        soft2 = vx * vx + vy * vy + self.cp.v_soft_mps**2
        cross = vx * ay - vy * ax
        d_soft2 = d(2 * vx * b1, 2 * vy * b1)
        d_kappa = d(ay * b1 - vy * b2, -ax * b1 + vx * b2) / soft2**1.5 - 1.5 * cross / soft2**2.5 * d_soft2
        kappa = cross / soft2**1.5
        k_max = np.tan(g * kin.max_steer_rad) / self.wb
        d_steer = self.wb / (1.0 + (self.wb * kappa) ** 2) * d_kappa
        d_rate = np.diff(d_steer, axis=0) / np.diff(self.t)[:, None] / (g * kin.max_steer_rate_rps)
        dot = vx * ax + vy * ay
        d_along = d(ax * b1 + vx * b2, ay * b1 + vy * b2) / np.sqrt(soft2) - 0.5 * dot / soft2**1.5 * d_soft2
        return np.vstack(
            [
                -d_kappa / k_max,
                d_kappa / k_max,
                -d_rate,
                d_rate,
                -d_along / (g * kin.max_accel_mps2),
                d_along / kin.max_brake_mps2,
            ]
        )


class _Paths:
    """The movers' corrected paths as functions of the coefficient vector ``z`` (mover i's x then y
    coefficients in ``z[offs[i]:offs[i + 1]]``): their box tracks (for the last ``z``, cached; each
    new ``z`` spends one evaluation of ``budget``) and the tracks' derivatives with respect to ``z``."""

    def __init__(
        self,
        movers: list[Movable],
        fixed: list[Movable],
        mats: list[np.ndarray],
        offs: np.ndarray,
        budget: _Budget | None,
    ) -> None:
        self.movers, self.mats, self.offs, self.budget = movers, mats, offs, budget
        self.fixed = [box_track(m) for m in fixed]
        # d(velocity at the samples)/d(coefficients): np.gradient is linear in the positions
        self.grad_b = [_gradient_of(b, m.t) for m, b in zip(movers, mats, strict=True)]
        self._z: np.ndarray | None = None
        self._tracks: list[BoxTrack] = []
        self._vel: list[np.ndarray] = []
        self._yaw_jac: dict[int, np.ndarray] = {}

    def deltas(self, z: np.ndarray) -> list[np.ndarray]:
        return [b @ self.coefs(z, i).T for i, b in enumerate(self.mats)]

    def coefs(self, z: np.ndarray, i: int) -> np.ndarray:
        return z[self.offs[i] : self.offs[i + 1]].reshape(2, -1)

    def tracks(self, z: np.ndarray) -> list[BoxTrack]:
        """Box tracks of the corrected paths (headings of the corrected motion: a turn turns the box),
        then the fixed ones'."""
        if self._z is None or not np.array_equal(z, self._z):
            if self.budget is not None:
                self.budget.spend()
            self._tracks, self._vel, self._yaw_jac = [], [], {}
            for m, d in zip(self.movers, self.deltas(z), strict=True):
                p = m.xy + d
                vel = np.column_stack([np.gradient(p[:, 0], m.t), np.gradient(p[:, 1], m.t)]) if len(m.t) > 1 else None
                self._vel.append(np.zeros((len(m.t), 2)) if vel is None else vel)
                yaw = headings(m.t, p, m.heading, vel) if m.yaw is None else m.yaw  # Movable.yaw: not turned
                self._tracks.append(BoxTrack(m.t, p[:, 0], p[:, 1], yaw, m.length, m.width))
            self._z = np.array(z, float)
        return self._tracks + self.fixed

    def yaw_jac(self, z: np.ndarray, i: int) -> np.ndarray:
        """(N, 2K): derivatives of mover ``i``'s headings at its samples with respect to its coefficients."""
        self.tracks(z)
        if i not in self._yaw_jac:
            vel, gb = self._vel[i], self.grad_b[i]
            src = heading_sources(vel) if self.movers[i].yaw is None else None
            if src is None:
                jac = np.zeros((len(vel), 2 * gb.shape[1]))
            else:
                v = vel[src]
                r2 = np.sum(v * v, 1)[:, None]
                jac = np.hstack([-v[:, 1:] / r2 * gb[src], v[:, :1] / r2 * gb[src]])
            self._yaw_jac[i] = jac
        return self._yaw_jac[i]


DENSE_GRADIENT_MAX = 1000
"""Up to this many samples (40 s at 25 fps) :func:`_gradient_of` multiplies by the gradient matrix itself."""


def _gradient_of(b: np.ndarray, t: np.ndarray) -> np.ndarray:
    """``G @ b`` for the (N, N) matrix G with ``G @ x == np.gradient(x, t)`` (zeros for a single sample). Beyond
    ``DENSE_GRADIENT_MAX`` samples without G (G of a 200 s track's 5,000 samples took a gigabyte): np.gradient is
    linear, column by column. The same numbers up to rounding, but SLSQP follows rounding: with np.gradient alone,
    KITTI 0002's declared pedestrian crash was replayed 0.069 s early (tests/test_crash_replay.py allows 0.06)."""
    n = len(t)
    if n < 2:
        return np.zeros_like(b)
    if n <= DENSE_GRADIENT_MAX:
        return np.asarray(np.gradient(np.eye(n), t, axis=0)) @ b
    return np.asarray(np.gradient(b, t, axis=0))


def _interp_matrix(t: np.ndarray, ts: np.ndarray) -> sparse.csr_array:
    """(len(ts), len(t)) sparse matrix W with ``W @ x == np.interp(ts, t, x)`` (held constant outside ``t``):
    two entries a row (dense, a long track's rows took hundreds of megabytes)."""
    n, rows = len(t), np.arange(len(ts))
    if n == 1:
        return sparse.csr_array((np.ones(len(ts)), (rows, np.zeros(len(ts), int))), shape=(len(ts), 1))
    j = np.clip(np.searchsorted(t, ts, side="right") - 1, 0, n - 2)
    span = t[j + 1] - t[j]
    w = np.clip(np.divide(ts - t[j], span, out=np.zeros_like(ts), where=span > 0), 0.0, 1.0)
    vals = np.concatenate([1.0 - w, w])
    return sparse.csr_array((vals, (np.concatenate([rows, rows]), np.concatenate([j, j + 1]))), shape=(len(ts), n))


class _Gap:
    """One pair's separation at times ``ts`` (s) minus ``target`` (m), and its derivative in ``z``."""

    def __init__(self, paths: _Paths, i: int, j: int, ts: np.ndarray, target: float) -> None:
        self.paths, self.i, self.j, self.ts, self.target = paths, i, j, ts, target
        n = len(paths.movers)
        self.interp = {
            k: (w, w @ paths.mats[k]) for k in (i, j) if k < n for w in [_interp_matrix(paths.movers[k].t, ts)]
        }
        self._states: dict[int, tuple[BoxTrack, States]] = {}  # side -> (track, its states at ts)

    def _states_at(self, z: np.ndarray) -> tuple[BoxTrack, BoxTrack, States, States]:
        """The pair's box tracks for ``z`` and their states at ``ts``, each track's reused while it is the same
        object (a fixed road user's for good, a mover's while SLSQP stays at one ``z``: its value, then its
        Jacobian)."""
        pair = _pick(self.paths.tracks(z), self.i, self.j)
        states = []
        for side, track in enumerate(pair):
            held = self._states.get(side)
            if held is None or held[0] is not track:
                held = self._states[side] = (track, track.at(self.ts))
            states.append(held[1])
        return pair[0], pair[1], states[0], states[1]

    def fun(self, z: np.ndarray) -> np.ndarray:
        return _separation_of_states(*self._states_at(z))[0] - self.target

    def jac(self, z: np.ndarray) -> np.ndarray:
        _, part = _separation_of_states(*self._states_at(z), partials=True)
        out = np.zeros((len(self.ts), len(z)))
        for side, k in ((0, self.i), (1, self.j)):
            if k not in self.interp:
                continue
            w, wb = self.interp[k]
            lo, size = int(self.paths.offs[k]), wb.shape[1]
            px, py, ph = (part[:, 3 * side + c, None] for c in range(3))
            out[:, lo : lo + size] += px * wb
            out[:, lo + size : lo + 2 * size] += py * wb
            out[:, lo : lo + 2 * size] += ph * (w @ self.paths.yaw_jac(z, k))
        return out


@dataclass
class _Problem:
    """One SLSQP problem: the cost and its gradient, the constraints (each with its ``jac``), the paths."""

    paths: _Paths
    cost: Callable[[np.ndarray], float]
    cost_jac: Callable[[np.ndarray], np.ndarray]
    cons: list[dict[str, Any]]
    kins: list[tuple[dict[str, Any], _Kin]]


def _problem(
    movers: list[Movable],
    fixed: list[Movable],
    bases: list[_Basis],
    eq: list[tuple[int, int, float, float]],
    ineq: list[tuple[int, int, np.ndarray, float]],
    cp: ContactParams,
    strict_kin: bool = False,
    budget: _Budget | None = None,
) -> _Problem:
    """The least-squares problem of :func:`_solve`, every function with its analytic derivative."""
    sizes = [b.size for b in bases]
    offs = np.concatenate([[0], np.cumsum([2 * k for k in sizes])]).astype(int)
    mats = [(b.at(m.t), b.at(m.t, 2)) for m, b in zip(movers, bases, strict=True)]
    paths = _Paths(movers, fixed, [b for b, _ in mats], offs, budget)
    hess = _cost_hessian(movers, mats, offs, cp.smooth_s4)

    def cost(z: np.ndarray) -> float:
        return float(z @ hess @ z)

    gaps = [_Gap(paths, i, j, np.array([tc]), g) for i, j, tc, g in eq]
    cons: list[dict[str, Any]] = [{"type": "eq", "fun": c.fun, "jac": c.jac} for c in gaps]
    gaps = [_Gap(paths, i, j, ts, g) for i, j, ts, g in ineq if len(ts)]
    cons += [{"type": "ineq", "fun": c.fun, "jac": c.jac} for c in gaps]
    cons += _accel_limits(mats, offs, cp.accel_limit_mps2)
    kins = _kin_constraints(movers, bases, offs, cp, strict_kin)
    cons += [k[0] for k in kins]
    return _Problem(paths, cost, lambda z: 2.0 * (hess @ z), cons, kins)


def _solve(
    movers: list[Movable],
    fixed: list[Movable],
    bases: list[_Basis],
    eq: list[tuple[int, int, float, float]],
    ineq: list[tuple[int, int, np.ndarray, float]],
    cp: ContactParams,
    rounds: int = 2,
    strict_kin: bool = False,
    budget: _Budget | None = None,
    max_iter: int = MAX_ITER,
) -> tuple[list[np.ndarray], bool, str]:
    """Least-squares coefficients for ``movers`` (index i < len(movers)) under the pair constraints.

    ``eq``: (i, j, time, target separation); ``ineq``: (i, j, times, minimum separation); indices >=
    len(movers) refer to ``fixed``. Each mover's corrected path keeps its kinematics (``Movable.kin``):
    within the limits (``strict_kin``) or, else, no further outside them than its uncorrected path.
    Every function SLSQP sees comes with its analytic derivative (no finite differences).
    Returns the displacements, success and the optimiser's message; stops, unsuccessful, when
    ``budget`` is spent. ``max_iter``: SLSQP iterations per round.
    """
    pb = _problem(movers, fixed, bases, eq, ineq, cp, strict_kin, budget)
    with _one_blas_thread():
        return _rounds(pb, np.zeros(int(pb.paths.offs[-1])), eq, ineq, rounds, max_iter)


def _rounds(
    pb: _Problem,
    z: np.ndarray,
    eq: list[tuple[int, int, float, float]],
    ineq: list[tuple[int, int, np.ndarray, float]],
    rounds: int,
    max_iter: int = MAX_ITER,
) -> tuple[list[np.ndarray], bool, str]:
    """:func:`_solve`'s SLSQP runs from ``z``, each from the last one's end, until one succeeds."""
    paths, res, ok = pb.paths, None, False
    for _ in range(rounds):
        try:
            options = {"maxiter": max_iter, "ftol": 1e-8}
            res = minimize(pb.cost, z, jac=pb.cost_jac, method="SLSQP", constraints=pb.cons, options=options)
        except _OutOfBudget:
            return paths.deltas(z), False, f"evaluation budget ({MAX_EVALS}) spent"
        z = np.asarray(res.x)
        ok = bool(res.success) and _satisfied(paths.tracks(z), eq, ineq)
        ok &= all(bool(np.all(k[0]["fun"](z) >= -KIN_TOL)) for k in pb.kins)
        if ok:
            break
    return paths.deltas(z), ok, "" if res is None else str(res.message)


@functools.cache
def _blas_controller() -> Any:
    from threadpoolctl import ThreadpoolController

    return ThreadpoolController()


def _one_blas_thread() -> Any:
    """A context with every BLAS library loaded (NumPy's and SciPy's own OpenBLAS) on one thread.

    SLSQP's result depends on the BLAS thread count (OPENBLAS_NUM_THREADS, else the machine's cores): a
    multi-threaded OpenBLAS splits some of its reductions by thread; the phone-filmed ccd_000053's crash
    correction found another optimum with 1 thread than with 2. One thread: the same on every machine."""
    return _blas_controller().limit(limits=1, user_api="blas")


def _cost_hessian(
    movers: list[Movable], mats: list[tuple[np.ndarray, np.ndarray]], offs: np.ndarray, smooth_s4: float
) -> np.ndarray:
    """H with the least-squares cost equal to ``z @ H @ z``: per mover, ``weight`` x (the mean squared
    correction, its part across the mover's heading ``lateral_weight`` times and, with a ``metric``, under
    that per-sample metric too (:func:`sight_metric`), + ``smooth_s4`` x the mean squared acceleration),
    the mean taken over samples and both axes."""
    hess = np.zeros((int(offs[-1]), int(offs[-1])))
    for i, (b, b2) in enumerate(mats):
        m = movers[i]
        k = b.shape[1]
        # per-sample metric u u^T + L n n^T of the displacement (u: heading, n: its normal; L = 1: identity)
        yaw = box_track(m).yaw if m.lateral_weight != 1.0 else np.zeros(len(b))
        c, s = np.cos(yaw), np.sin(yaw)
        lat = m.lateral_weight
        metric = {(0, 0): c * c + lat * s * s, (1, 1): s * s + lat * c * c, (0, 1): (1.0 - lat) * c * s}
        if m.metric is not None:  # the line of sight's anisotropy on top (its identity part counted once)
            metric = {(r, q): w + m.metric[:, r, q] - float(r == q) for (r, q), w in metric.items()}
        smooth = smooth_s4 * (b2.T @ b2)
        for (r, q), w in metric.items():
            block = m.weight * (b.T @ (w[:, None] * b) + (smooth if r == q else 0.0)) / (2 * len(b))
            lo_r, lo_q = int(offs[i]) + r * k, int(offs[i]) + q * k
            hess[lo_r : lo_r + k, lo_q : lo_q + k] = block
            hess[lo_q : lo_q + k, lo_r : lo_r + k] = block.T
    return hess


def _kin_constraints(
    movers: list[Movable], bases: list[_Basis], offs: np.ndarray, cp: ContactParams, strict: bool
) -> list[tuple[dict[str, Any], _Kin]]:
    """One SLSQP inequality per mover with kinematics: its rows (:class:`_Kin`) >= 0, or >= their
    uncorrected values where those are already negative (not ``strict``)."""
    out = []
    for i, (m, b) in enumerate(zip(movers, bases, strict=True)):
        if m.kin is None or b.rigid or len(m.t) < 2 or b.hi - b.lo < 2 * KIN_STEP_S:
            continue
        kin = _Kin(m, b, cp)
        floor = np.zeros(1) if strict else np.minimum(kin.rows(np.zeros((2, b.size))), 0.0)
        lo, hi = int(offs[i]), int(offs[i + 1])

        def fun(z: np.ndarray, kin: _Kin = kin, lo: int = lo, hi: int = hi, floor: np.ndarray = floor) -> np.ndarray:
            return kin.rows(z[lo:hi].reshape(2, -1)) - floor

        def jac(z: np.ndarray, kin: _Kin = kin, lo: int = lo, hi: int = hi) -> np.ndarray:
            part = kin.jac(z[lo:hi].reshape(2, -1))
            out = np.zeros((len(part), len(z)))
            out[:, lo:hi] = part
            return out

        out.append(({"type": "ineq", "fun": fun, "jac": jac}, kin))
    return out


def _accel_limits(mats: list[tuple[np.ndarray, np.ndarray]], offs: np.ndarray, lim: float) -> list[dict[str, Any]]:
    """|delta''| <= ``lim`` (m/s^2) on each axis at every sample: linear in the coefficients."""
    rows = []
    for i, (_b, b2) in enumerate(mats):
        k = b2.shape[1]
        for axis in range(2):
            m = np.zeros((b2.shape[0], int(offs[-1])))
            m[:, offs[i] + axis * k : offs[i] + (axis + 1) * k] = b2
            rows.append(m)
    if not rows:
        return []
    a_mat = np.vstack(rows)
    return [
        {"type": "ineq", "fun": lambda z: lim - a_mat @ z, "jac": lambda z: -a_mat},
        {"type": "ineq", "fun": lambda z: lim + a_mat @ z, "jac": lambda z: a_mat},
    ]


def _satisfied(
    trs: list[BoxTrack], eq: list[tuple[int, int, float, float]], ineq: list[tuple[int, int, np.ndarray, float]]
) -> bool:
    """The constraints hold with the exact headings, within 2 cm (SLSQP may stop just short)."""
    ok = True
    for i, j, tc, target in eq:
        ok &= abs(float(separation(*_pick(trs, i, j), np.array([tc]))[0]) - target) < 0.02
    for i, j, ts, gmin in ineq:
        ok &= not len(ts) or float(separation(*_pick(trs, i, j), ts).min()) >= gmin - 0.02
    return bool(ok)


def _pick(tracks: list[BoxTrack], i: int, j: int) -> tuple[BoxTrack, BoxTrack]:
    return tracks[i], tracks[j]


def make_contact(
    a: Movable,
    b: Movable,
    t_crash: float,
    cp: ContactParams | None = None,
    movable: tuple[bool, bool] = (True, True),
    overlap_s: float = 0.0,
    apart_margin_m: float = 0.0,
) -> Correction:
    """Smallest smooth displacement of the pair's last seconds so that their boxes first touch at
    ``t_crash`` (s): overlapping by ``penetration_m`` then, apart until ``touch_tol_s`` before.
    ``overlap_s`` > 0: they first touch exactly at ``t_crash`` (separation 0, apart until
    ``TOUCH_SLACK_S`` before) and overlap ``overlap_s`` later, where the paths end, by as much as their
    own separation closes in that time (at least ``penetration_m[0]``)
    (the contact is the first touch of the 3D boxes, the overlap after it is what a lagging replay needs).

    Tries each window of ``cp.windows_s`` in turn, within the movers' kinematics, then (where SLSQP
    finds no such correction) each again with the per-axis acceleration bound only (``kinematic``
    False), and last each again so with ``LONG_MAX_ITER`` iterations; ``ok`` is False when none satisfies
    the constraints (the last try is returned).
    ``movable`` may pin one of the two (e.g. parked).
    ``apart_margin_m`` > 0: apart on an ``APART_STEP_S`` grid within the correction's window as well, and by this much
    (m) until ``APART_MARGIN_S`` before the crash where the paths were that far apart before (a replay checks every
    0.02 s; a pair apart at 5 fps samples only grazed between them, 0.44 s before the crash).
    """
    cp = cp or ContactParams()
    movers = [m for m, free in zip((a, b), movable, strict=True) if free]
    fixed = [m for m, free in zip((a, b), movable, strict=True) if not free]
    if not movers:
        return Correction([], 0.0, 0.0, 0.0, False, "nothing may move")
    lo_common = max(a.t[0], b.t[0])
    t_end = t_crash + max(overlap_s, 0.0)
    # apart until shortly before the first touch (a margin for the final spline fit)
    t_apart = t_crash - (TOUCH_SLACK_S if overlap_s > 0 else 0.8 * cp.touch_tol_s)
    if overlap_s > 0:  # touching at t_crash, overlapping by the pair's own closing at t_end
        eq = [(0, 1, t_crash, 0.0), (0, 1, t_end, -_closing_overlap(a, b, t_crash, t_end, cp))]
    else:
        eq = [(0, 1, t_crash, -_penetration(a, b, t_crash, cp))]
    last: Correction | None = None
    budget = _Budget()
    solved: dict[tuple[float, bool, int], tuple[tuple[list[np.ndarray], bool, str], int]] = {}
    tries = [(kinematic, w, MAX_ITER) for kinematic in (True, False) for w in cp.windows_s]
    for kinematic, w, max_iter in tries + [(False, w, LONG_MAX_ITER) for w in cp.windows_s]:
        lo = max(t_crash - w, lo_common)
        bases = [_rigid(m) if m.rigid else _basis(lo, t_end, cp.knot_step_s, lo > m.t[0] + 1e-6) for m in movers]
        t_free = a.t[(a.t >= lo_common) & (a.t <= t_apart)]
        t_free = np.append(t_free, t_apart) if t_apart >= lo_common else t_free
        apart = [(0, 1, t_free, 0.0)]
        if apart_margin_m > 0.0 and t_apart > lo:  # apart between the samples too, and by a margin until shortly before
            grid = np.arange(lo, t_apart, APART_STEP_S)
            early = grid[grid <= t_crash - APART_MARGIN_S]
            far = early[separation(box_track(a), box_track(b), early) >= apart_margin_m] if len(early) else early
            floor = min(APART_FLOOR_M, apart_margin_m)
            apart = [(0, 1, np.union1d(t_free, grid), 0.0), (0, 1, early, floor), (0, 1, far, apart_margin_m)]
        solve_movers = movers if kinematic else [replace(m, kin=None) for m in movers]
        # the try's problem: a window reaching past the tracks' start poses the last one's again, to the same end
        key = (float(lo), kinematic, max_iter)
        if key in solved and budget.left >= solved[key][1]:
            (ds, ok, msg), spent = solved[key]
            budget.left -= spent
        else:
            left = budget.left
            ds, ok, msg = _solve(
                solve_movers, fixed, bases, eq, apart, cp, rounds=2 if kinematic else 3, budget=budget,
                max_iter=max_iter,
            )  # fmt: skip
            solved[key] = ((ds, ok, msg), left - budget.left)
        full = _full(ds, movable)
        size = max((float(np.hypot(*d.T).max()) if len(d) else 0.0) for d in ds)
        rms = float(np.sqrt(np.mean(np.concatenate([np.sum(d**2, 1) for d in ds]))))
        last = Correction(full, size, rms, float(t_end - lo), ok, msg, kinematic)
        if ok or budget.spent:
            return last
    assert last is not None
    return last


def _penetration(a: Movable, b: Movable, t: float, cp: ContactParams) -> float:
    """Overlap (m) at the crash: ``penetration_s`` x the pair's relative speed there, clipped."""
    va, vb = box_track(a).velocity(t), box_track(b).velocity(t)
    lo, hi = cp.penetration_m
    return float(np.clip(cp.penetration_s * np.hypot(*(va - vb)), lo, hi))


def _closing_overlap(a: Movable, b: Movable, t_touch: float, t_end: float, cp: ContactParams) -> float:
    """Overlap (m) at ``t_end`` after a touch at ``t_touch``: how much the pair's own (uncorrected)
    separation closes in between, at least ``penetration_m[0]`` (a head-on pair overlaps deeper than a
    sideswipe; asking a fixed depth bends the paths sideways to slow the closing)."""
    sep = separation(box_track(a), box_track(b), np.array([t_touch, t_end]))
    return float(max(cp.penetration_m[0], sep[0] - sep[1]))


def _full(ds: list[np.ndarray], movable: tuple[bool, ...]) -> list[np.ndarray]:
    it = iter(ds)
    return [next(it) if free else np.zeros((0, 2)) for free in movable]


def nudge_apart(
    m: Movable, others: list[Movable], t_end: float, cp: ContactParams | None = None, reach_m: float = np.inf
) -> Correction:
    """Smallest smooth displacement of ``m`` (its whole track may shift; ``rigid``: only that, a parked
    car's depth error, never a motion that would turn its box) that keeps it at least ``clearance_m``
    from every vehicle of ``others`` up to ``t_end`` (s). ``reach_m``: a displacement larger than this (m) will
    not be used, so the clearance is asked only where ``m`` comes that near another (a 200 s highway track
    asked it at each of its 5,000 samples of each of 30 others: 90 s and gigabytes of SLSQP)."""
    cp = cp or ContactParams()
    lo, hi = float(m.t[0]), float(min(m.t[-1], t_end))
    if hi - lo < 1e-6:
        return Correction([np.zeros_like(m.xy)], 0.0, 0.0, 0.0, False, "too short to move")
    bases = [_rigid(m) if m.rigid else _basis(lo, hi, max(cp.knot_step_s, (hi - lo) / 12), anchored=False)]
    ineq = []
    mine = box_track(m)
    for j, o in enumerate(others):
        ts = m.t[(m.t >= max(lo, o.t[0])) & (m.t <= min(hi, o.t[-1]))]
        near = within_reach(mine, box_track(o), ts, cp.clearance_m + reach_m)  # a farther one cannot come near
        ineq.append((0, 1 + j, ts[near], cp.clearance_m))
    ds, ok, msg = _solve([m], others, bases, [], ineq, cp, budget=_Budget())
    d = ds[0]
    size = float(np.hypot(*d.T).max()) if len(d) else 0.0
    return Correction([d], size, float(np.sqrt(np.mean(np.sum(d**2, 1)))), hi - lo, ok, msg)
