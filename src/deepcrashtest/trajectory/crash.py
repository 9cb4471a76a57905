"""Stage 2's crash phase: the crash seen in the video happens in the scenario, and nothing before it.

Scenario time (seconds), world frame (metres). Given the crash (time and pair, from the raw
scenario's ``collision``), the pair's last seconds are corrected so that their boxes first touch
at that time (``trajectory.contact.make_contact``; the pair's paths are continued at their last
velocity for ``ContactParams.penetration_s`` more, overlapping there, so that a replay that lags its
path slightly still touches; what the video shows after the contact is the impact); then
every other pair that touches before the paths end is separated by nudging the bystander
(``nudge_apart``) or, if that fails, dropping it. With
no crash known, either the first ego-agent overlap is the crash (legacy, ``find_first``) or, when
the video is known to show no crash, every contact is removed the same way.
"""

from __future__ import annotations

import hashlib
import math
from dataclasses import dataclass, field, replace
from typing import Any

import numpy as np

from deepcrashtest.errors import UserError
from deepcrashtest.scenario import Collision, brush_past, kinematics
from deepcrashtest.trajectory.collision import BoxTrack, Contact, first_contact
from deepcrashtest.trajectory.contact import (
    ContactParams,
    Correction,
    Movable,
    box_track,
    make_contact,
    nudge_apart,
    overlap_samples,
    separation,
    separation_on_joining,
    sight_metric,
)
from deepcrashtest.trajectory.dense import EPS_T, Dense
from deepcrashtest.trajectory.leadin import clear_appearances, clear_lead_ins, clear_start, seen_at
from deepcrashtest.trajectory.params import Stage2Params
from deepcrashtest.trajectory.parked import parked_apart

EGO_WEIGHT = 3.0  # the ego's path (visual odometry) is trusted more than a monocular agent track
EGO_LATERAL_WEIGHT = 10.0
"""... and its heading (the camera's yaw) more than its speed scale: the ego is moved along its path first. With 1,
ccd_000330's ego swerved (replay contact 0.49 s off, a bystander touched first); with 10 reproduced (replay IoU
0.42); ccd_000014 0.39 -> 0.37, the other crash clips unchanged (bench/fidelity_crashes.py --stage2)."""
STATIC_WEIGHT = 10.0  # a parked car moves last
MAX_NUDGE_M = 3.0  # a bystander that must move farther than this is dropped instead
MAX_FAILED_CORRECTION_M = 5.0  # a crash correction that failed and is larger than this is not applied


@dataclass
class CrashOutcome:
    """The collision (scenario time), the remaining agents, and what was changed (for provenance)."""

    collision: Collision | None
    agents: list[Dense]
    record: dict[str, Any] = field(default_factory=dict)


def contact_params(p: Stage2Params) -> ContactParams:
    w = p.crash_window_s
    return ContactParams(
        windows_s=(w, 1.5 * w, 2.25 * w),
        accel_limit_mps2=p.crash_accel_limit_mps2,
        large_m=p.crash_large_correction_m,
        penetration_s=p.crash_overlap_s,
    )


def _movable(d: Dense, ego: Dense, cp: ContactParams) -> Movable:
    """``d`` as a :class:`Movable`; an agent's displacements cost :func:`sight_metric` from the ego (the
    camera that placed it), the ego's cost ``EGO_LATERAL_WEIGHT`` times more across its heading."""
    is_ego = d is ego
    weight = EGO_WEIGHT if is_ego else (STATIC_WEIGHT if d.static else 1.0)
    rigid = d.static and not is_ego
    kin = None if rigid else kinematics(d.vehicle.category)
    yaw = None if d.box_yaw is None and not d.static else d.box_headings()
    lateral = EGO_LATERAL_WEIGHT if is_ego else 1.0
    metric = None
    if not is_ego:
        cam = np.column_stack([np.interp(d.t, ego.t, ego.xy[:, 0]), np.interp(d.t, ego.t, ego.xy[:, 1])])
        metric = sight_metric(d.xy, cam, cp.sight_across)
    return Movable(
        d.t, d.xy, d.vehicle.length, d.vehicle.width, d.heading, weight, rigid=rigid, kin=kin, lateral_weight=lateral,
        yaw=yaw, metric=metric,
    )  # fmt: skip


