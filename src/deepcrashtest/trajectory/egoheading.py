"""The ego drives where its camera points: its monocular translation re-integrated along the measured yaw.

A dashcam's ego-motion measures the camera's rotation well (image rotation) and the direction of its
translation poorly (parallax of a slow or featureless scene): the raw ego path drifts sideways across
the measured heading (ccd_000132: the path turned 12 deg while the camera turned 1 deg). A car does not
move sideways, and the processed ego's heading is the measured yaw (``pipeline._with_measured_yaw``),
through which every agent was placed; a replay drives the vehicle along its path, so a path that is
not where the camera points turns the replayed camera away from the agents (the replay's reprojection
IoU fell from 0.59 to 0.42 on ccd_000132, 0.67 to 0.46 on ccd_001135).

Here each raw ego step keeps only its component along the (lightly smoothed) measured yaw, and every
agent sample is moved with the ego at its time: the agents were placed relative to the camera, and
stay exactly where the camera saw them (the raw scenario's reprojection is unchanged). Positions in
metres (world frame, x forward, y left), times in seconds, angles in radians.
"""

from __future__ import annotations

import numpy as np

from deepcrashtest.scenario import Scenario, Vehicle

EPS_T = 1e-3  # seconds
LARGE_SHIFT_M = 2.0
"""A re-integration that moves the ego further than this (metres) is warned about."""


def smooth_series(t: np.ndarray, v: np.ndarray, window_s: float) -> np.ndarray:
    """Savitzky-Golay (quadratic) over about ``window_s`` seconds; short series or windows unchanged."""
    from scipy.signal import savgol_filter

    dt = float(np.median(np.diff(t)))
    win = int(round(window_s / max(dt, EPS_T))) | 1
    win = min(win, len(v) if len(v) % 2 else len(v) - 1)
    if win < 5:
        return v.astype(float)
    return np.asarray(savgol_filter(v, win, 2), dtype=float)


MOUNT_SPEED_MPS = 2.0
"""Steps faster than this (m/s) measure the camera's constant yaw relative to the car's travel (its mount)."""


def along_heading(t: np.ndarray, xy: np.ndarray, yaw: np.ndarray) -> np.ndarray:
    """Path (N, 2) whose every step is the step of ``xy`` projected on the heading ``yaw`` (N,) at its middle,
    plus the camera's constant mount yaw (the median offset of the travel from ``yaw`` over steps faster than
    ``MOUNT_SPEED_MPS``: KITTI 0008's ORB-SLAM path runs 0.24 deg off the camera's yaw, 2.4 m over the clip)."""
    if len(t) < 2:
        return xy.copy()
    mid = 0.5 * (yaw[1:] + yaw[:-1])
    d = np.diff(xy, axis=0)
    fast = np.hypot(*d.T) / np.maximum(np.diff(t), EPS_T) > MOUNT_SPEED_MPS
    if fast.sum() >= 5:
        off = (np.arctan2(d[fast, 1], d[fast, 0]) - mid[fast] + np.pi) % (2 * np.pi) - np.pi
        mid = mid + float(np.median(off))
    u = np.column_stack([np.cos(mid), np.sin(mid)])
    along = (np.diff(xy, axis=0) * u).sum(axis=1)
    return xy[0] + np.vstack([np.zeros((1, 2)), np.cumsum(along[:, None] * u, axis=0)])


def ego_along_measured_yaw(raw: Scenario, window_s: float, warnings: list[str]) -> tuple[Scenario, float]:
    """``raw`` with its ego re-integrated along the measured yaw (smoothed over ``window_s``) and every agent
    moved with it (see the module docstring); returns it and the largest shift of the ego (metres)."""
    e = raw.ego.trajectory.arrays()
    t, yaw = e["t"], np.unwrap(e["yaw"])
    if len(t) < 2 or not np.all(np.isfinite(yaw)):
        return raw, 0.0
    xy = np.column_stack([e["x"], e["y"]])
    shift = along_heading(t, xy, smooth_series(t, yaw, window_s)) - xy
    largest = float(np.hypot(*shift.T).max())
    if largest < 1e-6:
        return raw, 0.0
    if largest > LARGE_SHIFT_M:
        warnings.append(
            f"ego: its measured path ran up to {largest:.1f} m sideways of where the camera pointed; it is "
            "re-integrated along the camera's heading, the agents moved with it (as the camera saw them)"
        )

    return carry_with_ego(raw, t, shift), largest


def carry_with_ego(raw: Scenario, t: np.ndarray, shift: np.ndarray) -> Scenario:
    """``raw`` with the ego and every agent moved by ``shift`` (N, 2) metres, given at the ego's sample times
    ``t`` (N,) s and interpolated at each vehicle's own: the agents were placed relative to the camera and
    stay where the camera saw them when the ego's path is corrected."""

    def moved(v: Vehicle) -> Vehicle:
        a = v.trajectory.arrays()
        dx, dy = np.interp(a["t"], t, shift[:, 0]), np.interp(a["t"], t, shift[:, 1])
        traj = v.trajectory.model_copy(update={"x": (a["x"] + dx).tolist(), "y": (a["y"] + dy).tolist()})
        return v.model_copy(update={"trajectory": traj})

    return raw.evolve(ego=moved(raw.ego), agents=[moved(a) for a in raw.agents])
