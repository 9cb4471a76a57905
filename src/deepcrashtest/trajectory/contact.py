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
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, replace
from typing import Any

import numpy as np
from scipy.interpolate import BSpline, make_interp_spline
from scipy.optimize import minimize

from deepcrashtest.scenario import VEHICLE_KINEMATICS, Kinematics
from deepcrashtest.trajectory.collision import BoxTrack, headings


def separation(a: BoxTrack, b: BoxTrack, t: np.ndarray) -> np.ndarray:
    """Signed separation (m) of the two oriented boxes at times ``t`` (s), separating-axis test.

    > 0: apart (the largest gap along the four box axes, a lower bound of the distance);
    < 0: overlapping (minus the penetration depth). Each track is linearly interpolated.
    """
    t = np.atleast_1d(np.asarray(t, float))
    xa, ya, ha = a.at(t)
    xb, yb, hb = b.at(t)
    d = np.stack([xb - xa, yb - ya], axis=-1)
    ua = np.stack([np.cos(ha), np.sin(ha)], axis=-1)
    ub = np.stack([np.cos(hb), np.sin(hb)], axis=-1)
    va = np.stack([-ua[:, 1], ua[:, 0]], axis=-1)
    vb = np.stack([-ub[:, 1], ub[:, 0]], axis=-1)
    gaps = []
    for n in (ua, va, ub, vb):
        ra = 0.5 * a.length * np.abs(np.sum(ua * n, -1)) + 0.5 * a.width * np.abs(np.sum(va * n, -1))
        rb = 0.5 * b.length * np.abs(np.sum(ub * n, -1)) + 0.5 * b.width * np.abs(np.sum(vb * n, -1))
        gaps.append(np.abs(np.sum(d * n, -1)) - ra - rb)
    return np.max(np.stack(gaps), axis=0)


@dataclass(frozen=True)
class ContactParams:
    """Knobs of the crash-consistent correction (seconds, metres, m/s^2)."""

    windows_s: tuple[float, ...] = (2.0, 3.0, 4.5)
    """Tried in turn: how long before the crash a participant's correction may start."""
    knot_step_s: float = 0.5
    """Spacing of the correction spline's knots."""
    smooth_s4: float = 0.1
    """Weight of the correction's squared acceleration against its squared size (s^4)."""
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
    yaw: np.ndarray | None = None
    """Box headings (rad) per sample that a correction does not turn (a crawling ego: the camera's
    measured yaw, its path's direction being noise); None: the heading of the (corrected) motion."""


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
# Box-track evaluations (~1 ms each) one make_contact / nudge_apart call may spend over all its windows and
# rounds: bounds stage 2's time on pathological tracks (a wrong pair once ran > 10 min). Measured on the 19
# labelled crash clips (2026-12-01): at most 64,186 box tracks built for a correction that was found, so none is cut.
MAX_EVALS = 100_000
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
) -> tuple[list[np.ndarray], bool, str]:
    """Least-squares coefficients for ``movers`` (index i < len(movers)) under the pair constraints.

    ``eq``: (i, j, time, target separation); ``ineq``: (i, j, times, minimum separation); indices >=
    len(movers) refer to ``fixed``. Each mover's corrected path keeps its kinematics (``Movable.kin``):
    within the limits (``strict_kin``) or, else, no further outside them than its uncorrected path.
    Returns the displacements, success and the optimiser's message; stops, unsuccessful, when
    ``budget`` is spent.
    """
    sizes = [b.size for b in bases]
    offs = np.concatenate([[0], np.cumsum([2 * k for k in sizes])]).astype(int)
    mats = [(b.at(m.t), b.at(m.t, 2)) for m, b in zip(movers, bases, strict=True)]

    def coefs(z: np.ndarray, i: int) -> np.ndarray:
        return z[offs[i] : offs[i + 1]].reshape(2, -1)

    def deltas(z: np.ndarray) -> list[np.ndarray]:
        return [mats[i][0] @ coefs(z, i).T for i in range(len(movers))]

    def cost(z: np.ndarray) -> float:
        total = 0.0
        for i, (b, b2) in enumerate(mats):
            c = coefs(z, i)
            total += movers[i].weight * (np.mean((b @ c.T) ** 2) + cp.smooth_s4 * np.mean((b2 @ c.T) ** 2))
        return float(total)

    fixed_tracks = [box_track(m) for m in fixed]

    def all_tracks(z: np.ndarray) -> list[BoxTrack]:
        """Box tracks of the corrected paths (headings of the corrected motion: a turn turns the box)."""
        if budget is not None:
            budget.spend()
        ds = deltas(z)
        return [box_track(m, m.xy + ds[i]) for i, m in enumerate(movers)] + fixed_tracks

    def gap(i: int, j: int, ts: np.ndarray, target: float) -> Callable[[np.ndarray], np.ndarray]:
        return lambda z: separation(*_pick(all_tracks(z), i, j), ts) - target

    cons: list[dict[str, Any]] = [{"type": "eq", "fun": gap(i, j, np.array([tc]), g)} for i, j, tc, g in eq]
    cons += [{"type": "ineq", "fun": gap(i, j, ts, g)} for i, j, ts, g in ineq if len(ts)]
    cons += _accel_limits(mats, offs, cp.accel_limit_mps2)
    kins = _kin_constraints(movers, bases, offs, cp, strict_kin)
    cons += [k[0] for k in kins]
    z = np.zeros(offs[-1])
    res = None
    for _ in range(rounds):
        try:
            res = minimize(cost, z, method="SLSQP", constraints=cons, options={"maxiter": MAX_ITER, "ftol": 1e-8})
        except _OutOfBudget:
            return deltas(z), False, f"evaluation budget ({MAX_EVALS}) spent"
        z = np.asarray(res.x)
        ok = bool(res.success) and _satisfied(all_tracks(z), eq, ineq)
        ok &= all(bool(np.all(k[0]["fun"](z) >= -KIN_TOL)) for k in kins)
        if ok:
            break
    return deltas(z), ok, "" if res is None else str(res.message)


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

        out.append(({"type": "ineq", "fun": fun}, kin))
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