def resolve_crash(
    known: Collision | None,
    ego: Dense,
    agents: list[Dense],
    p: Stage2Params,
    warnings: list[str],
    *,
    t_from: float,
    no_crash: bool,
) -> CrashOutcome:
    """The crash phase (module docstring). ``known`` is in scenario time; ``t_from`` (s) is where the
    video starts in scenario time (legacy search starts there); ``no_crash``: the video shows none."""
    cp = contact_params(p)
    record: dict[str, Any] = {}
    collision = known
    legacy = False
    if collision is None and not no_crash:
        collision = find_first(ego, agents, t_from)
        legacy = collision is not None  # already touching there: nothing to enforce
        if legacy:
            record["source"] = "first box overlap of the ego with an agent after the lead-in"
    if collision is not None:
        byid = {d.id: d for d in [ego, *agents]}
        missing = [i for i in collision.participants if i not in byid]
        if missing:
            msg = f"collision participant(s) {missing} were dropped in stage 2 (track too short or implausible)"
            if collision.source == "user":
                raise UserError(msg)
            warnings.append(f"{msg}; the scenario has no collision")
            collision = None
    if collision is not None:
        for d in [ego, *agents]:
            d.cut(collision.time_s)  # after the contact the video shows the impact, not the approach
        late = [d for d in agents if d.t[0] >= collision.time_s - EPS_T]
        for d in late:
            warnings.append(f"agent {d.id}: appears after the collision; dropped")
        agents = [d for d in agents if d not in late]
        t_end = collision.time_s + (0.0 if legacy else cp.penetration_s)  # the pair overlaps until the paths end
        for d in [ego, *agents]:
            if d.id in collision.participants and d.t[-1] < t_end - EPS_T:
                if d.t[-1] < collision.time_s - EPS_T:
                    warnings.append(
                        f"agent {d.id}: last seen {collision.time_s - d.t[-1]:.2f} s before the crash; continued at "
                        "its last velocity to the crash"
                    )
                _reach(d, t_end)
    # before the pair's correction: it cannot move them apart before its window
    lead_ins = clear_lead_ins(ego, agents, t_from, cp.clearance_m, warnings)
    pair_ids = collision.participants if collision is not None else ()
    lead_ins += clear_appearances(ego, agents, pair_ids, t_from, cp.clearance_m, warnings)
    if lead_ins:
        record["lead_ins"] = lead_ins
    if collision is not None and not legacy:
        record.update(_enforce_pair(collision, ego, agents, cp, warnings))
    if collision is None:
        t_apart = max(float(d.t[-1]) for d in [ego, *agents]) - cp.touch_tol_s
    else:  # the pair first touches at the collision time (legacy: up to touch_tol_s before); the paths end after it
        t_apart = collision.time_s - (cp.touch_tol_s if legacy else -cp.penetration_s)
    pair = collision.participants if collision is not None else ()
    agents, nudges = _separate_others(ego, agents, pair, t_apart, cp, warnings)
    if nudges:
        record["bystanders"] = nudges
    shrunk = parked_apart(agents, pair, warnings)
    if shrunk:
        record["parked_shortened"] = shrunk
    return CrashOutcome(collision, agents, record)


EARLIER_TOUCH_S = 0.5
"""A detected crash (no camera jolt) with a pedestrian whose pair already touches this much earlier happens at that
touch (s). Chosen on the tuning split of ``bench/crash_detect_bench.py`` (DAD + even CCD): of the jolt-free
detections the touch came 0.78 s early on ccd_000882 (the touch right), 0.31 s on dad_000493 and 0.25 s on
ccd_000340 (the detection right); on the held-out odd CCD clips no jolt-free detection has a touch > 0.1 s earlier.
Only with a pedestrian (round touch26): a struck person is carried on the bonnet and their box goes on changing after
the contact, while a vehicle's box stops growing at it (the knee the detection takes); through a wide-angle lens
(``bench/fidelity_perturbed.py --variants fisheye``) dad_000493's motorcycle and ccd_000340's car touched 0.55 / 0.51 s
before detections that were right (0.2 / 0.0 s from the label), the only two times the rule fired on the 20 clips
and their 108 variants, both lost."""


