"""Hand-built raw Scenarios with known answers for the stage-2 tests (straight road along world x)."""

from __future__ import annotations

from collections.abc import Callable

import numpy as np

from deepcrashtest.scenario import Camera, Road, Scenario, Trajectory, Vehicle, VideoSource

FPS = 10.0
EGO_SPEED = 10.0
DURATION = 10.0

Path = Callable[[np.ndarray], tuple[np.ndarray, np.ndarray]]


def track(path: Path, f0: int, f1: int, yaw: float | None = None, noise: float = 0.0, seed: int = 0) -> Trajectory:
    """Samples of ``path(t) -> (x, y)`` at frames f0..f1 (inclusive), optional Gaussian noise (metres)."""
    t = np.arange(f0, f1 + 1) / FPS
    x, y = (np.broadcast_to(np.asarray(c, float), t.shape).copy() for c in path(t))
    if noise:
        rng = np.random.default_rng(seed)
        x += rng.normal(0, noise, len(t))
        y += rng.normal(0, noise, len(t))
    if yaw is None:
        yaw_arr = np.arctan2(np.gradient(y, t), np.gradient(x, t)) if len(t) > 1 else np.zeros(1)
    else:
        yaw_arr = np.full(len(t), yaw)
    speed = np.hypot(np.gradient(x, t), np.gradient(y, t)) if len(t) > 1 else np.zeros(1)
    return Trajectory.from_arrays(t, x, y, yaw_arr, speed, observed=np.ones(len(t), bool))


def vehicle(vid: int, traj: Trajectory, **kw) -> Vehicle:  # type: ignore[no-untyped-def]
    return Vehicle(
        id=vid,
        first_frame=int(round(traj.t[0] * FPS)),
        last_frame=int(round(traj.t[-1] * FPS)),
        trajectory=traj,
        **kw,
    )


def ego_path(t: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    return EGO_SPEED * t, np.zeros_like(t)


def raw_scenario(agents: list[Vehicle], ego: Trajectory | None = None, **kw) -> Scenario:  # type: ignore[no-untyped-def]
    ego_tr = ego if ego is not None else track(ego_path, 0, int(DURATION * FPS))
    n = len(ego_tr)
    return Scenario(
        name="hand_built",
        stage="raw",
        source=VideoSource(kind="synthetic", path="hand-built", fps=FPS, frame_count=n, width=1280, height=720),
        camera=Camera(fx=1000, fy=1000, cx=640, cy=360),
        ego=Vehicle(id=0, first_frame=0, last_frame=n - 1, trajectory=ego_tr),
        agents=agents,
        road=Road(centerline_x=[0.0, 100.0], centerline_y=[0.0, 0.0]),
        **kw,
    )


# one agent per class, each with its known answer (ids: 1..7); lanes: right y=-3.5, left y=+3.5
CLASS_CASES: dict[str, Vehicle] = {
    # same direction, ahead from the first frame, whole video
    "D0T1": vehicle(1, track(lambda t: (20 + EGO_SPEED * t, -3.5 + 0 * t), 0, 100)),
    # overtakes in the left lane: first seen at frame 80 five metres ahead, 4 m/s faster
    "D0T2": vehicle(2, track(lambda t: (EGO_SPEED * t + 5 + 4 * (t - 8), 3.5 + 0 * t), 80, 100)),
    # slower car far ahead in the right lane, comes into view at frame 30
    "D0T3": vehicle(3, track(lambda t: (90 + 6 * (t - 3), -3.5 + 0 * t), 30, 100)),
    # oncoming, in view at start, leaves the view 10 m ahead at 2.5 s; the ego passes it at 3 s
    "D1T1": vehicle(4, track(lambda t: (60 - 10 * t, 3.5 + 0 * t), 0, 25)),
    # oncoming, in view at start, far away: not passed by the end (10 s)
    "D1T2": vehicle(5, track(lambda t: (400 - 10 * t, 3.5 + 0 * t), 0, 30)),
    # oncoming, appears at 2 s, passed at ~6 s
    "D1T3": vehicle(6, track(lambda t: (120 - 10 * (t - 2), 3.5 + 0 * t), 20, 50)),
    # oncoming, appears at 5 s far ahead, not passed by the end
    "D1T4": vehicle(7, track(lambda t: (400 - 10 * (t - 5), 3.5 + 0 * t), 50, 80)),
}
