"""A moving road user's processed heading where the video saw it: the raw scenario's (fitted to its boxes).

Stage 2's heading of a moving agent is the direction of its fitted path; a monocular path's direction is
range noise for a slow road user and can be tens of degrees off for a moving one, and its projected 3D box
then comes out wider than the detector's box. Stage 1 fits each agent's heading to its image boxes
(:mod:`deepcrashtest.geometry.box_heading`, pulled towards the direction of motion by its speed): over the
observed span that heading is kept; outside it (extrapolation, step-back lead-in) the path's direction, with
a linear blend over ``blend_s``. Times in seconds (scenario time), angles in radians (world frame).
"""

from __future__ import annotations

import math

import numpy as np

from deepcrashtest.scenario import Collision, Vehicle, brush_past, interp_heading, kinematics
from deepcrashtest.trajectory.collision import BoxTrack, Contact, first_contact, overlaps, vehicle_box
from deepcrashtest.trajectory.contact import ContactParams, separation
from deepcrashtest.trajectory.crash import contact_after_apart

BLEND_S = 0.5
"""Seconds over which the observed heading hands over to the path's direction outside the observed span."""


def with_observed_yaw(
    final: Vehicle, raw: dict[str, np.ndarray], t_shift: float, blend_s: float = BLEND_S, turn_limit: bool = True
) -> Vehicle:
    """``final`` (a processed agent) with its heading replaced by ``raw``'s over ``raw``'s span (``raw``: the raw
    agent's trajectory arrays where the video saw it, ``t``, ``yaw``).

    ``t_shift``: scenario time minus the raw scenario's time (s). The raw heading is turned by a half turn
    where it points against the path's direction (a box fits both ways): once for the whole span, where it
    agrees less with the path's direction, weighted by speed (a body does not turn half round between two
    samples while a slow road user's path can reverse), and outside the span towards whichever of the path's
    direction or its reverse is nearer, a vehicle no faster than it can steer for the distance it drives
    (:func:`within_turn_rate`; ``turn_limit=False``: over ``blend_s`` whatever the turn)."""
    a = final.trajectory.arrays()
    r = raw
    if len(r["t"]) < 2 or len(a["t"]) < 2:
        return final
    t_raw = r["t"] + t_shift
    motion = np.unwrap(a["yaw"])
    box = np.interp(a["t"], t_raw, np.unwrap(r["yaw"]))
    outside = np.maximum(t_raw[0] - a["t"], a["t"] - t_raw[-1])
    w = np.clip(1.0 - np.maximum(outside, 0.0) / max(blend_s, 1e-6), 0.0, 1.0)
    inside = outside <= 0.0
    speed = np.abs(a["speed"])
    agree = float(np.sum((speed**2 * np.cos(box - motion))[inside])) if inside.any() else 1.0
    if agree < 0.0:
        box = box + math.pi
    yaw = box + (1.0 - w) * _towards(motion - box, 1.0 - w)
    if turn_limit and inside.any():
        yaw = within_turn_rate(yaw, a["t"], speed, inside, turn_per_m(final))
    traj = final.trajectory.model_copy(update={"yaw": [float(v) for v in yaw]})
    return final.model_copy(update={"trajectory": traj})


def turn_per_m(vehicle: Vehicle) -> float:
    """The most a ``vehicle`` can turn per metre it moves (rad/m): its kinematic bicycle at full lock
    (``tan(max_steer) / wheelbase``); infinite for a road user without a vehicle's kinematics (a pedestrian)."""
    kin = kinematics(vehicle.category)
    if kin.holonomic:
        return math.inf
    return math.tan(kin.max_steer_rad) / (kin.wheelbase_fraction * vehicle.length)


