"""A scenario that starts with no two road users in one place: invented lead-ins trimmed where they overlap.

Scenario time (seconds), world frame (metres). The step-back (``trajectory.stepback``) leads every road user present
at the video's start in from rest along its first heading; nothing in the video constrains that lead-in, and two
of them can run through each other (a car faster than the one ahead of it steps back farther and starts inside it,
ccd_000330 filmed through a longer lens; a car's straight lead-in through a pedestrian who stands where it turned in
from a side street, dad_000487 at half its frame rate). The simulator ignores boxes that overlap from the moment both
exist until they part, but a user's simulator spawns both at the start and meets a collision there, and the crash
correction (``trajectory.contact.make_contact``) cannot move a pair apart before its window: it failed on such a
pair and left its crash 0.8 s early. :func:`clear_lead_ins` gives such a lead-in a gentler start from rest, or trims
it: the road user then joins the scenario where its box is clear of every other one's (``trajectory.crash`` trims
an invented part that touches another road user after the video starts the same way).
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np

from deepcrashtest.trajectory.contact import separation
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
    changes: list[dict[str, float]] = []
    every = [ego, *agents]
    stuck: set[tuple[int, int]] = set()
    for _ in range(2 * len(every) + 1):
        found = _first_lead_in_contact(every, t_max, stuck)
        if found is None:
            break
        (a, b), t_hit = found
        movers = [
            d for d in (a, b) if d is not ego and not d.static and d.observed.any() and t_hit < _first_seen(d) - EPS_T
        ]
        movers.sort(key=lambda m: (m.vehicle.confidence or 0.0, len(m.t)))
        change = next((c for d in movers if (c := _gentler_lead_in(d, every, clearance_m)) is not None), None)
        change = change or next(
            (c for d in movers if (c := _trimmed(d, b if d is a else a, every, t_hit, clearance_m))), None
        )
        if change is None:
            stuck.add((a.id, b.id))
            continue
        changes.append(change)
        other = b.id if change["agent"] == a.id else a.id
        how = (
            f"it now leaves rest at {change['accel_mps2']:.2f} m/s^2" if "accel_mps2" in change
            else f"it joins the scenario at {change['to_s']:.2f} s instead of {change['from_s']:.2f} s"
        )  # fmt: skip
        warnings.append(
            f"agent {change['agent']}: its lead-in (before the video saw it) ran into road user {other}; {how}"
        )
    return changes


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
    others = [o for o in every if o is not d]
    t_seen = np.array([d.lead_in.plan.t_max])
    for accel in d.lead_in.gentler_accels():
        xy = d.xy.copy()
        xy[pre] = d.lead_in.positions(d.t[pre], accel)
        trial = replace(d, xy=xy)
        if all(_keeps_clear(trial, o, d.t[pre], t_seen, clearance_m) for o in others):
            d.xy = xy
            return {"agent": d.id, "accel_mps2": round(float(accel), 3)}
    return None


def _keeps_clear(d: Dense, o: Dense, ts: np.ndarray, t_seen: np.ndarray, clearance_m: float) -> bool:
    """Whether ``d``'s box stays at least ``clearance_m`` from ``o``'s at times ``ts`` where both exist, or at least
    as far as at ``t_seen`` (s) where that is nearer (never touching)."""
    at = ts[(ts >= o.t[0] - EPS_T) & (ts <= o.t[-1] + EPS_T)]
    if not len(at):
        return True
    box, other = d.box_track(), o.box_track()
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


def _first_lead_in_contact(
    every: list[Dense], t_max: float, stuck: set[tuple[int, int]]
) -> tuple[tuple[Dense, Dense], float] | None:
    """The pair (not both parked, not in ``stuck``) whose boxes first overlap before ``t_max`` (s, where the video
    starts: every sample before it is invented), the earliest first, with that time (s)."""
    best: tuple[tuple[Dense, Dense], float] | None = None
    boxes = [d.box_track() for d in every]
    for i in range(len(every)):
        for j in range(i + 1, len(every)):
            a, b = every[i], every[j]
            if (a.static and b.static) or (a.id, b.id) in stuck:
                continue
            lo, hi = max(float(a.t[0]), float(b.t[0])), min(float(a.t[-1]), float(b.t[-1]), t_max - EPS_T)
            ts = a.t[(a.t >= lo - EPS_T) & (a.t <= hi)]
            if not len(ts) or (best is not None and ts[0] >= best[1]):
                continue
            hit = ts[separation(boxes[i], boxes[j], ts) < 0.0]
            if len(hit) and (best is None or hit[0] < best[1]):
                best = ((a, b), float(hit[0]))
    return best
