"""Crash-consistent corrections: make two road users touch at the crash time, keep everyone else apart.

World frame (metres, x forward, y left), scenario time (seconds). A correction is a smooth
displacement ``delta(t)`` (metres) added to a vehicle's dense path: a cubic B-spline in time whose
coefficients are found by least squares (size + ``smooth_s4`` x acceleration, both squared) under
constraints solved with SciPy's SLSQP:

* the pair's signed box separation (:func:`separation`) is ``-penetration_m`` at the crash time and
  >= 0 up to ``touch_tol_s`` before it (so their first contact lies within that tolerance);
* the correction's own acceleration stays under ``accel_limit_mps2`` on each axis (the braking /
  steering a driver can add), so the corrected path stays drivable;
* a participant's correction starts at zero value, speed and acceleration ``window_s`` before the
  crash (only its last seconds move); a bystander's may shift its whole track (``nudge_apart``).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import numpy as np
from scipy.interpolate import BSpline
from scipy.optimize import minimize

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


@dataclass(frozen=True)
class Correction:
    """The result: one displacement (N, 2) per movable vehicle, its largest size (m) and the window (s)."""

    deltas: list[np.ndarray]
    max_m: float
    rms_m: float
    window_s: float
    ok: bool
    message: str = ""


def box_track(m: Movable, xy: np.ndarray | None = None) -> BoxTrack:
    """The movable's box track (heading of the motion, ``heading`` where it is still)."""
    p = m.xy if xy is None else xy
    return BoxTrack(m.t, p[:, 0], p[:, 1], headings(m.t, p, m.heading), m.length, m.width)


def _fast_track(m: Movable, yaw: np.ndarray, xy: np.ndarray) -> BoxTrack:
    """Box track with a given heading (the optimiser keeps the uncorrected headings; checked after)."""
    return BoxTrack(m.t, xy[:, 0], xy[:, 1], yaw, m.length, m.width)


def _basis(t: np.ndarray, lo: float, hi: float, step: float, anchored: bool) -> tuple[np.ndarray, np.ndarray]:
    """Cubic B-spline basis on [lo, hi] at times ``t`` and its second derivative, zero outside.

    ``anchored``: drop the first three functions, so value, slope and curvature are zero at ``lo``.
    Returns (B, B2), each (len(t), K).
    """
    n_in = max(0, int(round((hi - lo) / step)) - 1)
    inner = np.linspace(lo, hi, n_in + 2)[1:-1]
    knots = np.concatenate([[lo] * 4, inner, [hi] * 4])
    k_all = len(knots) - 4
    first = 3 if anchored else 0
    inside = (t >= lo) & (t <= hi)
    tt = np.clip(t, lo, hi)  # constant continuation outside [lo, hi] (zero before lo when anchored)
    b = np.zeros((len(t), k_all - first))
    b2 = np.zeros_like(b)
    for j in range(first, k_all):
        c = np.zeros(k_all)
        c[j] = 1.0
        spl = BSpline(knots, c, 3)
        b[:, j - first] = spl(tt)
        b2[:, j - first] = spl.derivative(2)(tt) * inside
    return b, b2