def within_turn_rate(yaw: np.ndarray, t: np.ndarray, speed: np.ndarray, kept: np.ndarray, per_m: float) -> np.ndarray:
    """``yaw`` (rad, unwrapped, at times ``t`` s) kept at the samples ``kept`` and elsewhere turning towards it no
    faster than a vehicle moving at ``speed`` (m/s) can, ``per_m`` rad per metre: forwards from the kept sample before
    and backwards from the one after; between two kept samples the two passes blend by the distance driven (from the
    one to the other). A car cannot turn on the spot: its heading handed over from its boxes to its path's
    direction (the lead-in before the video, the extrapolation after it) turns with the distance it drives, where
    the hand-over over a fixed time spun it (a box heading 73 deg from a noisy lead-in's direction, 0.4 s at 3 m/s)."""
    if not math.isfinite(per_m) or not kept.any() or kept.all():
        return yaw
    n = len(yaw)
    v = np.abs(np.asarray(speed, dtype=float))
    step = per_m * 0.5 * (v[1:] + v[:-1]) * np.diff(t)  # the largest turn between samples k and k + 1 (rad)
    fwd, bwd = np.array(yaw, dtype=float), np.array(yaw, dtype=float)
    has_f, has_b = kept.copy(), kept.copy()
    for k in range(1, n):
        if not kept[k] and has_f[k - 1]:
            fwd[k] = fwd[k - 1] + float(np.clip(yaw[k] - fwd[k - 1], -step[k - 1], step[k - 1]))
            has_f[k] = True
    for k in range(n - 2, -1, -1):
        if not kept[k] and has_b[k + 1]:
            bwd[k] = bwd[k + 1] + float(np.clip(yaw[k] - bwd[k + 1], -step[k], step[k]))
            has_b[k] = True
    dist = np.concatenate([[0.0], np.cumsum(v[1:] * np.diff(t))])
    left = np.maximum.accumulate(np.where(kept, np.arange(n), -1))
    right = np.minimum.accumulate(np.where(kept, np.arange(n), n)[::-1])[::-1]
    out = np.where(has_f, fwd, bwd)
    gap = ~kept & has_f & has_b
    if gap.any():
        lo, hi = dist[left[gap]], dist[np.minimum(right[gap], n - 1)]
        share = np.clip((dist[gap] - lo) / np.maximum(hi - lo, 1e-9), 0.0, 1.0)
        out[gap] = (1.0 - share) * fwd[gap] + share * bwd[gap]
    return out


def turned_no_closer(turned: Vehicle, plain: Vehicle, others: list[Vehicle], clearance_m: float) -> Vehicle:
    """``turned`` (a vehicle whose heading turns within its steering limit where the video did not see it:
    :func:`with_observed_yaw`, :func:`_path_heading_within`), or ``plain`` (the same hand-over over a fixed time)
    where the limited heading brings its box nearer than ``clearance_m`` (m) to a road user of ``others`` at a
    moment the two differ, and nearer than ``plain``'s: stage 2 keeps bystanders that far apart, and trims a lead-in
    to start that far from everyone, with the path's direction (ccd_000882: a parked car's lead-in held at its
    boxes' heading started 1 cm into its neighbour, which the replay ignores only until they part)."""
    ta, pa = turned.trajectory.arrays(), plain.trajectory.arrays()
    differ = np.abs(ta["yaw"] - pa["yaw"]) > 1e-9
    if not differ.any():
        return turned
    t = ta["t"][differ]
    bt, bp = vehicle_box(turned), vehicle_box(plain)
    for other in others:
        if other.id == turned.id or brush_past(turned.category, other.category):
            continue
        bo = vehicle_box(other)
        at = t[(t >= bo.t[0]) & (t <= bo.t[-1])]
        if len(at) and np.any(separation(bt, bo, at) < np.minimum(separation(bp, bo, at), clearance_m) - 1e-6):
            return plain
    return turned


REPLAY_TOUCH_TOL_S = 0.1
"""The crash pair's boxes, facing as the scenario says, must first touch at most this before the crash (s) ..."""
LATE_TOUCH_S = 0.05
"""... and no later than this after it (s): the paths end ``ContactParams.penetration_s`` (0.1 s) after the crash, so a
pair whose boxes first touch 0.1 s late touches at the paths' very end and the replay, lagging a little, misses it
(dad_000493 re-encoded: a scooter facing its boxes touched the ego 0.098 s late, no contact in the replay). Chosen on
the 20 fidelity clips and their re-encoded copies (``bench/fidelity_perturbed.py``): 0.02 s also brought both back
but turned ccd_000014's and ccd_000487's crash pairs along their paths (mean IoU 0.653 -> 0.648); 0.05 s kept the
20 clips' scenarios as they were."""
GRAZE_MARGIN_M = 0.05
"""Boxes are checked this much larger (m, each side) for contacts outside the crash pair: the simulator checks
every 0.02 s, the scenario's samples are 0.05-0.1 s apart (dad_000487: a bicycle's box facing its boxes grazed a
pedestrian's 1 cm deep between two samples, a contact before the crash in the replay)."""


