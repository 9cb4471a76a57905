"""Whether a scenario's vehicles move as vehicles can: the physical side of its fidelity to the video.

A scenario can reproduce its video's boxes and crash while its road users do what no vehicle does: turn half
round between two samples (a box fits both ways round), turn faster than their steering allows at their speed,
or slide sideways (a heading far off the direction of motion). A replay or an exported OpenSCENARIO shows all
three. Counted over every vehicle's samples the video saw (``Trajectory.observed``; pedestrians, who step
sideways and turn on the spot, are left out), with the simulator's kinematic bicycle
(:data:`deepcrashtest.scenario.VEHICLE_KINEMATICS`). And two road users can pass through each other
(:func:`overlapping_pairs`: a monocular depth error, or one road user tracked twice), which the simulator ignores
while they overlap from their first common moment and counts as a crash once they part and touch again; and two can
start (or one appear) inside the other (:func:`joining_overlaps`), a collision at spawn in a user's simulator. Times in
seconds, angles in radians (world frame), speeds in m/s.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np

from deepcrashtest.scenario import Scenario, Vehicle, brush_past, kinematics
from deepcrashtest.trajectory.collision import vehicle_box
from deepcrashtest.trajectory.contact import overlap_samples, separation_on_joining
from deepcrashtest.trajectory.traction import beyond_traction

#: A heading change between two samples larger than this (rad) is a half turn, not a turn.
HALF_TURN_RAD = 0.5 * math.pi
#: Speed (m/s) added to a vehicle's own before its turning limit is applied: a track's speed is that uncertain.
TURN_SPEED_MARGIN_MPS = 1.0
#: Speed (m/s) from which a heading off the direction of motion counts as sliding ...
SLIDE_MIN_SPEED_MPS = 3.0
#: ... when it is more than this off it (deg, rad), or off its reverse (reversing is allowed).
SLIDE_MAX_DEG = 20.0
SLIDE_MAX_RAD = math.radians(SLIDE_MAX_DEG)
#: Two road users whose boxes overlap at least this long (s) before the crash pass through each other ...
OVERLAP_MIN_S = 0.3
#: ... checked every this many seconds.
OVERLAP_STEP_S = 0.05


#: The per-vehicle counts (:func:`vehicle_plausibility`) a scenario's are summed over.
COUNTS = (
    "steps",
    "half_turns",
    "over_turning",
    "over_traction",
    "moving",
    "sliding",
    "unseen_steps",
    "unseen_over_turning",
)


def vehicle_plausibility(vehicle: Vehicle) -> dict[str, int]:
    """Counts for one vehicle over its observed samples: ``steps`` (consecutive observed pairs), ``half_turns``
    and ``over_turning`` among them (heading change above ``dt (v + TURN_SPEED_MARGIN_MPS) tan(max_steer) /
    wheelbase`` at the pair's mean speed, half turns included), ``over_traction`` among them (the speed changes
    faster than ``max_accel_mps2`` up or ``max_brake_mps2`` down), ``moving`` samples (speed of the path >=
    ``SLIDE_MIN_SPEED_MPS``) and ``sliding`` among them; and ``unseen_steps`` (pairs with a sample the video did not
    see: the lead-in before the video, the extrapolation after it) with ``unseen_over_turning`` among them, the
    same turning limit (a replay and an export show those samples too)."""
    a = vehicle.trajectory.arrays()
    t, yaw = a["t"], np.unwrap(a["yaw"])
    seen = np.ones(len(t), bool) if vehicle.trajectory.observed is None else np.asarray(vehicle.trajectory.observed)
    out = dict.fromkeys(COUNTS, 0)
    if len(t) < 3:
        return out
    kin = kinematics(vehicle.category)
    pair = seen[1:] & seen[:-1] & (np.diff(t) > 0)
    turn = np.abs(np.diff(yaw))
    speed = 0.5 * (np.abs(a["speed"][1:]) + np.abs(a["speed"][:-1])) + TURN_SPEED_MARGIN_MPS
    limit = np.diff(t) * speed * math.tan(kin.max_steer_rad) / (kin.wheelbase_fraction * vehicle.length)
    vx, vy = np.gradient(a["x"], t), np.gradient(a["y"], t)
    moving = seen & (np.hypot(vx, vy) >= SLIDE_MIN_SPEED_MPS)
    off = np.abs((np.arctan2(vy, vx) - yaw + 0.5 * math.pi) % math.pi - 0.5 * math.pi)
    out["steps"] = int(pair.sum())
    out["half_turns"] = int((pair & (turn > HALF_TURN_RAD)).sum())
    out["over_turning"] = int((pair & (turn > limit)).sum())
    out["over_traction"] = int((pair & beyond_traction(t, a["speed"], kin)).sum())
    out["moving"] = int(moving.sum())
    out["sliding"] = int((moving & (off > SLIDE_MAX_RAD)).sum())
    unseen = ~(seen[1:] & seen[:-1]) & (np.diff(t) > 0)
    out["unseen_steps"] = int(unseen.sum())
    out["unseen_over_turning"] = int((unseen & (turn > limit)).sum())
    return out


#: A vehicle whose heading turns more than this (deg) beyond what its steering allows for the distance it drives,
#: over any stretch of its samples (seen or not), spins (:func:`excess_turn_deg`).
SPIN_DEG = 20.0


def excess_turn_deg(vehicle: Vehicle) -> float:
    """The most a vehicle's heading turns (deg) beyond ``tan(max_steer) / wheelbase`` x the distance it drives, over
    any stretch between two of its samples: 0 for a car that turns as it can, ~70 for a box heading handed over to a
    path's direction 70 deg away within a few decimetres. 0 for a road user without a vehicle's kinematics."""
    kin = kinematics(vehicle.category)
    a = vehicle.trajectory.arrays()
    if kin.holonomic or len(a["t"]) < 2:
        return 0.0
    per_m = math.tan(kin.max_steer_rad) / (kin.wheelbase_fraction * vehicle.length)
    yaw = np.unwrap(a["yaw"])
    dist = np.concatenate([[0.0], np.cumsum(np.hypot(np.diff(a["x"]), np.diff(a["y"])))])
    excess = np.abs(yaw[None, :] - yaw[:, None]) - per_m * np.abs(dist[None, :] - dist[:, None])
    return math.degrees(max(0.0, float(excess.max())))


def per_vehicle(scenario: Scenario) -> list[tuple[Vehicle, dict[str, int]]]:
    """:func:`vehicle_plausibility` of each of the scenario's vehicles (the ego and the agents that are not
    pedestrians), in the scenario's order."""
    return [(v, vehicle_plausibility(v)) for v in scenario.vehicles() if not kinematics(v.category).holonomic]


