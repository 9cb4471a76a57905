"""A box read the other way round between two samples flips instead of spinning through its neighbours, and
bystanders that pass closer than the replay tracks its paths are moved apart before the crash (stage 2)."""

from __future__ import annotations

import math

import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st

from deepcrashtest.scenario import Scenario, interp_heading
from deepcrashtest.sim import simulate
from deepcrashtest.trajectory.collision import vehicle_box
from deepcrashtest.trajectory.contact import separation
from deepcrashtest.trajectory.pipeline import process_scenario
from trajectory_cases import raw_scenario, track, vehicle


@settings(max_examples=50, deadline=None)
@given(st.lists(st.floats(-0.7, 0.7), min_size=2, max_size=30), st.floats(-10.0, 10.0))
def test_headings_without_a_quarter_turn_between_samples_interpolate_as_before(steps, start):
    yaw = start + np.cumsum(steps)
    t = np.arange(len(yaw)) * 0.1
    tq = np.linspace(-0.1, t[-1] + 0.1, 97)
    assert np.array_equal(interp_heading(tq, t, yaw), np.interp(tq, t, np.unwrap(yaw)))


def test_a_half_turn_between_two_samples_flips_the_box_at_once():
    t = np.array([0.0, 0.05, 0.10, 0.15])
    yaw = np.array([-0.61, -0.61, -0.61 - math.pi, -0.61 - math.pi])  # the same box, read the other way round
    tq = np.linspace(0.0, 0.15, 31)
    out = interp_heading(tq, t, yaw)
    axis = np.mod(out + 0.61, math.pi)  # the box's axis: unchanged throughout
    assert np.allclose(np.minimum(axis, math.pi - axis), 0.0, atol=1e-12)
    assert out[0] == -0.61 and out[-1] == -0.61 - math.pi
    assert np.count_nonzero(np.diff(out)) == 1  # one step, at the midpoint
    assert np.isclose(tq[np.argmax(np.diff(out) != 0) + 1], 0.075, atol=0.006)


def _processed(raw: Scenario) -> Scenario:
    return raw.evolve(stage="processed")


def test_a_standing_car_read_the_other_way_round_does_not_hit_its_neighbour_in_the_replay():
    """A car standing 0.3 m beside a parked one whose heading is read the other way round from one frame to the
    next (a monocular track's creeping noise, then the car drives off): the replay turns its box at once
    instead of spinning it through the parked car."""
    fps = 20.0
    t = np.arange(0, 61) / fps
    flip = np.where(t < 1.5, 0.0, math.pi)
    x = np.where(t < 1.5, 30.0, 30.0 - 0.5 * 2.0 * (t - 1.5) ** 2)  # stands, then drives off (facing -x)
    stand = track(lambda s: (np.interp(s, t, x), 2.0 + 0 * s), 0, 60)
    stand = stand.model_copy(update={"yaw": [float(v) for v in flip]})
    parked = track(lambda s: (30.0 + 0 * s, 2.0 + 1.8 + 0.3 + 0 * s), 0, 60, yaw=0.0)
    sc = _processed(raw_scenario([vehicle(1, stand), vehicle(2, parked)]))
    hits = [c for c in simulate(sc, seed=0).collisions if set(c["vehicles"]) == {1, 2}]
    assert hits == []


def test_a_bystander_that_passes_closer_than_the_replay_tracks_is_moved_apart():
    """A parked car 0.1 m beside the ego's path never touches it in the tracks, but a replay that follows the
    path within decimetres would graze it: stage 2 moves it apart (and says so)."""
    parked = vehicle(3, track(lambda s: (40.0 + 0 * s, 0.9 + 0.9 + 0.1 + 0 * s), 0, 100, yaw=0.0))
    sc = process_scenario(raw_scenario([parked]))
    ego, car = vehicle_box(sc.ego), vehicle_box(sc.vehicle(3))
    ts = np.arange(max(ego.t[0], car.t[0]), min(ego.t[-1], car.t[-1]), 0.01)
    assert separation(ego, car, ts).min() >= 0.15
    assert any("agent 3" in w for w in sc.warnings)


def test_a_graze_between_two_video_frames_is_a_contact():
    """Two cars sampled 0.1 s apart (a 10 fps clip), one passing the other's corner at 4 m/s: their boxes overlap by
    4 cm for 0.03 s between two samples. The simulator, checking every 0.02 s, counts that contact, so stage 2's
    checks must too."""
    from deepcrashtest.trajectory.collision import BoxTrack, first_contact

    t = np.round(np.arange(0.0, 1.01, 0.1), 6)
    still = BoxTrack(t, 0 * t, 0 * t, 0 * t, 4.5, 1.8)
    dx = 4.46 + 3.0 * (t - 0.55)  # along x + y = 6.22: overlapping only while 4.42 < dx < 4.5
    passing = BoxTrack(t, dx, 6.22 - dx, 0 * t, 4.5, 1.8)
    assert separation(still, passing, t).min() > 0.1  # well apart at every sample
    assert separation(still, passing, np.linspace(0, 1, 1001)).min() < -0.03  # overlapping between two of them
    hit = first_contact(still, passing)
    assert hit is not None and 0.53 < hit.time_s < 0.55