def replayable_yaws(
    observed: list[Vehicle], path: list[Vehicle], collision: Collision | None, warnings: list[str]
) -> list[Vehicle]:
    """``observed`` (the processed vehicles, ego first, moving agents facing their boxes: :func:`with_observed_yaw`)
    with ``path``'s heading (the same vehicles facing along their paths, the boxes stage 2 made the crash with)
    put back where an agent's box heading changes the scenario's contacts: the crash pair no longer first
    touching within ``REPLAY_TOUCH_TOL_S`` of ``collision`` (scenario time), or another pair touching before
    it. Put back within ``REVERT_WINDOW_S`` of that contact (from there on for the pair), blended over
    ``BLEND_S``; over the whole track when that does not help. The replay takes each agent's heading from the
    scenario (``sim.world``), so the scenario's contacts are the replay's."""
    by_path = {v.id: v for v in path}
    changed = {v.id for v, p in zip(observed, path, strict=True) if v is not p}
    spans: dict[int, list[tuple[float, float]]] = {}
    kept = list(observed)
    for _ in range(4 * len(changed) + 1):
        broken = _broken_contact(kept, collision, changed)
        if broken is None:
            break
        ids, t_hit, lo, hi = broken
        for i in ids:
            own = spans.setdefault(i, [])
            if any(a <= t_hit <= b for a, b in own):  # facing its path there did not help: along it throughout
                own[:] = [(-math.inf, math.inf)]
                changed.discard(i)
            else:
                own.append((lo, hi))
        kept = _kept_apart(observed, by_path, spans, set(collision.participants) if collision is not None else set())
    if spans:
        warnings.append(
            f"agent(s) {sorted(spans)}: face along their paths, not their boxes, near a contact that their boxes' "
            "heading would change (the replay must touch as the crash does)"
        )
    return kept


def holding_yaws_after(vehicles: list[Vehicle], collision: Collision | None) -> list[Vehicle]:
    """``vehicles`` with the crash participants other than the ego facing, once their boxes touch (the crash time or
    the scenario's first contact of the pair, whichever is later), as they faced then, where that keeps their boxes
    overlapping longer after it: their paths go on past the contact only so that a replay lagging them still
    touches (``ContactParams.penetration_s``), and a heading that turns away there can take the box off the contact
    between the replay's steps. Zoomed ccd_001143: the bus, facing along its slow path at the crash (-354 deg),
    faced its box (-274 deg) 0.1 s later; the two touched at one instant, the replay 0.005 s later had turned the
    bus 4 deg and its rear corner missed the ego by 0.1 m. A heading that turns into the other road user (a car
    grazing a pedestrian, KITTI 0002) is kept."""
    if collision is None:
        return vehicles
    by_id = {v.id: v for v in vehicles}
    if not all(i in by_id for i in collision.participants):
        return vehicles
    a, b = (by_id[i] for i in collision.participants)
    hit = first_contact(vehicle_box(a), vehicle_box(b))
    t_hold = collision.time_s if hit is None else max(collision.time_s, hit.time_s)
    held = {i: _holding_yaw(by_id[i], t_hold) if i != 0 else by_id[i] for i in collision.participants}
    if _overlap_after(held[a.id], held[b.id], t_hold) <= _overlap_after(a, b, t_hold):
        return vehicles
    return [held.get(v.id, v) for v in vehicles]


def _overlap_after(a: Vehicle, b: Vehicle, t0: float) -> int:
    """How many of the 0.01 s steps after ``t0`` (s) to the end of the shorter path have the two boxes overlapping."""
    ba, bb = vehicle_box(a), vehicle_box(b)
    t = np.arange(t0 + 0.01, min(ba.t[-1], bb.t[-1]) + 1e-9, 0.01)
    return int(overlaps(ba, bb, t).sum()) if len(t) else 0


