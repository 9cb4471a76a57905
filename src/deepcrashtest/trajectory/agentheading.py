"""A moving road user's processed heading where the video saw it: the raw scenario's (fitted to its boxes).

Stage 2's heading of a moving agent is the direction of its fitted path; a monocular path's direction is
range noise for a slow road user and can be tens of degrees off for a moving one, and its projected 3D box
then comes out wider than the detector's box. Stage 1 fits each agent's heading to its image boxes
(:mod:`deepcrashtest.geometry.box_heading`, pulled towards the direction of motion by its speed): over the
observed span that heading is kept; outside it (extrapolation, step-back lead-in) the path's direction, with
a linear blend over ``blend_s``. Times in seconds (scenario time), angles in radians (world frame).
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np

from deepcrashtest.scenario import Scenario, Vehicle

BLEND_S = 0.5
"""Seconds over which the observed heading hands over to the path's direction outside the observed span."""


def with_observed_yaw(final: Vehicle, raw: Vehicle, t_shift: float, blend_s: float = BLEND_S) -> Vehicle:
    """``final`` (a processed agent) with its heading replaced by ``raw``'s over ``raw``'s span.

    ``t_shift``: scenario time minus the raw scenario's time (s). The raw heading is turned by a half turn
    where it points against the path's direction (a box fits both ways)."""
    a = final.trajectory.arrays()
    r = raw.trajectory.arrays()
    if len(r["t"]) < 2 or len(a["t"]) < 2:
        return final
    yaw = observed_headings(a["t"], np.unwrap(a["yaw"]), r["t"] + t_shift, r["yaw"], blend_s)
    traj = final.trajectory.model_copy(update={"yaw": [float(v) for v in yaw]})
    return final.model_copy(update={"trajectory": traj})


def observed_headings(
    t: np.ndarray, motion: np.ndarray, t_raw: np.ndarray, yaw_raw: np.ndarray, blend_s: float = BLEND_S
) -> np.ndarray:
    """Headings (rad, unwrapped) at times ``t`` (N,) s of a road user whose path runs along ``motion`` (N,) rad:
    ``yaw_raw`` (fitted to its boxes, at the times ``t_raw``, same clock) over ``t_raw``'s span, turned by a
    half turn where it points against the path, handing over to ``motion`` within ``blend_s`` outside it."""
    box = np.interp(t, t_raw, np.unwrap(yaw_raw))
    diff = (box - motion + 0.5 * math.pi) % math.pi - 0.5 * math.pi  # modulo a half turn
    outside = np.maximum(t_raw[0] - t, t - t_raw[-1])
    w = np.clip(1.0 - np.maximum(outside, 0.0) / max(blend_s, 1e-6), 0.0, 1.0)
    return np.unwrap(motion + w * diff)


EPS_T = 1e-3  # seconds
LATERAL_SIGMA_RAD = 0.01
"""A position's error across the line of sight (rad of bearing, 1 sigma, plus ``BASE_SIGMA_M``): where the
box sits in the image (a few pixels of a ~1000 px focal length, with the box centre's own jitter)."""
DEPTH_SIGMA_FRAC = 0.15
"""A position's error along the line of sight (fraction of the range, 1 sigma, plus ``BASE_SIGMA_M``):
monocular range noise."""
BASE_SIGMA_M = 0.1
"""Error (m, 1 sigma) every position has whatever its range (the box centre is not the vehicle's)."""
SIDESLIP_SIGMA_MPS = 0.2
"""Velocity across the heading (m/s, 1 sigma): a vehicle does not move sideways."""
ACCEL_SIGMA_MPS2 = 3.0
"""Acceleration (m/s^2, 1 sigma, each axis): keeps the refitted path as smooth as a vehicle's."""
MIN_SPEED_MPS = 1.0
"""Road users slower than this (median raw speed, m/s) keep their path: they are parked or crawling, and
stage 2 treats them so."""
MAX_RANGE_RMS_SIGMA = 1.0
"""A refit that moves the ranges further than this (RMS, in range sigmas) is not range noise (an ego-motion
that failed, a wrong heading): the path is kept. ccd_000487's standing ego (ego-motion lost) saw a crossing car
approach at 11 m/s; driving it along its heading drew it onto the camera (6.6 sigma)."""
MAX_BEARING_SIGMA = 3.0
"""Nor may it move any position further across the line of sight than this (bearing sigmas)."""
LARGE_MOVE_M = 5.0
"""A refit that moves a position further than this (m) is warned about."""


