"""Crash-consistent stage 2: hand-built tracks with known answers (the pair touches at the labelled time,
nothing touches before it), bounded lead-in, implausible tracks dropped."""

from __future__ import annotations

import numpy as np
import pytest

from deepcrashtest.scenario import Collision, Scenario
from deepcrashtest.trajectory.collision import BoxTrack, first_contact, vehicle_box
from deepcrashtest.trajectory.contact import Movable, box_track, make_contact, separation
from deepcrashtest.trajectory.pipeline import process_scenario
from trajectory_cases import raw_scenario, track, vehicle


def _contacts(sc: Scenario) -> list[tuple[int, int, float]]:
    vs = list(sc.vehicles())
    out = []
    for i in range(len(vs)):
        for j in range(i + 1, len(vs)):
            hit = first_contact(vehicle_box(vs[i]), vehicle_box(vs[j]))
            if hit is not None:
                out.append((vs[i].id, vs[j].id, hit.time_s))
    return out


def test_separation_is_signed_box_distance():
    t = np.array([0.0])
    a = BoxTrack(t, np.zeros(1), np.zeros(1), np.zeros(1), 4.0, 2.0)
    apart = BoxTrack(t, np.array([7.0]), np.zeros(1), np.zeros(1), 4.0, 2.0)
    deep = BoxTrack(t, np.array([3.5]), np.zeros(1), np.zeros(1), 4.0, 2.0)
    assert separation(a, apart, t)[0] == pytest.approx(3.0)  # 7 - 2 - 2
    assert separation(a, deep, t)[0] == pytest.approx(-0.5)


def test_make_contact_touches_at_the_crash_time_within_limits():
    t = np.round(np.arange(0, 4.01, 0.1), 6)
    ego = Movable(t, np.column_stack([10 * t, 0 * t]), 4.5, 1.8, 0.0, weight=3.0)
    car = Movable(t, np.column_stack([40.5 + 2 * t, 0.4 + 0 * t]), 4.5, 1.8, 0.0)  # 4 m short of touching at 4 s
    c = make_contact(ego, car, 4.0)
    assert c.ok and 2.0 < c.max_m < 4.5
    e2 = box_track(Movable(t, ego.xy + c.deltas[0], 4.5, 1.8, 0.0))
    a2 = box_track(Movable(t, car.xy + c.deltas[1], 4.5, 1.8, 0.0))
    hit = first_contact(e2, a2)
    assert hit is not None and 3.9 <= hit.time_s <= 4.0
    for d in c.deltas:  # smooth and drivable: nothing moves before the window, accelerations bounded
        assert np.allclose(d[t < 4.0 - c.window_s - 1e-6], 0.0)
        acc = np.diff(d, 2, axis=0) / 0.1**2
        assert np.abs(acc).max() < 4.0 * 1.5


def test_make_contact_stops_unsuccessful_when_its_evaluation_budget_is_spent(monkeypatch):
    """A correction that cannot be found in MAX_EVALS corrected-path evaluations is given up (not
    applied), deterministically: stage 2 stays bounded on pathological tracks."""
    import deepcrashtest.trajectory.contact as contact

    t = np.round(np.arange(0, 4.01, 0.1), 6)
    ego = Movable(t, np.column_stack([10 * t, 0 * t]), 4.5, 1.8, 0.0, weight=3.0)
    car = Movable(t, np.column_stack([40.5 + 2 * t, 0.4 + 0 * t]), 4.5, 1.8, 0.0)
    monkeypatch.setattr(contact, "MAX_EVALS", 5)
    c = make_contact(ego, car, 4.0)
    assert not c.ok and "budget" in c.message
    monkeypatch.setattr(contact, "MAX_EVALS", 1_000_000)
    assert make_contact(ego, car, 4.0).ok


def _rear_end_raw(**kw) -> Scenario:  # type: ignore[no-untyped-def]
    """Ego at 10 m/s; a car ahead at 4 m/s whose monocular depth is 3 m too far: at 5 s the tracks are
    3 m apart, but the video shows the rear-end then; a bystander overlaps the ego's lane at 2 s."""
    lead = vehicle(1, track(lambda t: (37.5 + 4 * t, 0.2 + 0 * t), 0, 60))
    cross = vehicle(2, track(lambda t: (25 + 0 * t, 12 - 6 * t), 0, 40))  # crosses the ego's path at x = 25
    return raw_scenario([lead, cross], **kw)