def earlier_touch(known: Collision, ego: Dense, agents: list[Dense], t_from: float, warnings: list[str]) -> Collision:
    """``known`` (scenario time), at the pair's first box contact when that comes more than ``EARLIER_TOUCH_S`` before
    it, after ``t_from`` (s) and where both were seen, when one of the two is a pedestrian: a crash detected where an
    approaching box stopped growing (no camera jolt) can be the moment after the impact (ccd_000882: the pedestrian is
    on the bonnet at 3.8 s; the boxes, as seen, touch at 3.02 s, the labelled contact 3.0 s)."""
    byid = {d.id: d for d in [ego, *agents]}
    if not all(i in byid for i in known.participants):
        return known
    a, b = (byid[i] for i in known.participants)
    if not any(d is not ego and d.vehicle.category == "pedestrian" for d in (a, b)):
        return known  # a vehicle's box stops growing at the contact: the detection is not late
    hit = first_contact(a.box_track(), b.box_track(), t_from=t_from)
    if hit is None or hit.time_s > known.time_s - EARLIER_TOUCH_S:
        return known
    if not all(d is ego or seen_at(d, hit.time_s) for d in (a, b)):
        return known
    warnings.append(
        f"the detected crash of {a.id} and {b.id}: their boxes, as seen, touch {known.time_s - hit.time_s:.2f} s "
        "before the detected frame (no camera jolt there); the crash is at that first touch"
    )
    return known.model_copy(update={"time_s": hit.time_s})


def find_first(ego: Dense, agents: list[Dense], t_from: float) -> Collision | None:
    """The first ego-agent box overlap after ``t_from`` (s), as a collision (legacy, no crash known); not of a road
    user inside the ego (:func:`_inside_ego`: the ego's bonnet taken for a car would be the crash)."""
    ego_box = ego.box_track()
    best: tuple[Contact, int] | None = None
    for d in agents:
        if _inside_ego(d, ego, math.inf):
            continue
        hit = first_contact(ego_box, d.box_track(), t_from=t_from)
        if hit is not None and (best is None or hit.time_s < best[0].time_s):
            best = (hit, d.id)
    if best is None:
        return None
    hit, agent_id = best
    return Collision(
        time_s=hit.time_s, agent_id=agent_id, other_id=ego.id, x=hit.x, y=hit.y, relative_speed=hit.relative_speed
    )


GRAZE_M = 0.05
"""A crash correction whose pair touches before the crash (between the samples it was checked on) is made again with
the pair this far apart (m) until shortly before it (``make_contact(apart_margin_m=)``)."""


def _grazes_before(ma: Movable, mb: Movable, corr: Correction, t_before: float) -> bool:
    """Whether the pair, corrected by ``corr``, first touches before ``t_before`` (s), counted as the replay counts it
    (:func:`contact_after_apart`: boxes overlapping from their first common moment only once they were apart)."""
    da, db = (corr.deltas[k] if k < len(corr.deltas) and len(corr.deltas[k]) else 0.0 for k in (0, 1))
    hit = contact_after_apart(box_track(ma, ma.xy + da), box_track(mb, mb.xy + db))
    return hit is not None and hit.time_s < t_before


def _enforce_pair(
    collision: Collision, ego: Dense, agents: list[Dense], cp: ContactParams, warnings: list[str]
) -> dict[str, Any]:
    """Correct the pair's last seconds so they first touch at the collision time; returns the record."""
    byid = {d.id: d for d in [ego, *agents]}
    a, b = byid[collision.other_id], byid[collision.agent_id]
    ma, mb = _movable(a, ego, cp), _movable(b, ego, cp)
    # the ego's measured path is held and only the other road user (monocular depth: metres of error) moved,
    # when that can make the crash: moving both slid a crawling ego sideways across the camera's yaw, and its
    # replay, steering along the path, lagged (dad_000493: 0.2-0.6 m behind in an S-curve, no contact)
    pinned = (a is not ego, b is not ego)
    overlap = cp.penetration_s  # first touch at the collision time, overlapping where the paths end
    corr = make_contact(ma, mb, collision.time_s, cp, movable=pinned, overlap_s=overlap)
    if not corr.ok and not all(pinned):  # the other alone cannot make it: both move (the ego weighted EGO_WEIGHT)
        corr = make_contact(ma, mb, collision.time_s, cp, overlap_s=overlap)
    t_before = collision.time_s - cp.touch_tol_s
    retries = dict.fromkeys((pinned, (True, True)))  # pinned is (True, True) for a pair without the ego: once
    for movable in retries if corr.ok and _grazes_before(ma, mb, corr, t_before) else ():
        again = make_contact(ma, mb, collision.time_s, cp, movable=movable, overlap_s=overlap, apart_margin_m=GRAZE_M)
        if again.ok and not _grazes_before(ma, mb, again, t_before):
            corr = again
            break
    applied = corr.ok or corr.max_m <= MAX_FAILED_CORRECTION_M
    for d, delta in zip((a, b), corr.deltas if applied else [], strict=False):
        if len(delta):
            d.xy = d.xy + delta
            d.observed = d.observed & (np.hypot(*delta.T) < 0.5)  # moved samples are no longer "as observed"
    rec = {
        "pair": [a.id, b.id],
        "max_m": round(corr.max_m, 3),
        "rms_m": round(corr.rms_m, 3),
        "window_s": round(corr.window_s, 2),
        "satisfied": corr.ok,
        "applied": applied,
        "within_kinematics": corr.kinematic,
    }
    if not corr.ok:
        warnings.append(
            f"the crash of {a.id} and {b.id} at {collision.time_s:.2f} s could not be made exact within the "
            f"kinematic limits ({corr.message}); "
            + ("the closest correction is used" if applied else "their paths are left uncorrected")
        )
    elif not corr.kinematic:
        warnings.append(
            f"the crash of {a.id} and {b.id}: no correction within the vehicles' steering limits was found; "
            "the replay may not follow the corrected paths exactly"
        )
    if corr.ok and corr.max_m > cp.large_m:
        warnings.append(
            f"the crash of {a.id} and {b.id}: their last {corr.window_s:.1f} s were moved by up to "
            f"{corr.max_m:.1f} m to make them touch at {collision.time_s:.2f} s (monocular depth error?)"
        )
    return {"correction": rec}


