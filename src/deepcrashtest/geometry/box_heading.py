"""Road users' headings that fit their image boxes: the direction of motion where it is measured, the
box's shape where it is not.

A monocular track's direction of motion is the derivative of noisy ranges: for a parked or slow road
user it is noise (the raw heading then falls back to the ego's), and even a moving one's can be off by
tens of degrees. The box says more: at a known position and size, the width of a road user's projected
3D box changes with its heading (a car seen from behind is ~1.8 m wide, seen side-on ~4.4 m). On the
fidelity clips the projected boxes of the raw headings were 1.2-1.4x wider than the detector's.

Per agent, each detected box (video frame) scores every heading of a grid (``GRID`` steps over 180 deg:
a box's footprint is symmetric under a half turn) by the IoU of the projected 3D box's horizontal span
(columns) with the tracked box's (the rows depend on the camera pitch and the road, not on the heading);
the heading track is the Viterbi path that maximises

    - sum_t 0.5 ((1 - IoU_t(psi_t)) / s_t)^2 - motion_t(psi_t) - axis_t(psi_t) - sum_t turn(psi_t - psi_{t-1})

where ``s_t`` is how far the box's best heading still falls short of a perfect fit (``1 - max_psi IoU_t``,
kept within ``IOU_SIGMA_MIN``..``IOU_SIGMA_MAX``): a box fits only as well as the position and size it is
projected from, and where those are off (a monocular range, a class's size) its IoU differences between
headings say less;  ``motion_t`` pulls towards the direction of motion with a weight growing with the speed (its
direction is uncertain by ~``MOTION_NOISE_MPS`` / speed), ``axis_t`` weakly towards the road's axes
(along or across the ego's heading: the box's width is the same for headings mirrored about the line
of sight) and ``turn`` keeps the heading from turning
faster than a road user does (``TURN_SIGMA_RAD_S`` per second, 1 sigma). The half-turn ambiguity is
resolved once per track, towards the raw heading (the direction of motion where the speed measures it, or
the ego's for a parked one): :func:`one_way_round`. Samples between fitted frames (not detected, cut by the
near plane) are interpolated; before the first and after the last they hold its heading.

Inputs and outputs are in the world frame of :mod:`deepcrashtest.scenario` (x forward, y left, metres,
radians CCW); boxes are pixels of the full frame, ``x1, y1, x2, y2``.
"""

from __future__ import annotations

import math

import numpy as np
import pandas as pd

from deepcrashtest.geometry.project import camera_rotation, project_camera_points, scenario_poses
from deepcrashtest.scenario import Camera, Scenario, Vehicle

#: Heading candidates over a half turn.
GRID = 36
#: Bounds of one box's span-IoU noise (1 sigma; the box's own shortfall from a perfect fit within them). Chosen
#: on KITTI's 18 training sequences (not 3, 8, 10) against the labelled headings: the monocular path's matched
#: cars, median error standing / 1-3 / 3-8 / >= 8 m/s 14.7 / 18.4 / 5.4 / 2.5 deg -> 9.1 / 5.8 / 3.3 / 2.2
#: (before, a reward linear in the IoU, 10 per 0.1 IoU, let a 5 % narrower box outweigh a 30 deg turn from
#: the direction of motion); with true positions and sizes (KITTI 0011) the boxes' own evidence stays strong
#: (a residual of ~0.03): median 1.2 deg.
IOU_SIGMA_MIN = 0.03
IOU_SIGMA_MAX = 0.3
#: Speed noise of a monocular track (m/s): the direction of motion is uncertain by atan(noise / speed).
MOTION_NOISE_MPS = 2.0
#: Pull towards the road's axes (the ego's heading or across it, rad, 1 sigma): a box's width alone cannot
#: tell a heading ``d`` right of the line of sight from one ``d`` left of it (a car parked along the road,
#: seen 25 deg off-axis, fits as well turned 50 deg); road users mostly drive or park along or across the road.
ROAD_AXIS_SIGMA_RAD = math.radians(20.0)
#: How fast a road user's heading may change (rad/s, 1 sigma).
TURN_SIGMA_RAD_S = 0.5
#: Corners nearer than this in front of the camera (m): the box is not scored (clipped hulls mislead).
MIN_DEPTH_M = 1.0