def _before(m: Movable, t_end: float) -> np.ndarray:
    return m.t[m.t <= t_end + 1e-9]


def make_contact(
    a: Movable,
    b: Movable,
    t_crash: float,
    cp: ContactParams | None = None,
    movable: tuple[bool, bool] = (True, True),
    overlap_s: float = 0.0,
) -> Correction:
    """Smallest smooth displacement of the pair's last seconds so that their boxes first touch at
    ``t_crash`` (s): overlapping by ``penetration_m`` then, apart until ``touch_tol_s`` before.
    ``overlap_s`` > 0: they first touch exactly at ``t_crash`` (separation 0, apart until
    ``TOUCH_SLACK_S`` before) and overlap ``overlap_s`` later, where the paths end, by as much as their
    own separation closes in that time (at least ``penetration_m[0]``)
    (the contact is the first touch of the 3D boxes, the overlap after it is what a lagging replay needs).

    Tries each window of ``cp.windows_s`` in turn, within the movers' kinematics, then (where SLSQP
    finds no such correction) each again with the per-axis acceleration bound only (``kinematic``
    False); ``ok`` is False when none satisfies the constraints (the last try is returned).
    ``movable`` may pin one of the two (e.g. parked).
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
    for kinematic, w in [(True, w) for w in cp.windows_s] + [(False, w) for w in cp.windows_s]:
        lo = max(t_crash - w, lo_common)
        bases = [_rigid(m) if m.rigid else _basis(lo, t_end, cp.knot_step_s, lo > m.t[0] + 1e-6) for m in movers]
        t_free = a.t[(a.t >= lo_common) & (a.t <= t_apart)]
        t_free = np.append(t_free, t_apart) if t_apart >= lo_common else t_free
        solve_movers = movers if kinematic else [replace(m, kin=None) for m in movers]
        ds, ok, msg = _solve(
            solve_movers, fixed, bases, eq, [(0, 1, t_free, 0.0)], cp, rounds=2 if kinematic else 3, budget=budget
        )
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


def nudge_apart(m: Movable, others: list[Movable], t_end: float, cp: ContactParams | None = None) -> Correction:
    """Smallest smooth displacement of ``m`` (its whole track may shift) that keeps it at least
    ``clearance_m`` from every vehicle of ``others`` up to ``t_end`` (s)."""
    cp = cp or ContactParams()
    lo, hi = float(m.t[0]), float(min(m.t[-1], t_end))
    if hi - lo < 1e-6:
        return Correction([np.zeros_like(m.xy)], 0.0, 0.0, 0.0, False, "too short to move")
    bases = [_basis(lo, hi, max(cp.knot_step_s, (hi - lo) / 12), anchored=False)]
    ineq = []
    for j, o in enumerate(others):
        ts = m.t[(m.t >= max(lo, o.t[0])) & (m.t <= min(hi, o.t[-1]))]
        ineq.append((0, 1 + j, ts, cp.clearance_m))
    ds, ok, msg = _solve([m], others, bases, [], ineq, cp, budget=_Budget())
    d = ds[0]
    size = float(np.hypot(*d.T).max()) if len(d) else 0.0
    return Correction([d], size, float(np.sqrt(np.mean(np.sum(d**2, 1)))), hi - lo, ok, msg)