def _holding_yaw(vehicle: Vehicle, t_hold: float) -> Vehicle:
    """``vehicle`` facing after ``t_hold`` (s) as it faced at it."""
    a = vehicle.trajectory.arrays()
    after = a["t"] > t_hold
    if not after.any() or not (a["t"] <= t_hold).any():
        return vehicle
    yaw = np.unwrap(np.asarray(a["yaw"], dtype=float))
    yaw[after] = float(interp_heading(np.array([t_hold]), a["t"], a["yaw"])[0])
    traj = vehicle.trajectory.model_copy(update={"yaw": [float(v) for v in np.unwrap(yaw)]})
    return vehicle.model_copy(update={"trajectory": traj})


REVERT_WINDOW_S = 0.0
"""Seconds either side of a contact within which an agent faces along its path (:func:`replayable_yaws`), then
``BLEND_S`` back to its boxes. Chosen on the 20 fidelity clips (DAD, CCD, highway; stage 2 rerun on one extract):
1.0 / 0.5 / 0.0 s gave mean reprojection IoU processed 0.622 / 0.630 / 0.635, replay 0.593 / 0.602 / 0.606 (the
crash pairs of ccd_000014/132/721 face their boxes longer), all 18 crashes reproduced each time."""


def _kept_apart(
    observed: list[Vehicle],
    by_path: dict[int, Vehicle],
    spans: dict[int, list[tuple[float, float]]],
    pair: set[int],
) -> list[Vehicle]:
    """``observed`` with each vehicle of ``spans`` facing its path within them (:func:`_path_heading_within`), turning
    to it no faster than it can steer unless that brings it nearer a road user other than its crash partner (``pair``:
    the collision's participants) than the bystander clearance (:func:`turned_no_closer`; ccd_001143's bus, turning
    over the unseen gap before its contact, swept 0.95 s through a car beside it)."""
    plain = [_path_heading_within(v, by_path[v.id], spans[v.id], False) if v.id in spans else v for v in observed]
    clearance = ContactParams().clearance_m
    out = []
    for v, p in zip(observed, plain, strict=True):
        if v.id not in spans:
            out.append(v)
            continue
        others = [o for o in plain if not (v.id in pair and o.id in pair)]
        out.append(turned_no_closer(_path_heading_within(v, by_path[v.id], spans[v.id]), p, others, clearance))
    return out


def _path_heading_within(
    observed: Vehicle, path: Vehicle, spans: list[tuple[float, float]], turn_limit: bool = True
) -> Vehicle:
    """``observed`` facing as ``path`` (or half round from it: the same box) within the time ``spans`` (s), blended
    over ``BLEND_S`` outside them; where the video did not see it, a vehicle turns between its boxes' heading and
    the path's no faster than it can steer (:func:`within_turn_rate`, the seen samples and the spans kept): a crash
    car whose boxes faced 75 deg off its path turned to it in the 0.4 s before the contact (ccd_000053);
    ``turn_limit=False``: over ``BLEND_S`` whatever the turn."""
    o, p = observed.trajectory.arrays(), path.trajectory.arrays()
    t = o["t"]
    w = np.zeros(len(t))
    for lo, hi in spans:
        out = np.maximum(np.maximum(lo - t, t - hi), 0.0)
        w = np.maximum(w, np.clip(1.0 - out / BLEND_S, 0.0, 1.0))
    yaw = np.unwrap(o["yaw"]) + w * _towards(np.unwrap(p["yaw"]) - np.unwrap(o["yaw"]), w)
    along = w >= 1.0 - 1e-9
    seen = np.ones(len(t), bool) if observed.trajectory.observed is None else np.asarray(observed.trajectory.observed)
    if turn_limit and along.any():
        yaw = within_turn_rate(yaw, t, np.abs(o["speed"]), along | seen, turn_per_m(observed))
    traj = observed.trajectory.model_copy(update={"yaw": [float(v) for v in yaw]})
    return observed.model_copy(update={"trajectory": traj})


