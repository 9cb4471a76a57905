"""The crash pair facing its boxes must touch by the crash time, not at the very end of its paths (real numbers:
dad_000493 re-encoded, whose replay then had no contact at all)."""

from __future__ import annotations

from deepcrashtest.scenario import Collision, Trajectory, Vehicle
from deepcrashtest.trajectory.agentheading import LATE_TOUCH_S, replayable_yaws
from deepcrashtest.trajectory.collision import first_contact, vehicle_box

# stage 2 of dad_000493 re-encoded (bench/fidelity_perturbed.py --variants copy), its last 0.55 s (scenario time): the
# ego and the crossing scooter 3, the crash at 5.548 s; the paths end 0.1 s after it. The scooter's boxes face
# 2.007 rad, its path 1.46-1.67 rad.
T = [5.098, 5.148, 5.198, 5.248, 5.298, 5.348, 5.398, 5.448, 5.498, 5.548, 5.598, 5.648]
EGO = (
    [13.932, 14.111, 14.29, 14.469, 14.648, 14.827, 15.006, 15.185, 15.364, 15.543, 15.721, 15.9],
    [1.315, 1.321, 1.326, 1.327, 1.327, 1.324, 1.319, 1.312, 1.303, 1.292, 1.279, 1.264],
    [0.039, 0.008, -0.019, -0.043, -0.051, -0.044, -0.044, -0.062, -0.089, -0.111, -0.138, -0.153],
    [3.578, 3.579, 3.579, 3.58, 3.58, 3.581, 3.582, 3.583, 3.583, 3.584, 3.585, 3.585],
)
X3 = [18.245, 18.236, 18.23, 18.228, 18.23, 18.236, 18.246, 18.259, 18.274, 18.288, 18.302, 18.314]
Y3 = [1.275, 1.388, 1.504, 1.622, 1.743, 1.866, 1.992, 2.119, 2.248, 2.377, 2.506, 2.635]
SPEED3 = [2.252, 2.295, 2.341, 2.39, 2.44, 2.493, 2.542, 2.576, 2.596, 2.601, 2.591, 2.567]
BOX_YAW3 = [2.007] * len(T)
PATH_YAW3 = [1.673, 1.638, 1.603, 1.57, 1.537, 1.505, 1.48, 1.464, 1.457, 1.459, 1.471, 1.491]
CRASH = Collision(time_s=5.548, agent_id=3, other_id=0, source="video-auto")


EGO_CAR = Vehicle(id=0, category="car", length=4.5, width=1.8, trajectory=Trajectory.from_arrays(T, *EGO))


def _vehicles(yaw3: list[float]) -> list[Vehicle]:
    path = Trajectory.from_arrays(T, X3, Y3, yaw3, SPEED3)
    scooter = Vehicle(id=3, category="motorcycle", length=2.097, width=0.799, trajectory=path)
    return [EGO_CAR, scooter]  # the ego's heading is its own in both (stage 2 passes the same vehicle)


def test_a_crash_pair_that_would_touch_at_the_end_of_its_paths_faces_along_them():
    observed, path = _vehicles(BOX_YAW3), _vehicles(PATH_YAW3)
    late = first_contact(*(vehicle_box(v) for v in observed))
    assert late is not None and late.time_s > CRASH.time_s + 0.09  # facing its boxes: 0.098 s late
    warnings: list[str] = []
    final = replayable_yaws(observed, path, CRASH, warnings)
    hit = first_contact(*(vehicle_box(v) for v in final))
    assert hit is not None and hit.time_s <= CRASH.time_s + LATE_TOUCH_S
    assert warnings and "agent(s) [3]" in warnings[0]