def hull_boxes(
    camera: Camera,
    ego: np.ndarray,
    pos: np.ndarray,
    yaws: np.ndarray,
    size: tuple[float, float, float],
    image_size: tuple[int, int],
) -> tuple[np.ndarray, np.ndarray]:
    """Enclosing 2D boxes (N, K, 4) px of a road user at ``pos`` (N, 2) world m with headings ``yaws`` (K,)
    rad seen by the ego at ``ego`` (N, 3: x, y, yaw), clipped to the image; and (N,) whether every corner
    lies at least ``MIN_DEPTH_M`` in front of the camera (else the row's boxes are not meaningful)."""
    length, width, height = size
    hl, hw = 0.5 * length, 0.5 * width
    local = np.array([[hl, hw], [hl, -hw], [-hl, -hw], [-hl, hw]])  # (4, 2)
    c, s = np.cos(yaws), np.sin(yaws)
    rot = np.stack([np.stack([c, s], -1), np.stack([-s, c], -1)], 1)  # (K, 2, 2): row-vector rotation
    foot = np.einsum("cj,kjl->kcl", local, rot)  # (K, 4, 2)
    xy = pos[:, None, None, :] + foot[None]  # (N, K, 4, 2)
    ce, se = np.cos(ego[:, 2]), np.sin(ego[:, 2])
    cam_x = ego[:, 0] + camera.forward_offset_m * ce
    cam_y = ego[:, 1] + camera.forward_offset_m * se
    dx = xy[..., 0] - cam_x[:, None, None]
    dy = xy[..., 1] - cam_y[:, None, None]
    fwd = ce[:, None, None] * dx + se[:, None, None] * dy
    left = -se[:, None, None] * dx + ce[:, None, None] * dy
    pts = []
    for z in (0.0, height):
        pts.append(np.stack([-left, np.full_like(fwd, camera.height_m - z), fwd], -1))
    level = np.concatenate(pts, axis=2)  # (N, K, 8, 3)
    cam = level @ camera_rotation(camera).T
    ok = (cam[..., 2] >= MIN_DEPTH_M).all(axis=(1, 2))
    box = np.zeros((*cam.shape[:2], 4))
    if ok.any():
        uv = project_camera_points(cam[ok].reshape(-1, 3), camera).reshape(int(ok.sum()), *cam.shape[1:3], 2)
        lo, hi = uv.min(axis=2), uv.max(axis=2)  # (n, K, 2)
        w, h = image_size
        box[ok] = np.clip(np.concatenate([lo, hi], axis=-1), 0, [w, h, w, h])
    return box, ok


def span_iou(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Element-wise IoU of the horizontal spans (``x1``, ``x2``: columns 0 and 2) of boxes ``a`` and ``b``
    (broadcast); 0 for empty spans. Rows are left out: a road user's vertical place in the image is the
    camera pitch's and the road's business, its heading shows in its width and horizontal place."""
    inter = np.clip(np.minimum(a[..., 2], b[..., 2]) - np.maximum(a[..., 0], b[..., 0]), 0, None)
    union = np.maximum(a[..., 2], b[..., 2]) - np.minimum(a[..., 0], b[..., 0])
    return np.where(union > 0, inter / np.where(union > 0, union, 1.0), 0.0)


def viterbi_headings(score: np.ndarray, dt: np.ndarray, grid: np.ndarray, turn_sigma: float) -> np.ndarray:
    """Indices (N,) into ``grid`` (K,) rad (a half turn) maximising ``sum score[t, k]`` minus the turn
    penalty ``0.5 (d / (turn_sigma dt))^2`` between consecutive rows (``d`` the heading change modulo a
    half turn, ``dt`` (N-1,) s)."""
    n, k = score.shape
    d = grid[:, None] - grid[None, :]
    d = (d + 0.5 * math.pi) % math.pi - 0.5 * math.pi  # (K, K) change modulo a half turn
    best = score[0].copy()
    back = np.zeros((n, k), dtype=int)
    for t in range(1, n):
        pen = 0.5 * (d / (turn_sigma * max(float(dt[t - 1]), 1e-3))) ** 2
        cand = best[None, :] - pen  # [to, from]
        back[t] = cand.argmax(axis=1)
        best = cand[np.arange(k), back[t]] + score[t]
    path = np.zeros(n, dtype=int)
    path[-1] = int(best.argmax())
    for t in range(n - 1, 0, -1):
        path[t - 1] = back[t, path[t]]
    return path


def agent_headings(
    agent: Vehicle,
    boxes: pd.DataFrame,
    ego_pose: np.ndarray,
    camera: Camera,
    image_size: tuple[int, int],
) -> np.ndarray | None:
    """Fitted headings (rad) at the agent's trajectory samples, or None when no box can be scored.

    ``boxes``: the agent's tracked boxes (``x1..y2`` px) with ``t`` (its trajectory's times, s) for the
    detected frames; ``ego_pose`` (len(boxes), 3) the ego's pose at those times."""
    a = agent.trajectory.arrays()
    t_box = boxes["t"].to_numpy(float)
    pos = np.column_stack([np.interp(t_box, a["t"], a["x"]), np.interp(t_box, a["t"], a["y"])])
    grid = np.linspace(0.0, math.pi, GRID, endpoint=False)
    hull, ok = hull_boxes(camera, ego_pose, pos, grid, (agent.length, agent.width, agent.height), image_size)
    if not ok.any():
        return None
    tracked = boxes[["x1", "y1", "x2", "y2"]].to_numpy(float)[ok]
    hull, t_box = hull[ok], t_box[ok]
    iou = span_iou(hull, tracked[:, None, :])  # (N, K)
    yaw_m = np.interp(t_box, a["t"], np.unwrap(a["yaw"]))
    speed = np.interp(t_box, a["t"], a["speed"])
    sigma_m = np.arctan2(MOTION_NOISE_MPS, np.maximum(speed, 1e-3))  # rad
    dpsi = (grid[None, :] - yaw_m[:, None] + 0.5 * math.pi) % math.pi - 0.5 * math.pi
    daxis = (grid[None, :] - ego_pose[ok, 2][:, None] + 0.25 * math.pi) % (0.5 * math.pi) - 0.25 * math.pi
    iou_sigma = np.clip(1.0 - iou.max(axis=1, keepdims=True), IOU_SIGMA_MIN, IOU_SIGMA_MAX)
    box = -0.5 * ((1.0 - iou) / iou_sigma) ** 2
    score = box - 0.5 * (dpsi / sigma_m[:, None]) ** 2 - 0.5 * (daxis / ROAD_AXIS_SIGMA_RAD) ** 2
    path = viterbi_headings(score, np.diff(t_box), grid, TURN_SIGMA_RAD_S)
    psi = one_way_round(np.unwrap(grid[path], period=math.pi), yaw_m, speed)
    return np.interp(a["t"], t_box, psi)  # between fitted frames linear, before / after them held