def step_headings(yaw: np.ndarray) -> np.ndarray:
    """Heading (rad) at the middle of each step between the samples of ``yaw`` (N,) -> (N-1,), modulo a half
    turn (a box's heading fits both ways; only the axis matters here)."""
    d = (np.diff(yaw) + 0.5 * math.pi) % math.pi - 0.5 * math.pi
    return yaw[:-1] + 0.5 * d


def _heading_fit_system(t: np.ndarray, obs: np.ndarray, yaw: np.ndarray, cam: np.ndarray) -> tuple[Any, np.ndarray]:
    """The sparse weighted least-squares system ``A p = b`` of :func:`along_box_heading` over the positions
    ``p`` (2N,: x0, y0, x1, ...), one row per residual (each divided by its sigma)."""
    from scipy import sparse

    n = len(t)
    los = obs - cam
    rng = np.maximum(np.hypot(los[:, 0], los[:, 1]), 1.0)
    u = los / rng[:, None]
    rows: list[np.ndarray] = []
    cols: list[np.ndarray] = []
    vals: list[np.ndarray] = []
    rhs: list[np.ndarray] = []
    r0 = 0
    for axis, sigma in ((u, DEPTH_SIGMA_FRAC * rng), (np.column_stack([-u[:, 1], u[:, 0]]), LATERAL_SIGMA_RAD * rng)):
        coef = axis / (sigma + BASE_SIGMA_M)[:, None]  # where the camera saw it: along, across the line of sight
        rows.append(np.repeat(r0 + np.arange(n), 2))
        cols.append(np.arange(2 * n))
        vals.append(coef.ravel())
        rhs.append((coef * obs).sum(axis=1))
        r0 += n
    dt = np.maximum(np.diff(t), EPS_T)
    mid = step_headings(yaw)
    across = np.column_stack([-np.sin(mid), np.cos(mid)]) / (SIDESLIP_SIGMA_MPS * dt)[:, None]
    j = np.arange(n - 1)  # each step's velocity across the heading
    rows.append(np.repeat(r0 + j, 4))
    cols.append(np.column_stack([2 * j + 2, 2 * j + 3, 2 * j, 2 * j + 1]).ravel())
    vals.append(np.column_stack([across, -across]).ravel())
    rhs.append(np.zeros(n - 1))
    r0 += n - 1
    h = 0.5 * (dt[1:] + dt[:-1])
    fwd, back = 1.0 / (dt[1:] * h * ACCEL_SIGMA_MPS2), 1.0 / (dt[:-1] * h * ACCEL_SIGMA_MPS2)
    k = np.arange(1, n - 1)  # each acceleration, per axis: (v_k - v_{k-1}) / mean step
    for ax in (0, 1):
        rows.append(np.repeat(r0 + np.arange(n - 2), 3))
        cols.append(np.column_stack([2 * (k + 1) + ax, 2 * k + ax, 2 * (k - 1) + ax]).ravel())
        vals.append(np.column_stack([fwd, -fwd - back, back]).ravel())
        rhs.append(np.zeros(n - 2))
        r0 += n - 2
    A = sparse.csr_matrix((np.concatenate(vals), (np.concatenate(rows), np.concatenate(cols))), shape=(r0, 2 * n))
    return A, np.concatenate(rhs)


