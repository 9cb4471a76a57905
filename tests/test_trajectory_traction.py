"""Every processed road user within its traction and braking (``trajectory.traction``), on real KITTI tracks.

KITTI tracking 0002 (a training sequence: real 3D labels + ORB-SLAM3 poses): stage 2's smoothed car 16 sped up
at 9.1 m/s^2 and braked at 12.7 m/s^2 (label depth noise), more than the simulator's vehicle can (4 / 9 m/s^2),
so its replay lagged its path. Times in seconds, positions in metres, accelerations in m/s^2.
"""

from __future__ import annotations

import numpy as np
import pytest

from deepcrashtest.scenario import VEHICLE_KINEMATICS, Scenario, kinematics
from deepcrashtest.trajectory.alongpath import along_accel, arc_length
from deepcrashtest.trajectory.traction import retimed_within


@pytest.fixture(scope="module")
def kitti2_raw(kitti_root) -> Scenario:
    from deepcrashtest.datasets.kitti.scenario import scenario_from_kitti

    return scenario_from_kitti(kitti_root, 2, road_users=True)


def _speed_changes(sc: Scenario) -> dict[int, tuple[float, float]]:
    """Per vehicle: its largest rise and fall of the sampled speed between consecutive samples (m/s^2)."""
    out = {}
    for v in sc.vehicles():
        a = v.trajectory.arrays()
        if len(a["t"]) >= 2:
            acc = np.diff(a["speed"]) / np.diff(a["t"])
            out[v.id] = (float(acc.max()), float(-acc.min()))
    return out


def test_every_processed_road_user_keeps_within_its_traction_and_braking(kitti2_raw):
    """KITTI 0002 through stage 2: no processed path asks more than its road user's kinematics (main: car 16
    +9.1 / -12.7 m/s^2); car 16 is re-timed along its own path (a warning says so), by decimetres."""
    from deepcrashtest.trajectory.pipeline import process_scenario

    sc = process_scenario(kitti2_raw)
    for vid, (rise, fall) in _speed_changes(sc).items():
        kin = kinematics(sc.vehicle(vid).category)
        assert rise <= kin.max_accel_mps2 and fall <= kin.max_brake_mps2, (vid, rise, fall)
    note = next(w for w in sc.warnings if w.startswith("agent 16: its processed path asked for more"))
    assert float(note.split("moved up to ")[1].split(" m")[0]) < 0.5


def test_a_retimed_path_keeps_its_shape_and_its_pinned_end(kitti2_raw):
    """Car 16's raw (label) track re-timed within 0.85 x a car's limits, held from 2 s before its end: the
    held samples stay within a centimetre, every sample lies on the original path, and the distances along
    it change within the limits (the label track itself: up to 16 m/s^2)."""
    a = kitti2_raw.vehicle(16).trajectory.arrays()
    t, xy = a["t"], np.column_stack([a["x"], a["y"]])
    s = arc_length(xy)
    assert np.abs(along_accel(t, s)).max() > VEHICLE_KINEMATICS.max_brake_mps2  # 16 m/s^2: worth re-timing
    pin = float(t[-1] - 2.0)
    new = retimed_within(t, xy, VEHICLE_KINEMATICS, 0.85, pin)
    held = t >= pin
    assert np.hypot(*(new[held] - xy[held]).T).max() < 0.01
    acc = along_accel(t[~held], arc_length(new[~held]))
    assert acc.max() <= 0.85 * VEHICLE_KINEMATICS.max_accel_mps2 + 0.05
    assert acc.min() >= -0.85 * VEHICLE_KINEMATICS.max_brake_mps2 - 0.05
    seg = _distance_to_polyline(new, xy)
    assert seg.max() < 1e-6  # re-timed along itself: the path's shape is kept


def _distance_to_polyline(p: np.ndarray, line: np.ndarray) -> np.ndarray:
    """Distance (m) of each point of ``p`` (N, 2) to the polyline ``line`` (M, 2)."""
    a, b = line[:-1], line[1:]
    ab = b - a
    w = np.clip(np.einsum("nmk,mk->nm", p[:, None] - a[None], ab) / np.maximum(np.sum(ab * ab, 1), 1e-12), 0, 1)
    closest = a[None] + w[..., None] * ab[None]
    return np.hypot(*(p[:, None] - closest).transpose(2, 0, 1)).min(axis=1)


def test_speed_jumps_far_apart_are_retimed_each_on_its_own_and_the_path_between_is_kept():
    """Two speed jumps 20 s apart (a 25 fps track, 10 -> 14 -> 10 m/s, seeded 3 cm jitter along it): each is
    re-timed within ``WINDOW_S`` of itself, and the 17 s between keep their samples exactly (one least squares
    over the whole stretch moved them and cost the cube of its samples: 2 s for a 770-sample highway track)."""
    from deepcrashtest.trajectory.traction import WINDOW_S

    t = np.arange(0.0, 30.0, 0.04)
    speed = np.where((t >= 5.0) & (t < 25.0), 14.0, 10.0)
    s = np.concatenate([[0.0], np.cumsum(speed[:-1] * np.diff(t))])
    s += np.random.default_rng(0).normal(0.0, 0.03, len(t))
    s = np.maximum.accumulate(s)
    xy = np.column_stack([s, np.zeros_like(s)])
    jumps = np.array([5.0, 25.0])
    new = retimed_within(t, xy, VEHICLE_KINEMATICS, 0.85, around_s=jumps)
    far = np.abs(t[:, None] - jumps[None]).min(axis=1) > WINDOW_S + 0.1
    assert far.sum() > 400 and np.array_equal(new[far], xy[far])
    for jump in jumps:  # each window as if re-timed alone
        alone = retimed_within(t, xy, VEHICLE_KINEMATICS, 0.85, around_s=np.array([jump]))
        near = np.abs(t - jump) <= WINDOW_S
        np.testing.assert_array_equal(new[near], alone[near])
        acc = along_accel(t[near], new[near, 0])[1:-1]  # its inner samples: the window's bounds hold there
        assert acc.max() <= 0.85 * VEHICLE_KINEMATICS.max_accel_mps2 + 0.05
        assert acc.min() >= -0.85 * VEHICLE_KINEMATICS.max_brake_mps2 - 0.05
    moved = np.abs(new[:, 0] - xy[:, 0])
    assert moved[~far].max() > 0.1  # the jumps were re-timed


