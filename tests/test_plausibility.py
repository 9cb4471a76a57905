"""Whether a scenario's vehicles move as vehicles can (``eval.plausibility``), on KITTI's labelled tracks."""

from __future__ import annotations

import math

import numpy as np

from deepcrashtest.datasets.kitti.scenario import scenario_from_kitti
from deepcrashtest.eval.plausibility import plausibility, vehicle_plausibility
from deepcrashtest.scenario import Scenario


def _turned(sc: Scenario, every_other: float, moving_by: float) -> Scenario:
    """Each agent's heading (not the ego's) turned by ``every_other`` rad at every second sample and by
    ``moving_by`` rad where it moves faster than 3 m/s."""
    agents = []
    for a in sc.agents:
        arr = a.trajectory.arrays()
        yaw = arr["yaw"] + every_other * (np.arange(len(arr["t"])) % 2) + moving_by * (arr["speed"] > 3.0)
        agents.append(a.model_copy(update={"trajectory": a.trajectory.model_copy(update={"yaw": yaw.tolist()})}))
    return sc.evolve(agents=agents)


def test_labelled_kitti_vehicles_move_as_vehicles(kitti_root):
    """KITTI 0011's labelled cars (positions and headings from LiDAR boxes, a town street with turning, crossing and
    parked cars) pass: no half turn, almost no step beyond the steering limit, few moving samples sliding. The
    same tracks turned half round at every other sample, or turned 40 deg off their motion, fail."""
    truth = scenario_from_kitti(kitti_root, 11)
    p = plausibility(truth)
    assert p["vehicles"] >= 20 and p["moving"] >= 200
    assert p["half_turns"] == 0 and p["vehicles_with_half_turns"] == []
    assert p["over_turning_share"] < 0.01  # measured 0.0003
    assert p["sliding_share"] < 0.02  # measured 0.0
    flipped = plausibility(_turned(truth, math.pi, 0.0))
    assert flipped["half_turns"] >= 0.9 * flipped["steps"]
    turned = {a.id for a in truth.agents if a.category != "pedestrian" and len(a.trajectory.t) >= 3}
    assert set(flipped["vehicles_with_half_turns"]) == turned  # every agent turned, the ego as it drove
    assert p["vehicles_spinning"] == [] and len(set(flipped["vehicles_spinning"]) & turned) >= 0.9 * len(turned)
    sliding = plausibility(_turned(truth, 0.0, math.radians(40.0)))
    agents_moving = sliding["moving"] - vehicle_plausibility(truth.ego)["moving"]
    assert sliding["sliding"] > 0.9 * agents_moving


def test_report_lists_the_vehicles_that_do_not_move_as_vehicles(kitti_root):
    """The report's plausibility section: KITTI 0011's labelled cars through stage 2 all pass (the labels' own
    speeds, their LiDAR boxes differenced at 10 Hz, change faster than a car's traction on 3 % of their steps:
    noise, listed too); turned half round at every other sample, every car gets its row."""
    from deepcrashtest.trajectory.pipeline import process_scenario
    from deepcrashtest.viz.report import plausibility_section

    truth = process_scenario(scenario_from_kitti(kitti_root, 11))
    assert "Every vehicle moves as a vehicle can" in plausibility_section(truth).body
    p = plausibility(truth)  # stage 2's lead-ins and extrapolations (the samples the labels did not see) turn as cars
    assert p["unseen_steps"] > p["steps"] and p["unseen_over_turning"] == 0  # measured 15,181 and 0
    assert plausibility(_turned(truth, math.pi, 0.0))["unseen_over_turning"] > 0.5 * p["unseen_steps"]
    body = plausibility_section(_turned(truth, math.pi, 0.0)).body
    turned = [a for a in truth.agents if a.category != "pedestrian" and len(a.trajectory.t) >= 3]
    assert body.count("<tr><td>") == len(turned)
    assert "Every vehicle" not in body