def _separate_others(
    ego: Dense, agents: list[Dense], pair: tuple[int, ...], t_end: float, cp: ContactParams, warnings: list[str]
) -> tuple[list[Dense], list[dict[str, Any]]]:
    """Nudge (or drop) every bystander that touches anyone before ``t_end`` (s); the pair is left alone. A bystander
    inside the ego (:func:`_inside_ego`) is dropped first: nudging a real road user clear of it is impossible."""
    nudges: list[dict[str, Any]] = []
    for d in [d for d in agents if d.id not in pair and _inside_ego(d, ego, t_end)]:
        agents = [a for a in agents if a is not d]
        nudges.append({"agent": d.id, "dropped": True, "inside_ego": True})
        warnings.append(
            f"agent {d.id}: inside the ego's own box most of the time both are in the scenario (the ego's bonnet, "
            "mirror or a reflection taken for a road user?); dropped"
        )
    seen: dict[tuple[bytes, bytes], Contact | None] = {}  # each pair's contact, while neither path changed
    stuck: set[tuple[int, float]] = set()  # (mover, time) of clashes a nudge did not move: not asked again
    for _ in range(2 * len(agents) + 1):
        clash = _first_clash(ego, agents, pair, t_end, cp.near_miss_m, seen, stuck)
        if clash is None:
            break
        mover, hit_time = clash
        others = [d for d in [ego, *agents] if d is not mover]
        if _trim_invented(mover, hit_time, others, cp.clearance_m):
            nudges.append({"agent": mover.id, "trimmed_at_s": round(hit_time, 3), "starts_s": round(mover.t[0], 3)})
            warnings.append(
                f"agent {mover.id}: its extrapolated path touched another road user at {hit_time:.2f} s; it is "
                "in the scenario only from/until 1 s away from there"
            )
            continue
        others_m = [_movable(o, ego, cp) for o in others if not brush_past(mover.vehicle.category, o.vehicle.category)]
        corr = nudge_apart(_movable(mover, ego, cp), others_m, t_end, cp, reach_m=2 * MAX_NUDGE_M)
        if corr.ok and corr.max_m < NO_NUDGE_M:  # kept apart where the nudge looks (the samples): between them
            stuck.add((mover.id, round(hit_time, 3)))
            continue
        if corr.ok and corr.max_m <= MAX_NUDGE_M:
            mover.xy = mover.xy + corr.deltas[0]
            nudges.append({"agent": mover.id, "max_m": round(corr.max_m, 3)})
            warnings.append(
                f"agent {mover.id}: touched another road user at {hit_time:.2f} s before the crash; moved by up to "
                f"{corr.max_m:.1f} m to keep it apart"
            )
        else:
            agents = [d for d in agents if d is not mover]
            nudges.append({"agent": mover.id, "dropped": True})
            warnings.append(
                f"agent {mover.id}: touched another road user at {hit_time:.2f} s before the crash and cannot be "
                "moved apart plausibly; dropped"
            )
    return agents, nudges