def test_a_long_stretch_is_retimed_in_pieces_as_one_least_squares_would():
    """900 samples (36 s at 25 fps, seeded 0.3 m jitter: the limits bind all along) are solved in pieces of at
    most ``MAX_SAMPLES`` (one least squares grows as the cube of its samples: a 200 s highway track's took minutes
    and gigabytes); each piece looks ``LOOK_AHEAD`` samples beyond what it keeps, so the pieces join as the one
    solve would: within a centimetre, the limits kept at the joins too. Without the look-ahead they were 0.58 m
    apart."""
    from deepcrashtest.trajectory import alongpath

    t = np.arange(900) / 25.0
    s = np.cumsum(15.0 + 3.0 * np.sin(t / 3.0)) / 25.0 + np.random.default_rng(0).normal(0.0, 0.3, len(t))
    assert len(t) > 2 * alongpath.MAX_SAMPLES
    pieces = alongpath.bounded_distances(t, s, 3.0, 6.0)
    whole = alongpath._bounded(t, s, 3.0, 6.0, np.ones(len(t)), np.inf, -np.inf)
    assert np.abs(pieces - whole).max() < 0.01
    acc = along_accel(t, pieces)
    assert acc.max() <= 3.0 + 0.02 and acc.min() >= -6.0 - 0.02


def test_an_impacts_stop_is_not_retimed_into_the_approach():
    """An ego at 13 m/s stopped to 1.5 m/s within 0.2 s of its crash at 5 s (the phone-filmed ccd_000053's
    ego-motion reads this): braking bounded everywhere spread the stop over the approach (the speed 0.5 s before
    the crash fell by more than 1 m/s); from the impact on the braking is unbounded (a crash stops a car harder than
    its brakes) and the approach keeps its speed, while a speed *rise* after the impact is still bounded."""
    from deepcrashtest.trajectory.alongpath import bounded_distances

    t = np.arange(0.0, 8.0, 0.1)
    speed = np.where(t < 5.0, 13.0, 1.5)
    s = np.concatenate([[0.0], np.cumsum(speed[:-1] * 0.1)])

    def speed_before(d: np.ndarray) -> float:
        return float(np.gradient(d, t)[np.searchsorted(t, 4.5)])

    bounded = bounded_distances(t, s, 3.4, 7.6)
    assert speed_before(bounded) < 12.0  # the stop carried back into the approach
    impact = bounded_distances(t, s, 3.4, 7.6, impact_s=5.0)
    assert abs(speed_before(impact) - 13.0) < 0.05
    assert along_accel(t, impact)[t[1:-1] < 4.95].min() >= -7.6 - 0.02
    rise = np.concatenate([[0.0], np.cumsum(np.where(t < 5.0, 10.0, 13.0)[:-1] * 0.1)])  # 10 -> 13 m/s at 5 s
    assert along_accel(t, bounded_distances(t, rise, 3.4, 7.6, impact_s=5.0)).max() <= 3.4 + 0.02


def test_where_the_lead_in_meets_the_video_the_ego_keeps_within_its_traction():
    """An ego-motion whose first readings run fast (a held scale jumping, then settling: 4.5 m/s with a 3 m/s bump
    over the first 0.5 s, as ccd_000053 filmed off a screen read 5.4 -> 5.8 -> 4.3 m/s): the step-back lead-in ramps
    from rest to the median of the first 0.5 s' speeds and the final spline's start runs faster; where they met the
    ego asked 5.5 m/s^2 (the car's limit 4), which the traction fit left, holding the lead-in. Now the lead-in's last
    ``LEAD_JUNCTION_S`` are re-timed with the video's start; the lead-in's own ramp stays (its speed at t_max)."""
    from deepcrashtest.trajectory.pipeline import process_scenario
    from trajectory_cases import raw_scenario, track

    fine = np.linspace(0.0, 10.0, 10001)
    speed = 4.5 + 3.0 * np.exp(-(((fine - 0.3) / 0.2) ** 2))
    along = np.concatenate([[0.0], np.cumsum(0.5 * (speed[1:] + speed[:-1]) * np.diff(fine))])
    ego = track(lambda t: (np.interp(t, fine, along), np.zeros_like(t)), 0, 60)
    sc = process_scenario(raw_scenario([], ego=ego))
    e = sc.ego.trajectory.arrays()
    accel = np.gradient(e["speed"], e["t"])
    assert accel.max() <= VEHICLE_KINEMATICS.max_accel_mps2  # before: 5.5 m/s^2 at the video's first sample
    lead = e["t"] < sc.scenario_time(0.0) - 0.5
    assert np.all(np.abs(np.diff(accel[lead])) < 0.5)  # the ramp from rest, untouched before its last 0.5 s