def test_labelled_crash_is_reproduced_and_nothing_touches_before():
    crash = Collision(time_s=5.0, agent_id=1, other_id=0, source="user")
    sc = process_scenario(_rear_end_raw(collision=crash))
    t_max = sc.provenance.parameters["t_max_s"]
    assert sc.collision is not None and sc.collision.participants == (0, 1)
    assert sc.collision.time_s == pytest.approx(5.0 + t_max)
    contacts = _contacts(sc)
    pair = [c for c in contacts if set(c[:2]) == {0, 1}]
    assert pair and abs(pair[0][2] - (5.0 + t_max)) <= 0.03  # the first touch of the 3D boxes is the crash time
    assert all(set(c[:2]) == {0, 1} for c in contacts), contacts  # the bystander was moved or dropped
    rec = sc.provenance.parameters["crash"]["correction"]
    assert rec["pair"] == [0, 1] and rec["satisfied"] and 1.0 < rec["max_m"] < 5.0
    assert any("agent 2" in w for w in sc.warnings)


def test_third_party_crash_between_two_agents():
    a = vehicle(3, track(lambda t: (40 + 0 * t, -10 + 3 * t), 0, 50))  # crossing from the right
    b = vehicle(4, track(lambda t: (20 + 5 * t, -2.5 + 0 * t), 0, 50))  # same direction, right lane
    # nominally they meet near t = 3.3 s (a at y = 0, b at x = 36.5): the video says 3.5 s
    sc = process_scenario(raw_scenario([a, b], collision=Collision(time_s=3.5, agent_id=4, other_id=3)))
    t_max = sc.provenance.parameters["t_max_s"]
    contacts = _contacts(sc)
    assert contacts and {contacts[0][0], contacts[0][1]} == {3, 4}
    assert abs(contacts[0][2] - (3.5 + t_max)) <= 0.1
    assert not sc.collision.involves_ego  # type: ignore[union-attr]


def test_no_crash_in_the_video_means_no_contact():
    raw = _rear_end_raw()
    params = dict(raw.provenance.parameters, crash_detection={"found": False})
    sc = process_scenario(raw.evolve(provenance=raw.provenance.model_copy(update={"parameters": params})))
    assert sc.collision is None and _contacts(sc) == []


def test_lead_in_is_bounded_and_parked_cars_stay():
    fast = track(lambda t: (30 * t, 0 * t), 0, 50)
    parked = vehicle(1, track(lambda t: (80 + 0 * t, 4 + 0 * t), 0, 50, yaw=0.0))
    sc = process_scenario(raw_scenario([parked], ego=fast))
    t_max = sc.provenance.parameters["t_max_s"]
    assert t_max == pytest.approx(4.0)  # 30 m/s at 3 m/s^2 would take 10 s
    e = sc.ego.trajectory.arrays()
    assert e["speed"][0] == pytest.approx(18.0, abs=0.5)  # starts moving: 30 - 3 x 4
    assert e["x"][0] == pytest.approx(-(18 * 4 + 0.5 * 3 * 16), abs=1.0)  # 96 m behind, not 150 m
    p = sc.vehicle(1).trajectory.arrays()
    assert np.ptp(p["x"]) < 0.05 and np.ptp(p["y"]) < 0.05
    # every observed second survives: video frames 0..50 are all in the scenario
    assert sc.video_frame(e["t"][-1]) == 50 and sc.video_frame(t_max) == 0


def test_implausible_agent_is_dropped_not_fatal():
    wild = vehicle(5, track(lambda t: (20 + 80 * t, 0 * t + 3.5), 0, 30))  # 80 m/s in a city: localisation noise
    sc = process_scenario(raw_scenario([wild]))
    assert sc.agents == [] and any("agent 5" in w and "dropped" in w for w in sc.warnings)
    assert all(max(v.trajectory.speed) <= 90 for v in sc.vehicles())


