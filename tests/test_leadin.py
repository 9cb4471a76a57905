"""A processed scenario starts with no two road users in one place: stage 2 trims an invented lead-in that runs
through another road user (``trajectory.leadin``), and the crash correction then finds its crash."""

from __future__ import annotations

import numpy as np
import pytest

from deepcrashtest.scenario import Collision, Scenario
from deepcrashtest.trajectory.collision import first_contact, vehicle_box
from deepcrashtest.trajectory.contact import separation
from deepcrashtest.trajectory.pipeline import process_scenario
from trajectory_cases import raw_scenario, track, vehicle

# A rear-end like ccd_000330 filmed through a longer lens: the car ahead first seen 1.05 m from the ego's bumper
# (centres 5.5 m apart, boxes 4.5 and 4.4 m long) and 0.5 m/s faster; from 2 s it slows and the ego speeds up,
# and their boxes touch at 3.85 s. An oncoming car at 12 m/s makes the step-back 4 s long: from rest, the faster car
# ahead steps back 1.63 m farther than the ego and its lead-in starts 0.58 m inside it.
CRASH_S = 3.85


def _ego_x(t: np.ndarray) -> np.ndarray:
    u = np.maximum(t - 2.0, 0.0)
    return 2.0 * t + 0.75 * u**2


def _car_x(t: np.ndarray, gap_m: float = 5.5) -> np.ndarray:
    u = np.maximum(t - 2.0, 0.0)
    return gap_m + 2.5 * t - 0.25 * u**2


def _raw(gap_m: float = 5.5) -> Scenario:
    ego = track(lambda t: (_ego_x(t), 0.0 * t), 0, 40)
    ahead = vehicle(1, track(lambda t: (_car_x(t, gap_m), 0.0 * t), 0, 40), length=4.4, width=1.8)
    oncoming = vehicle(2, track(lambda t: (80.0 - 12.0 * t, 3.5 + 0.0 * t), 0, 40), length=4.4, width=1.8)
    crash = Collision(time_s=CRASH_S, agent_id=1, other_id=0, source="video-auto")
    return raw_scenario([ahead, oncoming], ego=ego, collision=crash)


def _overlaps_at_start(sc: Scenario) -> list[tuple[int, int, float]]:
    """Pairs whose boxes overlap at the first moment both exist (id, id, separation m)."""
    vs = list(sc.vehicles())
    out = []
    for i in range(len(vs)):
        for j in range(i + 1, len(vs)):
            a, b = vehicle_box(vs[i]), vehicle_box(vs[j])
            t0 = max(a.t[0], b.t[0])
            if t0 <= min(a.t[-1], b.t[-1]):
                sep = float(separation(a, b, np.array([t0]))[0])
                if sep < 0.0:
                    out.append((vs[i].id, vs[j].id, sep))
    return out


def test_a_lead_in_that_starts_inside_the_road_user_behind_it_leaves_rest_gentler():
    """Before: both started at 0 s from rest 0.58 m into each other (a spawn collision in any simulator that checks)
    and the crash correction, asked to keep them apart from 0 s where it cannot move them, failed and left the pair
    overlapping 0.4 s before their crash. Now the car ahead leaves rest at a gentler acceleration (starting nearer
    where the video first sees it), is in the scenario from the start as before, and the pair first touches at the
    crash."""
    sc = process_scenario(_raw())
    assert _overlaps_at_start(sc) == []
    car = next(v for v in sc.agents if v.id == 1)
    assert car.trajectory.t[0] == 0.0 and car.trajectory.speed[0] < 0.1  # from rest at the start, as before
    (change,) = sc.provenance.parameters["crash"]["lead_ins"]
    assert change["agent"] == 1 and 0.0 < change["accel_mps2"] < 3.0
    assert any("lead-in" in w and "agent 1" in w for w in sc.warnings)
    assert sc.provenance.parameters["crash"]["correction"]["satisfied"] is True
    assert sc.collision is not None
    hit = first_contact(vehicle_box(sc.ego), vehicle_box(car))  # counted from 0 s: no overlap at the start either
    assert hit is not None and abs(hit.time_s - sc.collision.time_s) <= 0.1


def test_a_lead_in_through_a_standing_pedestrian_is_trimmed():
    """A car first seen at 8 m/s, 15 m past a pedestrian who stands on its lane all along: its lead-in from rest runs
    back through her, whatever its acceleration. It joins the scenario once past her, clear of everyone."""
    car = vehicle(1, track(lambda t: (20.0 + 8.0 * t, -3.5 + 0.0 * t), 0, 40), length=4.4, width=1.8)
    person = vehicle(3, track(lambda t: (5.0 + 0.0 * t, -3.5 + 0.0 * t), 0, 40), category="pedestrian",
                     length=0.6, width=0.6, height=1.7)  # fmt: skip
    sc = process_scenario(raw_scenario([car, person], ego=track(lambda t: (10.0 * t, 0.0 * t), 0, 40)))
    car_out = next(v for v in sc.agents if v.id == 1)
    person_out = next(v for v in sc.agents if v.id == 3)
    assert car_out.trajectory.t[0] > 0.0  # trimmed: joins later
    assert first_contact(vehicle_box(car_out), vehicle_box(person_out)) is None
    (change,) = sc.provenance.parameters["crash"]["lead_ins"]
    assert change["agent"] == 1 and change["to_s"] == pytest.approx(car_out.trajectory.t[0], abs=1e-3)
    assert _overlaps_at_start(sc) == []


def test_lead_ins_that_keep_apart_are_left_whole():
    """The same scene with the car ahead 3 m farther: its lead-in never reaches the ego and nothing is trimmed."""
    raw = _raw(gap_m=8.5)
    sc = process_scenario(raw.evolve(collision=None))
    assert _overlaps_at_start(sc) == []
    assert all(v.trajectory.t[0] == 0.0 for v in sc.vehicles())
    assert not any("lead-in" in w for w in sc.warnings)


def test_a_track_continued_after_it_was_lost_ends_where_its_next_track_appears():
    """The car ahead tracked 0-2 s (id 1), lost, and tracked again 3-5 s under a new id (3): stage 2 continues track 1
    after the video lost it, through the place where track 3 then appears (a road user appearing inside another: a
    collision in a user's simulator, ignored by ours). Now the continuation ends where track 3 appears."""

    def car(t: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        return 20.0 + 8.0 * t, -3.5 + 0.0 * t

    first = vehicle(1, track(car, 0, 20), length=4.4, width=1.8)
    again = vehicle(3, track(car, 30, 50), length=4.4, width=1.8)
    sc = process_scenario(raw_scenario([first, again], ego=track(lambda t: (10.0 * t, 0.0 * t), 0, 50)))
    lost, found = (next(v for v in sc.agents if v.id == i) for i in (1, 3))
    assert lost.trajectory.t[-1] < found.trajectory.t[0]  # it ended before the new track appears (was: 2 s later)
    assert sum(lost.trajectory.observed) == 21  # the part the video saw is whole
    assert _overlaps_at_start(sc) == []
    (change,) = sc.provenance.parameters["crash"]["lead_ins"]
    assert change == {"agent": 1, "until_s": pytest.approx(lost.trajectory.t[-1], abs=1e-3)}