def _towards(diff: np.ndarray, weight: np.ndarray) -> np.ndarray:
    """The turn (rad, per sample) from a heading to a target ``diff`` away from it that is handed over with
    ``weight`` (0 = the heading, 1 = the target), the target taken half round where that turns less (a box fits
    both ways), chosen once per stretch of ``weight > 0`` and kept so along it: a target that crosses a right
    angle to the heading must not flip a per-sample choice half round between two samples (a road user turned by
    its extrapolated path away from its held box heading). The choice is the one that turns the body less over
    the stretch's hand-over (``0 < weight < 1``, weighted), not at its first sample alone: a box near a right
    angle to its path there took the path's reverse, then turned 140 deg back to its box where the hand-over
    ended (ccd_000031 letterboxed: 222 -> 318 -> 180 deg beside a path of 135-180 deg)."""
    near = (diff + 0.5 * math.pi) % math.pi - 0.5 * math.pi
    cont = np.unwrap(near, period=math.pi)
    out = np.empty_like(near)
    anchor = weight <= 0.0
    bounds = np.flatnonzero(np.diff(anchor.astype(np.int8))) + 1
    for run in np.split(np.arange(len(diff)), bounds):
        if not len(run):
            continue
        edge = run[-1] if run[0] == 0 and len(run) < len(diff) else run[0]  # the sample next to an anchor
        k = round(float(cont[edge] - near[edge]) / math.pi)
        w = weight[run]
        handover = (w > 0.0) & (w < 1.0)
        if not handover.any():
            out[run] = cont[run] - math.pi * k
            continue
        options = [cont[run] - math.pi * m for m in (k, k - 1, k + 1)]
        out[run] = min(options, key=lambda turn: float(np.sum((w * np.abs(turn))[handover])))
    return out


def _broken_contact(
    vehicles: list[Vehicle], collision: Collision | None, changed: set[int]
) -> tuple[set[int], float, float, float] | None:
    """The ids among ``changed`` of a pair whose contact differs from the crash (see :func:`replayable_yaws`),
    the contact's time and the span (s) to face along the path; None when no pair's does."""
    pair = set(collision.participants) if collision is not None else set()
    if collision is not None and pair & changed:
        a, b = (next(v for v in vehicles if v.id == i) for i in collision.participants)
        hit = first_contact(vehicle_box(a), vehicle_box(b))
        late = hit is not None and hit.time_s > collision.time_s + LATE_TOUCH_S
        if hit is None or late or collision.time_s - hit.time_s > REPLAY_TOUCH_TOL_S:
            t_hit = collision.time_s if hit is None else min(hit.time_s, collision.time_s)
            return pair & changed, t_hit, t_hit - REVERT_WINDOW_S, math.inf
    t_end = collision.time_s if collision is not None else math.inf  # the pair may touch that late: none before
    grazing = [vehicle_box(v, GRAZE_MARGIN_M) for v in vehicles]
    boxes = [vehicle_box(v) for v in vehicles]
    for i, vi in enumerate(vehicles):
        for j in range(i + 1, len(vehicles)):
            ids = {vi.id, vehicles[j].id}
            if ids <= pair or not ids & changed or brush_past(vi.category, vehicles[j].category):
                continue
            hit = _replay_contact((grazing[i], grazing[j]), (boxes[i], boxes[j]))
            if hit is not None and hit.time_s < t_end:
                movers = ids & changed
                unseen = {k for k in movers if not _seen(vi if k == vi.id else vehicles[j], hit.time_s)}
                return unseen or movers, hit.time_s, hit.time_s - REVERT_WINDOW_S, hit.time_s + REVERT_WINDOW_S
    return None


def _replay_contact(grazing: tuple[BoxTrack, BoxTrack], boxes: tuple[BoxTrack, BoxTrack]) -> Contact | None:
    """The first contact of a pair as the replay counts it (:func:`contact_after_apart`), seen on its boxes
    ``GRAZE_MARGIN_M`` larger (a graze between the simulator's steps) or on its own boxes, whichever comes first.

    Boxes that overlap from their first common moment are ignored until they are apart; that holds for the
    larger boxes only where the real ones overlap too: an agent that appears 5 cm from a parked car and touches it
    0.03 s later (ccd_000031 letterboxed: agent 4 and parked car 3) overlaps it from the start with the margin,
    so that contact was missed and the replay counted it."""
    hits = [h for h in (contact_after_apart(*grazing), contact_after_apart(*boxes)) if h is not None]
    return min(hits, key=lambda h: h.time_s) if hits else None


def _seen(v: Vehicle, t: float) -> bool:
    """Whether ``v``'s sample nearest to ``t`` (s) was observed (not extrapolated or invented): turning its box
    there costs nothing the video shows."""
    obs = v.trajectory.observed
    if obs is None:
        return True
    k = int(np.argmin(np.abs(np.asarray(v.trajectory.t) - t)))
    return bool(obs[k])