def test_overlap_from_the_start_then_a_retouch_counts_as_the_simulator_counts():
    from deepcrashtest.trajectory.crash import contact_after_apart

    t = np.round(np.arange(0, 4.01, 0.1), 6)
    parked = BoxTrack(t, 20 + 0 * t, 0 * t, 0 * t, 4.5, 1.8)
    # starts overlapping the parked car (depth noise), drives off (apart after 1.125 s), backs into it at 1.875 s
    x = np.where(t <= 1.5, 20 + 4 * t, 26 - 4 * (t - 1.5))
    mover = BoxTrack(t, x, 0 * t, 0 * t, 4.5, 1.8)
    hit = contact_after_apart(parked, mover)
    assert hit is not None and 1.5 < hit.time_s < 4.0  # the re-touch, not the overlap at 0 s
    assert first_contact(parked, mover).time_s == 0.0  # type: ignore[union-attr]


def test_a_slow_ego_that_creeps_backwards_is_kept_with_a_warning():
    """A crawling ego whose monocular track runs backwards for a second (ccd_000080's extraction did)
    must not sink stage 2: its backward steps are held in place, with a warning, never 'not physically
    possible'."""

    def creep(t: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        back = np.where(t < 1.5, -0.9 * t, -1.35 + 0.0 * t)  # 0.9 m/s backwards, then stopped
        fwd = np.where(t > 2.5, 2.0 * (t - 2.5) ** 2 / 2, 0.0)  # then 2 m/s^2 forward
        return back + fwd, 0.0 * t

    lead = vehicle(1, track(lambda t: (30 + 0 * t, 0.3 + 0 * t), 0, 60))
    # the camera looks forward (its yaw is measured from the image's rotation) while the track creeps back
    sc = process_scenario(raw_scenario([lead], ego=track(creep, 0, 60, yaw=0.0)))
    assert len(sc.ego.trajectory) > 10
    assert any("backwards" in w for w in sc.warnings)
    x = sc.ego.trajectory.arrays()["x"]
    assert (np.maximum.accumulate(x) - x).max() < 0.3  # held in place, not reversing (the replay cannot)
    from deepcrashtest.sim import simulate

    yaw = np.asarray(simulate(sc).states)[:, 0, 2]  # the replayed ego keeps facing forward
    assert np.abs(yaw).max() < np.pi / 4


def test_a_crawling_egos_crash_is_made_with_the_cameras_heading():
    """An ego crawling at 0.4 m/s whose monocular path drifts 0.2 rad off the camera's (measured) yaw 0:
    the processed ego faces the camera's yaw, and so must the box the crash correction touches with
    (the replayed ego does not turn to a crawl's noisy direction either): the processed pair's first
    contact is at the crash time (with the path's direction, the touch moved or vanished)."""
    ego = track(lambda t: (0.4 * t, 0.08 * t), 0, 60, yaw=0.0)
    parked = vehicle(1, track(lambda t: (7.0 + 0 * t, 2.3 + 0 * t), 0, 60, yaw=0.0))
    raw = raw_scenario([parked], ego=ego, collision=Collision(time_s=5.0, agent_id=1, other_id=0, source="user"))
    sc = process_scenario(raw)
    t_max = sc.provenance.parameters["t_max_s"]
    pair = [c for c in _contacts(sc) if set(c[:2]) == {0, 1}]
    assert pair and abs(pair[0][2] - (5.0 + t_max)) <= 0.05, (pair, 5.0 + t_max)
    assert abs(sc.provenance.parameters["crash"]["contact_time_s"] - (5.0 + t_max)) <= 0.05


def test_a_parked_car_in_the_egos_way_is_shifted_whole_and_keeps_its_heading():
    """A parked car whose monocular depth puts it 0.2 m into the ego's lane (no crash in the video): it is
    moved apart as a whole (its depth error), never along a bent path whose direction turned its box
    (ccd_000340: such a nudge swung a parked car's heading by 4 rad and the replay's first contact was it)."""
    parked = vehicle(1, track(lambda t: (50 + 0 * t, 1.6 + 0 * t), 0, 100, yaw=0.0))
    raw = raw_scenario([parked])
    params = dict(raw.provenance.parameters, crash_detection={"found": False})
    sc = process_scenario(raw.evolve(provenance=raw.provenance.model_copy(update={"parameters": params})))
    assert sc.collision is None and _contacts(sc) == []
    p = sc.vehicle(1).trajectory.arrays()
    assert np.ptp(p["x"]) < 0.01 and np.ptp(p["y"]) < 0.01  # one shift of the whole track
    assert np.abs(p["yaw"]).max() < 1e-6  # it faces where it was seen facing
    assert p["y"][0] > 1.6 + 0.2  # moved out of the ego's way


def test_a_bystander_is_nudged_apart_only_where_it_comes_near():
    """A car overtaking a parked one 0.3 m too close (at 8-12 s of a 40 s track) is moved apart; the clearance is
    asked only where the two can come within ``reach_m`` of each other (the rest cannot touch after a move that
    small), and the move is the one asking it at every sample gives (a 200 s highway track asked it at each of its
    5,000 samples of each of 30 others: 90 s and gigabytes of SLSQP)."""
    from deepcrashtest.trajectory.contact import nudge_apart

    t = np.arange(0.0, 40.0, 0.04)
    car = Movable(t, np.column_stack([-100 + 10 * t, 2.1 + 0 * t]), 4.5, 1.8, 0.0)
    parked = Movable(t, np.column_stack([0 * t, 0 * t]), 4.5, 1.8, 0.0, kin=None)
    near = nudge_apart(car, [parked], t[-1], reach_m=6.0)
    every = nudge_apart(car, [parked], t[-1])
    assert near.ok and every.ok and 0.1 < near.max_m < 1.0
    assert np.abs(near.deltas[0] - every.deltas[0]).max() < 0.005
    moved = box_track(Movable(t, car.xy + near.deltas[0], 4.5, 1.8, 0.0))
    assert separation(moved, box_track(parked), t).min() >= 0.5 - 0.02  # the clearance (ContactParams)


@pytest.mark.parametrize(("category", "moved"), [("pedestrian", True), ("car", False)])
def test_a_detected_crash_moves_to_an_earlier_touch_only_with_a_pedestrian(category: str, moved: bool):
    """A crash detected without a camera jolt (where a box stopped growing) whose pair's boxes, as seen, touch
    0.9 s earlier: a struck pedestrian is carried on the bonnet and their box goes on changing after the contact
    (ccd_000882: detected at 3.8 s, the boxes touch at 3.02, the label 3.0), so the crash is at the touch; a
    vehicle's box stops growing at the contact, so the detection stands (through a wide-angle lens dad_000493's
    motorcycle and ccd_000340's car touched 0.5 s before detections that were right)."""
    crossing = vehicle(5, track(lambda t: (45.0 + 0 * t, 6.3 - 1.5 * t), 20, 50), category=category)
    crash = Collision(time_s=5.0, agent_id=5, other_id=0, source="video-auto")
    raw = raw_scenario([crossing], collision=crash)
    found = {"found": True, "source": "video-auto", "evidence": {"near": 1.0, "closing": 1.0, "jolt": 0.0}}
    raw = raw.model_copy(
        update={"provenance": raw.provenance.model_copy(update={"parameters": {"crash_detection": found}})}
    )
    sc = process_scenario(raw)
    t_max = sc.provenance.parameters["t_max_s"]
    assert sc.collision is not None and sc.collision.participants == (0, 5)
    early = sc.collision.time_s - t_max
    if moved:
        assert 3.7 < early < 4.5 and any("as seen, touch" in w for w in sc.warnings)
    else:
        assert early == pytest.approx(5.0) and not any("as seen, touch" in w for w in sc.warnings)


def test_a_crash_correction_keeps_the_pair_apart_between_its_samples():
    """A car turning across the ego's path at 5 fps (samples 0.2 s apart): the crash correction kept the two apart at
    the samples, but between them the turning box's corner touched the ego 0.6 s before the crash, and the replay,
    checking every 0.02 s, crashed there (854x480 ccd_000132 at half frame rate: 0.44 s early). With
    ``apart_margin_m`` (what stage 2 asks again when a correction grazes) they stay apart on a 0.05 s grid, by the
    margin until 0.3 s before, and first touch at the crash."""
    t = np.round(np.arange(0, 4.01, 0.2), 6)
    ego = Movable(t, np.column_stack([6 * t, 0 * t]), 4.5, 1.8, 0.0, weight=3.0)
    r, turn = 8.8228, 0.4101 + 0.75685 * t  # m, rad: an elliptic arc (a random case that grazed)
    xy = np.column_stack([29.1717 + r * np.cos(turn), 0.6 * r * np.sin(turn) + 0.66998])
    car = Movable(t, xy, 4.5, 1.8, 0.4101 + np.pi / 2)
    first = []
    for margin in (0.0, 0.05):
        c = make_contact(ego, car, 4.0, apart_margin_m=margin)
        assert c.ok
        hit = first_contact(box_track(ego, ego.xy + c.deltas[0]), box_track(car, car.xy + c.deltas[1]))
        assert hit is not None
        first.append(hit.time_s)
    assert first[0] < 3.6  # without: the corner grazes between two samples
    assert 3.9 <= first[1] <= 4.0


def test_cars_parked_into_each_other_are_shortened_where_they_stand():
    """Two cars parked bumper to bumper whose centres the video puts 4.37 m apart, each 4.5 m long (the class's
    length, its least measured dimension): 0.13 m into each other all clip long (dad_000478). They stay where they
    were placed and are shortened just enough to stand 5 cm apart; a pair 1.5 m into each other (one car tracked twice,
    a depth error) is more than a size can explain and is left as it is; no car shrinks below 90 % of its size over
    all the pairs it is in."""
    from deepcrashtest.trajectory.parked import PARKED_GAP_M, PARKED_MAX_SHRINK

    rows = [(1, 40.0, 6.0), (2, 44.37, 6.0), (3, 60.0, -6.0), (4, 63.0, -6.0), (5, 48.44, 6.0)]
    parked = [vehicle(i, track(lambda t, x=x, y=y: (x + 0 * t, y + 0 * t), 0, 60, yaw=0.0)) for i, x, y in rows]
    sc = process_scenario(raw_scenario(parked))
    v = {a.id: a for a in sc.agents}
    t = np.array([sc.ego.trajectory.t[0] + 1.0])
    assert separation(vehicle_box(v[1]), vehicle_box(v[2]), t)[0] == pytest.approx(PARKED_GAP_M, abs=0.01)
    assert 4.5 * (1 - PARKED_MAX_SHRINK) <= v[1].length < 4.45 and v[1].length == pytest.approx(v[2].length)
    for i, x, y in rows[:2]:
        a = v[i].trajectory.arrays()
        assert np.abs(a["x"] - x).max() < 0.02 and np.abs(a["y"] - y).max() < 0.02  # not moved
    assert v[3].length == v[4].length == pytest.approx(4.5, abs=0.01)  # 1.5 m into each other: left
    # a third car 0.43 m into the second: the second cannot shrink below 90 % of its size over both pairs
    assert min(a.length for a in sc.agents) >= 4.5 * (1 - PARKED_MAX_SHRINK) - 1e-6
    assert any("parked 0.13 m into each other" in w for w in sc.warnings)


def test_a_road_user_first_seen_a_few_millimetres_into_another_is_moved_apart():
    """An oncoming car first seen 3 mm into a parked car's box (depth noise, as ccd_000031 through wipers had it)
    drives on alongside it: boxes that overlap when both first exist are ignored until apart, as the simulator
    counts contacts, but the final paths' smoothing moves each by centimetres, and a few millimetres become apart
    and touching a moment later, a contact the replay counts (3 s before that clip's crash). An overlap that shallow
    (under ``near_miss_m``) when both first exist is a clash: the car is nudged clear, nothing overlaps."""
    from deepcrashtest.eval.plausibility import joining_overlaps, overlapping_pairs

    parked = vehicle(1, track(lambda t: (60 + 0 * t, 6 + 0 * t), 0, 100, yaw=0.0), length=4.5, width=1.8)
    oncoming = vehicle(
        2, track(lambda t: (62 - 8 * (t - 2), 6 + 1.797 + 0 * t), 20, 60, yaw=np.pi), length=4.5, width=1.8
    )
    sc = process_scenario(raw_scenario([parked, oncoming]))
    assert {a.id for a in sc.agents} == {1, 2}
    assert joining_overlaps(sc) == [] and overlapping_pairs(sc) == []
    a, b = (vehicle_box(sc.vehicle(i)) for i in (1, 2))
    lo, hi = max(a.t[0], b.t[0]), min(a.t[-1], b.t[-1])
    assert separation(a, b, np.linspace(lo, hi, 400)).min() > 0.1
