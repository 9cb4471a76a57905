"""The scenario's crash happens in its replay (real KITTI tracking labels + ORB-SLAM3 poses).

A crash is declared (as ``extract --crash`` would) between two real road users that pass close in the
sequence; stage 2 corrects their last seconds within the simulator's kinematics, and the replay
(``simulate`` with the default replay controller) must produce that contact first, at that time.
"""

from __future__ import annotations

import numpy as np
import pytest

from deepcrashtest.scenario import VEHICLE_KINEMATICS, Collision, Scenario
from deepcrashtest.sim import simulate
from deepcrashtest.trajectory.pipeline import process_scenario

CASES = [
    # (sequence, a, b, raw time s): a pedestrian beside a passing car (their boxes 1.2 m apart at 13.0 s)
    (2, 4, 6, 13.0),
]


def _steer_demand(sc: Scenario, vid: int, t_from: float) -> float:
    """Largest road-wheel angle (rad) the vehicle's processed path asks for after ``t_from`` (s), at
    speeds above 1 m/s (curvature from the sampled positions)."""
    v = next(v for v in sc.vehicles() if v.id == vid)
    a = v.trajectory.arrays()
    m = a["t"] >= t_from
    t, x, y = a["t"][m], a["x"][m], a["y"][m]
    vx, vy = np.gradient(x, t), np.gradient(y, t)
    ax, ay = np.gradient(vx, t), np.gradient(vy, t)
    s = np.hypot(vx, vy)
    kappa = (vx * ay - vy * ax) / np.maximum(s, 1e-6) ** 3
    fast = s > 1.0
    wb = VEHICLE_KINEMATICS.wheelbase_fraction * v.length
    return float(np.abs(np.arctan(wb * kappa[fast])).max(initial=0.0))


@pytest.mark.parametrize(("seq", "a", "b", "t_raw"), CASES)
def test_declared_crash_is_the_replays_first_contact(kitti_root, seq, a, b, t_raw):
    from deepcrashtest.datasets.kitti.scenario import scenario_from_kitti

    raw = scenario_from_kitti(kitti_root, seq, road_users=True)
    raw = raw.evolve(collision=Collision(time_s=t_raw, other_id=a, agent_id=b, source="user"))
    sc = process_scenario(raw)
    assert sc.collision is not None and set(sc.collision.participants) == {a, b}
    rec = sc.provenance.parameters["crash"]["correction"]
    assert rec["satisfied"] and rec["max_m"] < 2.5, rec
    sim = simulate(sc)
    first = sim.first_contact
    assert first is not None and set(first["vehicles"]) == {a, b}, sim.collisions[:3]
    assert abs(first["time"] - sc.collision.time_s) <= 0.25
    # the corrected last seconds stay within what the simulator's vehicles can steer
    window_start = sc.collision.time_s - rec["window_s"]
    for vid in (a, b):
        cat = next(v.category for v in sc.vehicles() if v.id == vid)
        if cat != "pedestrian":
            assert _steer_demand(sc, vid, window_start) <= VEHICLE_KINEMATICS.max_steer_rad * 1.05


def test_agents_replay_their_processed_trajectories(kitti_root):
    """An agent's replay tracks its processed trajectory (centimetres), so the contacts stage 2 arranged
    (and the separations it kept) are the replay's."""
    from deepcrashtest.datasets.kitti.scenario import scenario_from_kitti

    sc = process_scenario(scenario_from_kitti(kitti_root, 2, road_users=True))
    sim = simulate(sc)
    t_end = sim.first_contact["time"] if sim.first_contact else sim.times[-1]
    worst = 0.0
    for i, v in enumerate(sc.vehicles()):
        if i == 0:
            continue
        arr = v.trajectory.arrays()
        m = sim.present[:, i] & (sim.times >= arr["t"][0]) & (sim.times <= min(arr["t"][-1], t_end - 0.1))
        if m.sum() < 2:
            continue
        ts = sim.times[m]
        err = np.hypot(
            sim.states[m, i, 0] - np.interp(ts, arr["t"], arr["x"]),
            sim.states[m, i, 1] - np.interp(ts, arr["t"], arr["y"]),
        )
        worst = max(worst, float(err.max()))
    assert worst < 0.1


def test_detected_crash_of_two_road_users_standing_still_is_dropped(kitti_root):
    """Two cars parked side by side (KITTI 0002, tracks 17 and 18, 8-23 s) cannot crash: a detected
    (video-auto) crash between them is dropped with a warning, not forced by moving a parked car, and the
    scenario keeps the whole video."""
    from deepcrashtest.datasets.kitti.scenario import scenario_from_kitti

    raw = scenario_from_kitti(kitti_root, 2, road_users=True)
    raw = raw.evolve(collision=Collision(time_s=20.0, other_id=17, agent_id=18, source="video-auto", confidence=0.5))
    sc = process_scenario(raw)
    assert sc.collision is None
    assert any("neither moves" in w for w in sc.warnings), sc.warnings
    # the scenario does not end at the dropped crash: every observed second is kept
    assert sc.video_time(sc.ego.trajectory.t[-1]) >= raw.video_time(raw.ego.trajectory.t[-1]) - 0.2
