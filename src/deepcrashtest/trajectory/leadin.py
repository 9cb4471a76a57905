"""No road user starts or appears inside another: invented lead-ins and continuations kept apart.

Scenario time (seconds), world frame (metres). The step-back (``trajectory.stepback``) leads every road user present
at the video's start in from rest along its first heading; nothing in the video constrains that lead-in, and two
of them can run through each other (a car faster than the one ahead of it steps back farther and starts inside it,
ccd_000330 filmed through a longer lens; a car's straight lead-in through a pedestrian who stands where it turned in
from a side street, dad_000487 at half its frame rate). The simulator ignores boxes that overlap from the moment both
exist until they part, but a user's simulator spawns both at the start and meets a collision there, and the crash
correction (``trajectory.contact.make_contact``) cannot move a pair apart before its window: it failed on such a
pair and left its crash 0.8 s early. :func:`clear_lead_ins` gives such a lead-in a gentler start from rest, or trims
it: the road user then joins the scenario where its box is clear of every other one's (``trajectory.crash`` trims
an invented part that touches another road user after the video starts the same way). :func:`clear_appearances`
does the same where a road user joins later inside another's invented path (a track continued after the video lost
it, through the place where the same car, tracked again under a new id, appears).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import replace

import numpy as np

from deepcrashtest.scenario import brush_past
from deepcrashtest.trajectory.collision import BoxTrack
from deepcrashtest.trajectory.contact import separation, separation_on_joining
from deepcrashtest.trajectory.dense import EPS_T, Dense


def seen_at(d: Dense, t: float) -> bool:
    """Whether ``t`` (s) lies within the span the video saw ``d`` (its first to its last observed sample)."""
    seen = d.t[d.observed]
    return bool(len(seen)) and seen[0] - EPS_T <= t <= seen[-1] + EPS_T


def clear_start(d: Dense, others: list[Dense], lo: float, hi: float, clearance_m: float) -> float:
    """The first sample time (s) of ``d`` in ``[lo, hi]`` at which its box is at least ``clearance_m`` (m) from
    the box of every road user of ``others`` present then; ``hi`` (where it is first seen) if none is. A
    lead-in trimmed 1 s after its contact often still overlapped the road user it touched (a scooter's
    lead-in 1.5 m into a car, dad_000478 filmed off a screen): the scenario then starts with two road users in
    one place, which the replay ignores only until they part (a graze 0.03 s later is a contact)."""
    box = d.box_track()
    ts = d.t[(d.t >= lo - EPS_T) & (d.t <= hi + EPS_T)]
    gap = np.full(len(ts), np.inf)
    for o in others:
        at = (ts >= o.t[0] - EPS_T) & (ts <= o.t[-1] + EPS_T)
        if at.any():
            gap[at] = np.minimum(gap[at], separation(box, o.box_track(), ts[at]))
    clear = ts[gap >= clearance_m]
    return float(clear[0]) if len(clear) else hi


def clear_lead_ins(
    ego: Dense, agents: list[Dense], t_max: float, clearance_m: float, warnings: list[str]
) -> list[dict[str, float]]:
    """Keep apart (in place) every pair whose boxes touch before ``t_max`` (s, where the video starts: the step-back
    lead-ins and other invented starts); returns one record per change (agent id, and its lead-in's acceleration or
    its new start).

    The one changed is an agent of the pair (never the ego, never a parked one), the less confident first. Its
    step-back lead-in (``Dense.lead_in``) first takes the strongest gentler acceleration that keeps it ``clearance_m``
    (m) from every road user present (or as near as the video first sees them): it starts from rest nearer its first
    observed position and is in the scenario from the start as before (a car faster than the one behind it). Else it
    is trimmed: it joins at :func:`clear_start` after the contact (a lead-in through a road user standing in its
    way), but only where that ends the overlap before it is seen (two boxes that overlap where the video sees both
    are depth noise, not the lead-in's doing, and stay). Pairs in which neither can change stay as they are."""
    every = [ego, *agents]

    def resolve(a: Dense, b: Dense, t_hit: float) -> dict[str, float] | None:
        movers = [d for d in (a, b) if d is not ego and not d.static and d.observed.any()]
        movers = sorted((d for d in movers if t_hit < _first_seen(d) - EPS_T), key=_least_trusted)
        done = next(((d, c) for d in movers if (c := _gentler_lead_in(d, every, clearance_m)) is not None), None)
        done = done or next(
            ((d, c) for d in movers if (c := _trimmed(d, _other(d, a, b), every, t_hit, clearance_m)) is not None), None
        )
        if done is None:
            return None
        d, change = done
        how = (
            f"it now leaves rest at {change['accel_mps2']:.2f} m/s^2" if "accel_mps2" in change
            else f"it joins the scenario at {change['to_s']:.2f} s instead of {change['from_s']:.2f} s"
        )  # fmt: skip
        warnings.append(
            f"agent {d.id}: its lead-in (before the video saw it) ran into road user {_other(d, a, b).id}; {how}"
        )
        return change

    return _pair_by_pair(every, _lead_in_contact(t_max), resolve)


def _first_seen(d: Dense) -> float:
    return float(d.t[d.observed][0])


def _gentler_lead_in(d: Dense, every: list[Dense], clearance_m: float) -> dict[str, float] | None:
    """``d``'s step-back lead-in at the strongest gentler acceleration that keeps it clear of every other road user
    (applied in place; the record), or None."""
    if d.lead_in is None:
        return None
    pre = d.t < d.lead_in.plan.t_max - EPS_T
    if not pre.any():
        return None
    others = [(o, o.box_track()) for o in every if o is not d]
    t_seen = np.array([d.lead_in.plan.t_max])
    for accel in d.lead_in.gentler_accels():
        xy = d.xy.copy()
        xy[pre] = d.lead_in.positions(d.t[pre], accel)
        box = replace(d, xy=xy).box_track()
        if all(_keeps_clear(box, o, other, d.t[pre], t_seen, clearance_m) for o, other in others):
            d.xy = xy
            return {"agent": d.id, "accel_mps2": round(float(accel), 3)}
    return None


def _keeps_clear(
    box: BoxTrack, o: Dense, other: BoxTrack, ts: np.ndarray, t_seen: np.ndarray, clearance_m: float
) -> bool:
    """Whether ``box`` stays at least ``clearance_m`` from ``o``'s box ``other`` at times ``ts`` where ``o`` exists,
    or at least as far as at ``t_seen`` (s) where that is nearer (never touching)."""
    at = ts[(ts >= o.t[0] - EPS_T) & (ts <= o.t[-1] + EPS_T)]
    if not len(at):
        return True
    floor = clearance_m
    if o.t[0] - EPS_T <= t_seen[0] <= o.t[-1] + EPS_T:
        floor = min(floor, float(separation(box, other, t_seen)[0]))
    return bool(np.all(separation(box, other, at) >= max(floor, 1e-3)))


def _trimmed(d: Dense, other: Dense, every: list[Dense], t0: float, clearance_m: float) -> dict[str, float] | None:
    """``d`` trimmed to start at :func:`clear_start` from ``t0`` (in place; the record), or None where it would
    still overlap ``other`` there."""
    start = clear_start(d, [o for o in every if o is not d], t0, _first_seen(d), clearance_m)
    if separation(d.box_track(), other.box_track(), np.array([start]))[0] <= 0.0:
        return None  # still in the other one where the video first sees it
    record = {"agent": d.id, "from_s": round(float(d.t[0]), 3), "to_s": round(start, 3)}
    d.keep(d.t >= start - EPS_T)
    d.lead_in = None
    return record


def clear_appearances(
    ego: Dense, agents: list[Dense], pair: tuple[int, ...], t_max: float, clearance_m: float, warnings: list[str]
) -> list[dict[str, float]]:
    """Keep apart (in place) every pair whose boxes overlap where the later of the two joins the scenario after the
    video starts (``t_max``, s) while one of them is invented there; returns one record per change.

    The simulator ignores such an overlap, but a road user that appears inside another is a collision in a user's
    simulator. The invented one (never the ego, never a parked one) gives way: a start extrapolated before the video
    first saw it is trimmed to join at :func:`clear_start` (or where it is first seen); a track continued after the
    video lost it (the same road user, tracked again under a new id, appears inside its continuation) ends where the
    other appears, unless it is one of the crash ``pair`` (it must reach the crash). Two road users that overlap
    where the video sees both stay as they are (depth noise)."""
    every = [ego, *agents]

    def resolve(a: Dense, b: Dense, t0: float) -> dict[str, float] | None:
        for d in sorted((a, b), key=_least_trusted):
            if d is ego or d.static or not d.observed.any():
                continue
            change = None
            if t0 < _first_seen(d) - EPS_T:
                change = _trimmed(d, _other(d, a, b), every, t0, clearance_m)
            elif t0 > _last_seen(d) + EPS_T and d.id not in pair:
                change = {"agent": d.id, "until_s": round(float(d.t[d.t < t0 - EPS_T][-1]), 3)}
                d.keep(d.t < t0 - EPS_T)
            if change is not None:
                how = (
                    f"it joins the scenario at {change['to_s']:.2f} s" if "to_s" in change
                    else f"its continuation after the video lost it ends at {change['until_s']:.2f} s"
                )  # fmt: skip
                warnings.append(f"agent {d.id}: road user {_other(d, a, b).id} appears inside its invented path; {how}")
                return change
        return None

    return _pair_by_pair(every, _overlap_on_joining(t_max), resolve)


def _last_seen(d: Dense) -> float:
    return float(d.t[d.observed][-1])


def _brush(a: Dense, b: Dense) -> bool:
    """Whether the two brush past each other (:func:`~deepcrashtest.scenario.brush_past`): no pair event of theirs."""
    return brush_past(a.vehicle.category, b.vehicle.category)


PairEvent = Callable[[Dense, Dense, BoxTrack, BoxTrack], "float | None"]


def _lead_in_contact(t_max: float) -> PairEvent:
    """The pair's first overlap before ``t_max`` (s, where the video starts: every sample before it is invented)."""

    def when(a: Dense, b: Dense, box_a: BoxTrack, box_b: BoxTrack) -> float | None:
        lo, hi = max(float(a.t[0]), float(b.t[0])), min(float(a.t[-1]), float(b.t[-1]), t_max - EPS_T)
        ts = a.t[(a.t >= lo - EPS_T) & (a.t <= hi)]
        hit = ts[separation(box_a, box_b, ts) < 0.0] if len(ts) else ts
        return float(hit[0]) if len(hit) else None

    return when


def _overlap_on_joining(t_max: float) -> PairEvent:
    """The first moment both exist, at or after ``t_max`` (s), where their boxes overlap then."""

    def when(a: Dense, b: Dense, box_a: BoxTrack, box_b: BoxTrack) -> float | None:
        joining = separation_on_joining(box_a, box_b, EPS_T)
        return joining[0] if joining is not None and joining[0] >= t_max - EPS_T and joining[1] < 0.0 else None

    return when


def _pair_by_pair(
    every: list[Dense], when: PairEvent, resolve: Callable[[Dense, Dense, float], dict[str, float] | None]
) -> list[dict[str, float]]:
    """``resolve`` the pair (not both parked) whose event ``when`` comes first, then the next, until none is left (a
    pair it cannot resolve is not offered again); the records of the changes made. Each pair's event is computed
    once and again only after ``resolve`` changed one of the two (the change record's ``agent``): 80 road users, a
    few of them changed and dozens of pairs left as they are, were scanned afresh after each (KITTI 0019's labelled
    road users: 9 s)."""
    changes: list[dict[str, float]] = []
    pairs = [(a, b) for i, a in enumerate(every) for b in every[i + 1 :] if not (a.static and b.static or _brush(a, b))]
    boxes: dict[int, BoxTrack] = {}
    times: dict[tuple[int, int], float | None] = {}

    def box(d: Dense) -> BoxTrack:
        if d.id not in boxes:
            boxes[d.id] = d.box_track()
        return boxes[d.id]

    for _ in range(2 * len(every) + 1):
        best: tuple[tuple[Dense, Dense], float] | None = None
        for a, b in pairs:
            key = (a.id, b.id)
            if key not in times:
                times[key] = when(a, b, box(a), box(b))
            t = times[key]
            if t is not None and (best is None or t < best[1]):
                best = ((a, b), t)
        if best is None:
            break
        (a, b), t = best
        change = resolve(a, b, t)
        if change is None:
            times[(a.id, b.id)] = None  # not offered again
            continue
        changes.append(change)
        moved = int(change["agent"])
        boxes.pop(moved, None)
        times = {k: v for k, v in times.items() if moved not in k}
    return changes


def _other(d: Dense, a: Dense, b: Dense) -> Dense:
    return b if d is a else a


def _least_trusted(d: Dense) -> tuple[float, int]:
    """Sort key: the less confident road user first (then the shorter track)."""
    return (d.vehicle.confidence or 0.0, len(d.t))