def _rigid(t: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """A constant shift: one basis function equal to 1, no acceleration."""
    return np.ones((len(t), 1)), np.zeros((len(t), 1))


def _solve(
    movers: list[Movable],
    fixed: list[Movable],
    bases: list[tuple[np.ndarray, np.ndarray]],
    eq: list[tuple[int, int, float, float]],
    ineq: list[tuple[int, int, np.ndarray, float]],
    cp: ContactParams,
    rounds: int = 3,
) -> tuple[list[np.ndarray], bool, str]:
    """Least-squares coefficients for ``movers`` (index i < len(movers)) under the pair constraints.

    ``eq``: (i, j, time, target separation); ``ineq``: (i, j, times, minimum separation); indices >=
    len(movers) refer to ``fixed``. Returns the displacements, success and the optimiser's message.
    """
    sizes = [b.shape[1] for b, _ in bases]
    offs = np.concatenate([[0], np.cumsum([2 * k for k in sizes])]).astype(int)

    def deltas(z: np.ndarray) -> list[np.ndarray]:
        out = []
        for i, (b, _b2) in enumerate(bases):
            c = z[offs[i] : offs[i + 1]].reshape(2, -1)
            out.append(np.column_stack([b @ c[0], b @ c[1]]))
        return out

    def cost(z: np.ndarray) -> float:
        total = 0.0
        for i, (b, b2) in enumerate(bases):
            c = z[offs[i] : offs[i + 1]].reshape(2, -1)
            total += movers[i].weight * (np.mean((b @ c.T) ** 2) + cp.smooth_s4 * np.mean((b2 @ c.T) ** 2))
        return float(total)

    fixed_tracks = [box_track(m) for m in fixed]
    yaws = [box_track(m).yaw for m in movers]  # held during one solve, then updated from its result

    def all_tracks(z: np.ndarray, exact: bool = False) -> list[BoxTrack]:
        ds = deltas(z)
        if exact:
            return [box_track(m, m.xy + ds[i]) for i, m in enumerate(movers)] + fixed_tracks
        return [_fast_track(m, yaws[i], m.xy + ds[i]) for i, m in enumerate(movers)] + fixed_tracks

    def gap(i: int, j: int, ts: np.ndarray, target: float) -> Callable[[np.ndarray], np.ndarray]:
        return lambda z: separation(*_pick(all_tracks(z), i, j), ts) - target

    cons: list[dict[str, Any]] = [{"type": "eq", "fun": gap(i, j, np.array([tc]), g)} for i, j, tc, g in eq]
    cons += [{"type": "ineq", "fun": gap(i, j, ts, g)} for i, j, ts, g in ineq if len(ts)]
    cons += _accel_limits(bases, offs, cp.accel_limit_mps2)
    z = np.zeros(offs[-1])
    for _ in range(rounds):
        res = minimize(cost, z, method="SLSQP", constraints=cons, options={"maxiter": 200, "ftol": 1e-8})
        z = np.asarray(res.x)
        ds = deltas(z)
        yaws[:] = [box_track(m, m.xy + ds[i]).yaw for i, m in enumerate(movers)]
        ok = bool(res.success) and _satisfied(all_tracks(z, exact=True), eq, ineq)
        if ok:
            break
    return deltas(z), ok, str(res.message)


def _accel_limits(bases: list[tuple[np.ndarray, np.ndarray]], offs: np.ndarray, lim: float) -> list[dict[str, Any]]:
    """|delta''| <= ``lim`` (m/s^2) on each axis at every sample: linear in the coefficients."""
    rows = []
    for i, (_b, b2) in enumerate(bases):
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
    a: Movable, b: Movable, t_crash: float, cp: ContactParams | None = None, movable: tuple[bool, bool] = (True, True)
) -> Correction:
    """Smallest smooth displacement of the pair's last seconds so that their boxes first touch at
    ``t_crash`` (s): overlapping by ``penetration_m`` then, apart until ``touch_tol_s`` before.

    Tries each window of ``cp.windows_s`` in turn; ``ok`` is False when none satisfies the constraints
    (the displacements of the last try are returned). ``movable`` may pin one of the two (e.g. parked).
    """
    cp = cp or ContactParams()
    movers = [m for m, free in zip((a, b), movable, strict=True) if free]
    fixed = [m for m, free in zip((a, b), movable, strict=True) if not free]
    if not movers:
        return Correction([], 0.0, 0.0, 0.0, False, "nothing may move")
    lo_common = max(a.t[0], b.t[0])
    last: Correction | None = None
    for w in cp.windows_s:
        lo = max(t_crash - w, lo_common)
        bases = [
            _rigid(m.t) if m.rigid else _basis(m.t, lo, t_crash, cp.knot_step_s, lo > m.t[0] + 1e-6) for m in movers
        ]
        t_apart = t_crash - 0.8 * cp.touch_tol_s  # a margin for the final spline fit
        t_free = a.t[(a.t >= lo_common) & (a.t <= t_apart)]
        t_free = np.append(t_free, t_apart) if t_apart >= lo_common else t_free
        eq = [(0, 1, t_crash, -_penetration(a, b, t_crash, cp))]
        ds, ok, msg = _solve(movers, fixed, bases, eq, [(0, 1, t_free, 0.0)], cp)
        full = _full(ds, movable)
        size = max((float(np.hypot(*d.T).max()) if len(d) else 0.0) for d in ds)
        rms = float(np.sqrt(np.mean(np.concatenate([np.sum(d**2, 1) for d in ds]))))
        last = Correction(full, size, rms, float(t_crash - lo), ok, msg)
        if ok:
            return last
    assert last is not None
    return last


def _penetration(a: Movable, b: Movable, t: float, cp: ContactParams) -> float:
    """Overlap (m) at the crash: ``penetration_s`` x the pair's relative speed there, clipped."""
    va, vb = box_track(a).velocity(t), box_track(b).velocity(t)
    lo, hi = cp.penetration_m
    return float(np.clip(cp.penetration_s * np.hypot(*(va - vb)), lo, hi))


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
    bases = [_basis(m.t, lo, hi, max(cp.knot_step_s, (hi - lo) / 12), anchored=False)]
    ineq = []
    for j, o in enumerate(others):
        ts = m.t[(m.t >= max(lo, o.t[0])) & (m.t <= min(hi, o.t[-1]))]
        ineq.append((0, 1 + j, ts, cp.clearance_m))
    ds, ok, msg = _solve([m], others, bases, [], ineq, cp)
    d = ds[0]
    size = float(np.hypot(*d.T).max()) if len(d) else 0.0
    return Correction([d], size, float(np.sqrt(np.mean(np.sum(d**2, 1)))), hi - lo, ok, msg)