def test_road_users_passing_through_each_other_are_counted(kitti_root):
    """KITTI 0011's labelled road users (LiDAR boxes, a town street with parked, crossing and turning cars and
    pedestrians) never overlap; one car put where another parked car stands, for the time both exist, is one pair
    passing through the other."""
    from deepcrashtest.eval.plausibility import OVERLAP_MIN_S, overlapping_pairs

    truth = scenario_from_kitti(kitti_root, 11)
    assert overlapping_pairs(truth) == []
    cars = [a for a in truth.agents if a.category == "car" and len(a.trajectory.t) >= 20]
    host, guest = cars[0], next(a for a in cars[1:] if len(set(a.trajectory.t) & set(cars[0].trajectory.t)) >= 10)
    h = host.trajectory.arrays()
    g = guest.trajectory.arrays()
    x, y = np.interp(g["t"], h["t"], h["x"]), np.interp(g["t"], h["t"], h["y"])
    moved = guest.model_copy(
        update={"trajectory": guest.trajectory.model_copy(update={"x": x.tolist(), "y": y.tolist()})}
    )
    pairs = overlapping_pairs(truth.evolve(agents=[moved if a is guest else a for a in truth.agents]))
    assert [sorted(p[:2]) for p in pairs] == [sorted([host.id, guest.id])]
    assert pairs[0][2] >= OVERLAP_MIN_S


def test_speed_changes_beyond_a_vehicles_traction_are_counted(kitti8_raw):
    """KITTI 0008's labelled tracks (LiDAR boxes and ORB-SLAM3 poses, their speeds differenced at 10 Hz) change speed
    faster than their vehicles can accelerate or brake at 7.8 % of their observed steps (the boxes' noise, twice
    differenced); stage 2's processed scenario of them (smoothing, traction fit) at none. One car of it given a
    1 m/s jump between two samples 0.1 s apart (10 m/s^2, over a car's 4 m/s^2) counts exactly that step."""
    from deepcrashtest.trajectory.pipeline import process_scenario

    assert plausibility(kitti8_raw)["over_traction_share"] > 0.03  # measured 0.078
    sc = process_scenario(kitti8_raw)
    p = plausibility(sc)
    assert p["steps"] >= 1000 and p["over_traction"] == 0
    car = next(a for a in sc.agents if a.category == "car" and all(a.trajectory.observed or [False]))
    arr = car.trajectory.arrays()
    k = len(arr["t"]) // 2
    speed = arr["speed"] + 1.0 * (np.arange(len(arr["t"])) >= k)
    jumped = car.model_copy(update={"trajectory": car.trajectory.model_copy(update={"speed": speed.tolist()})})
    q = plausibility(sc.evolve(agents=[jumped if a is car else a for a in sc.agents]))
    assert q["over_traction"] == 1 and q["over_traction_share"] > 0


def test_road_users_joining_inside_each_other_are_counted(kitti_root):
    """KITTI 0011's labelled road users through stage 2 (step-back lead-ins included) never start or appear inside one
    another; the car put where another stands when it first appears is counted, at that moment, as deep as its box
    reaches into the other's, and the report names the pair."""
    from deepcrashtest.eval.plausibility import joining_overlaps
    from deepcrashtest.trajectory.collision import vehicle_box
    from deepcrashtest.trajectory.contact import separation
    from deepcrashtest.trajectory.pipeline import process_scenario
    from deepcrashtest.viz.report import plausibility_section

    truth = process_scenario(scenario_from_kitti(kitti_root, 11))
    assert joining_overlaps(truth) == []
    assert plausibility(truth)["overlapping_on_joining"] == []
    cars = [a for a in truth.agents if a.category == "car" and len(a.trajectory.t) >= 20]
    host = cars[0]
    guest = next(a for a in cars[1:] if host.trajectory.t[0] < a.trajectory.t[0] < host.trajectory.t[-1])
    h, g = host.trajectory.arrays(), guest.trajectory.arrays()
    x = g["x"] + np.interp(g["t"][0], h["t"], h["x"]) - g["x"][0]  # its first sample on the host's place then
    y = g["y"] + np.interp(g["t"][0], h["t"], h["y"]) - g["y"][0]
    moved = guest.model_copy(
        update={"trajectory": guest.trajectory.model_copy(update={"x": x.tolist(), "y": y.tolist()})}
    )
    sc = truth.evolve(agents=[moved if a is guest else a for a in truth.agents])
    ((a, b, t, depth),) = joining_overlaps(sc)
    assert sorted([a, b]) == sorted([host.id, guest.id]) and t == round(g["t"][0], 3)
    expected = -separation(vehicle_box(host), vehicle_box(moved), np.array([g["t"][0]]))[0]
    assert depth == round(expected, 3) and depth > 1.0
    assert "joins the scenario" in plausibility_section(sc).body