NO_NUDGE_M = 1e-3
"""A nudge moving its road user less than this (m) found the pair already apart at the samples it checks (the contact
falls between them); the clash is not asked again (it came back 6 times in a row on ccd_000014 at half its frame
rate, each time a nudge of 0.0 m)."""


INSIDE_EGO_SHARE = 0.5
"""A bystander whose box overlaps the ego's for more than this share of their common time is inside the ego."""


def _inside_ego(d: Dense, ego: Dense, t_end: float) -> bool:
    """Whether ``d``'s box overlaps the ego's for more than ``INSIDE_EGO_SHARE`` of their common time before ``t_end``
    (s), checked every 0.05 s: no road user drives inside the ego; a wide box at the bottom of the picture is the
    ego's own bonnet taken for a car (dad_000512: a "car" 4 m ahead of the standing camera, 0.6 m into the ego,
    through which the stopped SUV ahead of it could not be moved clear of a passing scooter and was dropped)."""
    over = overlap_samples(d.box_track(), ego.box_track(), t_end)
    return bool(len(over) >= 2 and np.mean(over) > INSIDE_EGO_SHARE)


def _pair_contact(a: BoxTrack, b: BoxTrack, a_grown: BoxTrack, b_grown: BoxTrack, near_miss_m: float) -> Contact | None:
    """:func:`_first_clash`'s contact of two road users: of their grown boxes, or of their own where the grown
    ones overlap from the start; their first moment when their own boxes overlap then by less than ``near_miss_m``
    (m): the final paths' smoothing moves each by centimetres, and two boxes a few millimetres into each other
    when both first exist come out apart there and touching a moment later, a contact the simulator counts
    (``bench/fidelity_perturbed.py --variants wiper``, ccd_000031: an oncoming car first seen 2.8 mm into a parked
    one touched it 0.02 s on in the replay, 3 s before the crash)."""
    hits = [contact_after_apart(a_grown, b_grown)]
    if near_miss_m > 0 and _touch_at_start(a_grown, b_grown):
        joining = separation_on_joining(a, b, EPS_T)
        shallow = joining is not None and -near_miss_m < joining[1] <= 0.0
        hits.append(first_contact(a, b) if shallow else contact_after_apart(a, b))  # the first never comes later
    return min((h for h in hits if h is not None), key=lambda h: h.time_s, default=None)


def _box_key(b: BoxTrack) -> bytes:
    """A digest of a box track's contents (times, centres, headings, size)."""
    h = hashlib.blake2b(digest_size=16)
    for arr in (b.t, b.x, b.y, b.yaw, np.array([b.length, b.width])):
        h.update(np.ascontiguousarray(arr, dtype=float).tobytes())
    return h.digest()


def _grown(b: BoxTrack, margin_m: float) -> BoxTrack:
    """``b`` with its box ``margin_m / 2`` (m) larger on every side (two such boxes touch ``margin_m`` apart)."""
    return b if margin_m <= 0 else replace(b, length=b.length + margin_m, width=b.width + margin_m)


def _trim_invented(d: Dense, t_hit: float, others: list[Dense], clearance_m: float, margin_s: float = 1.0) -> bool:
    """A contact in the unobserved part of a track (extrapolated after it was seen, or invented before):
    keep that part only up to ``margin_s`` from the contact; an invented lead-in so trimmed starts where
    ``d`` is at least ``clearance_m`` (m) from every road user of ``others``
    (:func:`~deepcrashtest.trajectory.leadin.clear_start`). False
    when the contact is in the seen part."""
    seen = d.t[d.observed]
    if not len(seen) or d.static:
        return False
    if t_hit > seen[-1] + EPS_T:
        d.keep(d.t <= max(float(seen[-1]), t_hit - margin_s) + EPS_T)
        return True
    if t_hit < seen[0] - EPS_T:
        start = clear_start(d, others, min(float(seen[0]), t_hit + margin_s), float(seen[0]), clearance_m)
        d.keep(d.t >= start - EPS_T)
        return True
    return False