def one_way_round(psi: np.ndarray, yaw_motion: np.ndarray, speed: np.ndarray) -> np.ndarray:
    """``psi`` (N,) rad, continuous modulo a half turn, or ``psi + pi``: the one whose direction agrees better
    with the direction of motion ``yaw_motion`` (N,) rad, each sample weighted by how well its speed (m/s)
    measures that direction (``speed^2 / (speed^2 + MOTION_NOISE_MPS^2)``).

    One choice for the whole track: a road user's body does not turn half round between two frames, while a
    slow one's direction of motion does (range noise, reversing); turning each frame towards it spun parked and
    crawling cars half round in the scenario (17 raw tracks of the 20 fidelity clips)."""
    w = speed**2 / (speed**2 + MOTION_NOISE_MPS**2) + 1e-3  # a parked one's: towards its raw heading
    return psi if float(np.sum(w * np.cos(psi - yaw_motion))) >= 0.0 else psi + math.pi


def fit_box_headings(scenario: Scenario, tracks: pd.DataFrame) -> Scenario:
    """The raw scenario with every agent's heading fitted to its detected boxes (module docstring).

    ``tracks``: the image tracker's table (``frame``, ``track_id``, ``x1..y2``, ``state``); a track's id
    is its agent's id. Agents without a scorable box keep their headings."""
    if not len(tracks) or not scenario.agents:
        return scenario
    det = tracks if "state" not in tracks.columns else tracks[tracks["state"] == "detected"]
    pose = scenario_poses(scenario)
    size = (scenario.source.width, scenario.source.height)
    agents = []
    for agent in scenario.agents:
        rows = det[det["track_id"] == agent.id].drop_duplicates("frame").sort_values("frame")
        t = np.array([scenario.frame_time(int(f)) for f in rows["frame"]])
        a0, a1 = agent.trajectory.t[0], agent.trajectory.t[-1]
        poses = [pose(0, float(v)) if a0 - 1e-6 <= v <= a1 + 1e-6 else None for v in t]
        keep = np.array([p is not None for p in poses], dtype=bool)
        if not keep.any():
            agents.append(agent)
            continue
        sel = rows[keep].assign(t=t[keep])
        ego = np.array([p for p in poses if p is not None], dtype=float)
        yaw = agent_headings(agent, sel, ego, scenario.camera, size)
        if yaw is None:
            agents.append(agent)
            continue
        traj = agent.trajectory.model_copy(update={"yaw": [float(v) for v in yaw]})
        agents.append(agent.model_copy(update={"trajectory": traj}))
    return scenario.evolve(agents=agents)