def overlapping_pairs(scenario: Scenario) -> list[tuple[int, int, float]]:
    """(id, id, seconds) for each pair of road users, the crash pair left out, whose boxes overlap for at least
    ``OVERLAP_MIN_S`` (sampled every ``OVERLAP_STEP_S``) while both are in the scenario, before its collision (or its
    end): one passes through the other. Ids in the scenario's order."""
    users = [scenario.ego, *scenario.agents]
    crash = set(scenario.collision.participants) if scenario.collision is not None else set()
    t_stop = scenario.collision.time_s if scenario.collision is not None else math.inf
    boxes = [vehicle_box(u) for u in users]
    out = []
    for i in range(len(users)):
        for j in range(i + 1, len(users)):
            if {users[i].id, users[j].id} == crash and len(crash) == 2 or _brush(users[i], users[j]):
                continue
            seconds = float(np.sum(overlap_samples(boxes[i], boxes[j], t_stop, OVERLAP_STEP_S))) * OVERLAP_STEP_S
            if seconds >= OVERLAP_MIN_S - 1e-9:
                out.append((users[i].id, users[j].id, round(seconds, 2)))
    return out


def _brush(a: Vehicle, b: Vehicle) -> bool:
    """Two road users that pass each other without a collision (two pedestrians: :func:`scenario.brush_past`)."""
    return brush_past(a.category, b.category)


def joining_overlaps(scenario: Scenario) -> list[tuple[int, int, float, float]]:
    """(id, id, time s, overlap m) for each pair of road users whose boxes overlap at the first moment both are in the
    scenario (before its collision, or its end): a user's simulator spawns them (or the later one) inside each other,
    a collision at that moment, which this project's simulator ignores until they part. Ids in the scenario's order."""
    users = [scenario.ego, *scenario.agents]
    t_stop = scenario.collision.time_s if scenario.collision is not None else math.inf
    boxes = [vehicle_box(u) for u in users]
    out = []
    for i in range(len(users)):
        for j in range(i + 1, len(users)):
            if _brush(users[i], users[j]):
                continue
            joining = separation_on_joining(boxes[i], boxes[j])
            if joining is not None and joining[0] <= t_stop and joining[1] < 0.0:
                out.append((users[i].id, users[j].id, round(joining[0], 3), round(-joining[1], 3)))
    return out


def plausibility(scenario: Scenario, rows: list[tuple[Vehicle, dict[str, int]]] | None = None) -> dict[str, Any]:
    """The scenario's vehicles' counts (``rows``: :func:`per_vehicle`'s, computed when not given) summed, with the
    shares ``over_turning_share`` (of steps), ``sliding_share`` (of moving samples) and ``vehicles_with_half_turns``,
    and the road users passing through each other (``overlapping_pairs``: :func:`overlapping_pairs`)."""
    rows = per_vehicle(scenario) if rows is None else rows
    total = {k: sum(r[k] for _, r in rows) for k in COUNTS}
    return total | {
        "overlapping_pairs": [list(p) for p in overlapping_pairs(scenario)],
        "overlapping_on_joining": [list(p) for p in joining_overlaps(scenario)],
        "vehicles": len(rows),
        "vehicles_with_half_turns": sorted(v.id for v, r in rows if r["half_turns"]),
        "vehicles_spinning": sorted(v.id for v, _ in rows if excess_turn_deg(v) > SPIN_DEG),
        "over_turning_share": round(total["over_turning"] / total["steps"], 4) if total["steps"] else None,
        "over_traction_share": round(total["over_traction"] / total["steps"], 4) if total["steps"] else None,
        "sliding_share": round(total["sliding"] / total["moving"], 4) if total["moving"] else None,
        "unseen_over_turning_share": (
            round(total["unseen_over_turning"] / total["unseen_steps"], 4) if total["unseen_steps"] else None
        ),
        "rule": (
            f"vehicles' observed samples (unseen over turning: their other samples); over turning: heading "
            f"change > dt (v + {TURN_SPEED_MARGIN_MPS:g} m/s) tan(max steer) / wheelbase; over traction: speed "
            "change between two samples faster than the vehicle's acceleration or braking; sliding: speed >= "
            f"{SLIDE_MIN_SPEED_MPS:g} m/s and heading > {SLIDE_MAX_DEG:g} deg off the direction of motion (or its "
            f"reverse); spinning: a heading turning > {SPIN_DEG:g} deg beyond the steering limit over the distance "
            f"driven, anywhere on the track; overlapping pairs: road users' boxes overlapping >= {OVERLAP_MIN_S:g} s "
            "before the crash (the crash pair left out); overlapping on joining: two road users' boxes overlapping "
            "at the first moment both are in the scenario, before the crash (a spawn inside each other)"
        ),
    }