def along_box_heading(t: np.ndarray, obs: np.ndarray, yaw: np.ndarray, cam: np.ndarray) -> np.ndarray:
    """Positions (N, 2) m that move along the heading ``yaw`` (N,) rad and stay where the camera saw ``obs``.

    Weighted least squares over every position: each observed one is kept within ``LATERAL_SIGMA_RAD`` of its
    bearing from the camera at ``cam`` (N, 2) and ``DEPTH_SIGMA_FRAC`` of its range along it, each step's
    velocity across the heading at its middle within ``SIDESLIP_SIGMA_MPS`` and each acceleration within
    ``ACCEL_SIGMA_MPS2``. The normal equations are banded (SciPy sparse, ``spsolve``). Times ``t`` (N,) s,
    world frame."""
    from scipy.sparse.linalg import spsolve

    if len(t) < 3:
        return obs.copy()
    A, b = _heading_fit_system(t, obs, yaw, cam)
    sol = spsolve((A.T @ A).tocsc(), A.T @ b)
    return np.asarray(sol, dtype=float).reshape(-1, 2)


def moves_in_sigmas(xy: np.ndarray, obs: np.ndarray, cam: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """How far the positions ``xy`` (N, 2) lie from the observed ``obs`` (N, 2) along and across the line of
    sight from the camera at ``cam`` (N, 2), each in its sigma (:data:`DEPTH_SIGMA_FRAC`,
    :data:`LATERAL_SIGMA_RAD`, :data:`BASE_SIGMA_M`): (N,) and (N,), signed."""
    los = obs - cam
    rng = np.maximum(np.hypot(los[:, 0], los[:, 1]), 1.0)
    u = los / rng[:, None]
    d = xy - obs
    along = (d * u).sum(axis=1) / (DEPTH_SIGMA_FRAC * rng + BASE_SIGMA_M)
    across = (d[:, 1] * u[:, 0] - d[:, 0] * u[:, 1]) / (LATERAL_SIGMA_RAD * rng + BASE_SIGMA_M)
    return along, across


def agents_along_box_heading(raw: Scenario, warnings: list[str]) -> Scenario:
    """``raw`` with every moving vehicle's (not a pedestrian's) path refitted to move along its heading
    (fitted to its boxes in stage 1) while staying where the camera saw it (:func:`along_box_heading`):
    a replay drives a vehicle along its path, so a path whose direction is range noise turned the
    replayed box away from the one the video shows (ccd_000487: a car crossing broadside replayed
    pointing at the camera)."""
    e = raw.ego.trajectory.arrays()
    off = raw.camera.forward_offset_m
    eyaw = np.unwrap(e["yaw"])
    agents = []
    for v in raw.agents:
        a = v.trajectory.arrays()
        if v.category == "pedestrian" or len(a["t"]) < 3 or float(np.median(a["speed"])) < MIN_SPEED_MPS:
            agents.append(v)
            continue
        yaw_e = np.interp(a["t"], e["t"], eyaw)
        cam = np.column_stack([np.interp(a["t"], e["t"], e["x"]), np.interp(a["t"], e["t"], e["y"])])
        cam += off * np.column_stack([np.cos(yaw_e), np.sin(yaw_e)])
        obs = np.column_stack([a["x"], a["y"]])
        xy = along_box_heading(a["t"], obs, np.unwrap(a["yaw"]), cam)
        along, across = moves_in_sigmas(xy, obs, cam)
        if float(np.sqrt(np.mean(along**2))) > MAX_RANGE_RMS_SIGMA or float(np.abs(across).max()) > MAX_BEARING_SIGMA:
            warnings.append(
                f"agent {v.id}: its path and its box heading disagree by more than range noise explains "
                f"(range moved {float(np.sqrt(np.mean(along**2))):.1f} sigma RMS); its path is kept"
            )
            agents.append(v)
            continue
        moved = float(np.hypot(*(xy - obs).T).max())
        if moved > LARGE_MOVE_M:
            warnings.append(f"agent {v.id}: moved up to {moved:.1f} m to drive along its heading (range noise)")
        traj = v.trajectory.model_copy(update={"x": xy[:, 0].tolist(), "y": xy[:, 1].tolist()})
        agents.append(v.model_copy(update={"trajectory": traj}))
    return raw.evolve(agents=agents)