def _reach(d: Dense, t_end: float, fit_s: float = 0.5) -> None:
    """Continue ``d`` (unobserved samples) at its mean velocity of its last ``fit_s`` seconds until
    ``t_end`` (s): a crash participant that left the view (or was lost) just before the crash still
    takes part in it (the simulator removes a vehicle after its last sample)."""
    last = d.t >= d.t[-1] - fit_s
    span_s = float(d.t[-1] - d.t[last][0])
    vel = (d.xy[-1] - d.xy[last][0]) / span_s if span_s > EPS_T and not d.static else np.zeros(2)
    step = float(np.median(np.diff(d.t))) if len(d.t) > 1 else 0.05
    t_new = np.append(np.arange(d.t[-1] + step, t_end - EPS_T, step), t_end)
    d.t = np.concatenate([d.t, t_new])
    d.xy = np.vstack([d.xy, d.xy[-1] + (t_new - d.t[-len(t_new) - 1])[:, None] * vel])
    d.observed = np.concatenate([d.observed, np.zeros(len(t_new), bool)])


def _touch_at_start(a: BoxTrack, b: BoxTrack) -> bool:
    """Whether two boxes touch at the first moment both exist (False when they never coexist)."""
    joining = separation_on_joining(a, b, EPS_T)
    return joining is not None and joining[1] <= 0.0


def contact_after_apart(a: BoxTrack, b: BoxTrack) -> Contact | None:
    """The first contact of two boxes, as the simulator counts it: boxes that overlap from their first
    common moment (label/depth noise) are ignored until they are apart, and a later re-touch counts."""
    hit = first_contact(a, b)
    t0 = max(a.t[0], b.t[0])
    if hit is None or hit.time_s > t0 + EPS_T:
        return hit
    ts = np.unique(np.concatenate([a.t[(a.t >= t0) & (a.t <= b.t[-1])], b.t[(b.t >= t0) & (b.t <= a.t[-1])]]))
    apart = ts[separation(a, b, ts) > 0.0]
    return None if not len(apart) else first_contact(a, b, t_from=float(apart[0]))


def _first_clash(
    ego: Dense,
    agents: list[Dense],
    pair: tuple[int, ...],
    t_end: float,
    near_miss_m: float = 0.0,
    seen: dict[tuple[bytes, bytes], Contact | None] | None = None,
    stuck: set[tuple[int, float]] | None = None,
) -> tuple[Dense, float] | None:
    """The earliest contact before ``t_end`` between two road users that are not both the crash pair
    (nor both parked, nor overlapping from the moment both exist by ``near_miss_m`` or more: the simulator ignores
    those too);
    returns the one to move (an agent outside the pair, the less confident one) and the time; two pedestrians
    brush past (:func:`~deepcrashtest.scenario.brush_past`). Boxes
    closer than ``near_miss_m`` (m) count as touching: a replay tracks each path within decimetres, and
    the paths are checked at their samples only. Two boxes apart by less than ``near_miss_m`` when both first
    exist overlap grown from the start, so that check ignores them: their own boxes are checked too, as the
    simulator does (dad_000487: a cyclist's invented lead-in 0.12 m from a parked car touched it 0.6 s on).
    ``seen``: each pair's contact by the two box tracks' contents, kept between calls (a nudge changes one path:
    the 110 road users of a 200 s clip were checked pair by pair again after each of 33 nudges). ``stuck``: (mover
    id, time rounded to the ms) of clashes not to return again (a nudge found the pair apart at its samples)."""
    every = [ego, *agents]
    own = [d.box_track() for d in every]
    tracks = [_grown(b, near_miss_m) for b in own]
    keys = [_box_key(b) for b in tracks]
    seen = {} if seen is None else seen
    best: tuple[float, Dense] | None = None
    for i in range(len(every)):
        for j in range(i + 1, len(every)):
            a, b = every[i], every[j]
            if (a.id in pair and b.id in pair) or (a.static and b.static):
                continue
            if brush_past(a.vehicle.category, b.vehicle.category):
                continue
            if (keys[i], keys[j]) not in seen:
                seen[keys[i], keys[j]] = _pair_contact(own[i], own[j], tracks[i], tracks[j], near_miss_m)
            hit = seen[keys[i], keys[j]]
            if hit is None or hit.time_s >= t_end:
                continue
            cands = [d for d in (a, b) if d is not ego and d.id not in pair]
            if not cands:
                continue
            invented = [d for d in cands if not seen_at(d, hit.time_s)]  # move an invented path first
            mover = min(invented or cands, key=lambda d: (d.vehicle.confidence or 0.0, len(d.t)))
            if stuck and (mover.id, round(hit.time_s, 3)) in stuck:
                continue
            if best is None or hit.time_s < best[0]:
                best = (hit.time_s, mover)
    return None if best is None else (best[1], best[0])
