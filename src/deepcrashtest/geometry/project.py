"""Project road users' 3D boxes into the original camera (pure geometry, no I/O).

Frames (see :mod:`deepcrashtest.scenario`):

* World: x forward (the ego's initial heading), y left, z up, metres; the road is ``z = 0``.
* Ego pose ``(x, y, yaw)``: the ego centre on the road and its heading (radians, CCW from +x).
* The camera sits ``camera.forward_offset_m`` ahead of the ego centre along its heading,
  ``camera.height_m`` above the road, pitched down by ``camera.pitch_rad`` and rolled by
  ``camera.roll_rad`` about its optical axis, turned ``camera.yaw_rad`` left of the ego's heading (the convention of
  :mod:`deepcrashtest.geometry.egomotion`: a level-camera vector ``v`` reads ``Rz(roll) Rx(pitch) v``).
* Camera: x right, y down, z forward; image u right, v down, pixels of the full frame.

A road user's box is its ground footprint (centre ``x, y``, heading ``yaw``, ``length`` x ``width``)
extruded up by ``height``. Boxes partly behind the camera are clipped at the near plane
(``z = near_m``) before the enclosing 2D box is taken; boxes wholly behind give no 2D box.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from deepcrashtest.scenario import Camera, Scenario

NEAR_M = 0.1
"""Near clipping plane, metres in front of the camera."""
EDGE_SAMPLES = np.linspace(0.0, 1.0, 9)[1:-1]
"""Where a distorting lens's box edges are sampled between their corners (share of each edge)."""

#: The 12 edges of a box, as pairs of :func:`box_corners_world` corner indices.
BOX_EDGES = np.array(
    [[0, 1], [1, 2], [2, 3], [3, 0], [4, 5], [5, 6], [6, 7], [7, 4], [0, 4], [1, 5], [2, 6], [3, 7]], dtype=int
)


@dataclass(frozen=True)
class ProjectedBox:
    """One road user in the image.

    ``corners``: (8, 2) pixels of the box corners (NaN for corners at or behind the near plane);
    ``box``: the enclosing 2D box ``[x1, y1, x2, y2]`` of the near-plane-clipped box (clipped to
    the image when its size was given), or None when no part of the box is in front of the camera
    (or inside the image); ``depth_m``: distance of the box centre in front of the camera (metres,
    may be negative).
    """

    corners: np.ndarray
    box: np.ndarray | None
    depth_m: float


def box_corners_world(
    x: float, y: float, yaw: float, length: float, width: float, height: float, z0: float = 0.0
) -> np.ndarray:
    """(8, 3) world corners of a box: bottom face first (front-left, front-right, rear-right,
    rear-left), then the top face in the same order. ``z0``: height of the box's bottom (metres)."""
    c, s = math.cos(yaw), math.sin(yaw)
    hl, hw = 0.5 * length, 0.5 * width
    local = np.array([[hl, hw], [hl, -hw], [-hl, -hw], [-hl, hw]])
    xy = local @ np.array([[c, s], [-s, c]]) + [x, y]
    bottom = np.column_stack([xy, np.full(4, z0)])
    top = np.column_stack([xy, np.full(4, z0 + height)])
    return np.vstack([bottom, top])


def camera_rotation(camera: Camera) -> np.ndarray:
    """3x3 rotation taking a level camera's coordinates (x right, y down, z forward) to the camera's."""
    cp, sp = math.cos(camera.pitch_rad), math.sin(camera.pitch_rad)
    cr, sr = math.cos(camera.roll_rad), math.sin(camera.roll_rad)
    rx = np.array([[1.0, 0.0, 0.0], [0.0, cp, -sp], [0.0, sp, cp]])
    rz = np.array([[cr, -sr, 0.0], [sr, cr, 0.0], [0.0, 0.0, 1.0]])
    return rz @ rx


def world_to_camera(points: np.ndarray, camera: Camera, ego_x: float, ego_y: float, ego_yaw: float) -> np.ndarray:
    """(N, 3) world points (metres) -> (N, 3) camera-frame points for the ego at ``(ego_x, ego_y, ego_yaw)``; the
    camera sits ``forward_offset_m`` ahead of the ego's centre along its heading and looks ``camera.yaw_rad`` left
    of it."""
    p = np.asarray(points, dtype=float).reshape(-1, 3)
    c, s = math.cos(ego_yaw), math.sin(ego_yaw)
    cam_x = ego_x + camera.forward_offset_m * c
    cam_y = ego_y + camera.forward_offset_m * s
    if camera.yaw_rad:
        c, s = math.cos(ego_yaw + camera.yaw_rad), math.sin(ego_yaw + camera.yaw_rad)
    dx, dy = p[:, 0] - cam_x, p[:, 1] - cam_y
    fwd = c * dx + s * dy
    left = -s * dx + c * dy
    level = np.column_stack([-left, camera.height_m - p[:, 2], fwd])
    return level @ camera_rotation(camera).T


def project_camera_points(points_cam: np.ndarray, camera: Camera) -> np.ndarray:
    """(N, 3) camera-frame points -> (N, 2) pixels (NaN where ``z <= 0``); OpenCV lens distortion applied."""
    p = np.asarray(points_cam, dtype=float).reshape(-1, 3)
    out = np.full((len(p), 2), np.nan)
    front = p[:, 2] > 1e-9
    if not front.any():
        return out
    q = p[front]
    if camera.distortion:
        import cv2

        img, _ = cv2.projectPoints(q, np.zeros(3), np.zeros(3), camera.matrix(), np.asarray(camera.distortion))
        out[front] = img.reshape(-1, 2)
    else:
        out[front, 0] = camera.fx * q[:, 0] / q[:, 2] + camera.cx
        out[front, 1] = camera.fy * q[:, 1] / q[:, 2] + camera.cy
    return out


def clip_edges_near(points_cam: np.ndarray, near_m: float = NEAR_M, edges: np.ndarray = BOX_EDGES) -> np.ndarray:
    """Camera-frame points of a box clipped at the plane ``z = near_m``: the corners in front of it
    plus the points where the box's edges cross it. (K, 3), K = 0 when all lies behind."""
    p = np.asarray(points_cam, dtype=float)
    keep = [p[p[:, 2] >= near_m]]
    a, b = p[edges[:, 0]], p[edges[:, 1]]
    cross = (a[:, 2] - near_m) * (b[:, 2] - near_m) < 0
    if cross.any():
        a, b = a[cross], b[cross]
        f = (near_m - a[:, 2]) / (b[:, 2] - a[:, 2])
        keep.append(a + f[:, None] * (b - a))
    return np.vstack(keep)


def project_box(
    camera: Camera,
    ego_pose: tuple[float, float, float],
    x: float,
    y: float,
    yaw: float,
    length: float,
    width: float,
    height: float,
    z0: float = 0.0,
    image_size: tuple[int, int] | None = None,
    near_m: float = NEAR_M,
) -> ProjectedBox:
    """Project one road user's box for the ego at ``ego_pose = (x, y, yaw)`` (world, m, rad).

    ``image_size = (width, height)`` pixels clips the 2D box to the image (None when it falls
    outside). See :class:`ProjectedBox`.
    """
    corners_w = box_corners_world(x, y, yaw, length, width, height, z0)
    cam = world_to_camera(corners_w, camera, *ego_pose)
    corners = project_camera_points(np.where(cam[:, 2:3] >= near_m, cam, np.nan), camera)
    depth = float(cam[:, 2].mean())
    clipped = clip_edges_near(cam, near_m)
    if len(clipped) == 0:
        return ProjectedBox(corners, None, depth)
    if camera.distortion:  # a lens bows the edges: the box is around the whole of each edge, not its corners
        a, b = cam[BOX_EDGES[:, 0]], cam[BOX_EDGES[:, 1]]
        dense = (a[None] + EDGE_SAMPLES[:, None, None] * (b - a)[None]).reshape(-1, 3)
        clipped = np.vstack([clipped, dense[dense[:, 2] >= near_m]])
    uv = project_camera_points(clipped, camera)
    box = np.array([uv[:, 0].min(), uv[:, 1].min(), uv[:, 0].max(), uv[:, 1].max()])
    if image_size is not None:
        w, h = image_size
        box = np.array([max(box[0], 0.0), max(box[1], 0.0), min(box[2], float(w)), min(box[3], float(h))])
        if box[2] <= box[0] or box[3] <= box[1]:
            return ProjectedBox(corners, None, depth)
    return ProjectedBox(corners, box, depth)


def project_box_edges(
    camera: Camera,
    ego_pose: tuple[float, float, float],
    x: float,
    y: float,
    yaw: float,
    length: float,
    width: float,
    height: float,
    z0: float = 0.0,
    near_m: float = NEAR_M,
) -> np.ndarray:
    """(K, 2, 2) pixel segments of the box's edges that lie (partly) in front of the near plane,
    each clipped at it: what to draw of a 3D box. Edge order follows :data:`BOX_EDGES`."""
    cam = world_to_camera(box_corners_world(x, y, yaw, length, width, height, z0), camera, *ego_pose)
    a, b = cam[BOX_EDGES[:, 0]], cam[BOX_EDGES[:, 1]]
    keep = (a[:, 2] >= near_m) | (b[:, 2] >= near_m)
    a, b = a[keep], b[keep]
    for p, q in ((a, b), (b, a)):  # move the endpoint behind the plane onto it
        behind = p[:, 2] < near_m
        f = (near_m - p[behind, 2]) / (q[behind, 2] - p[behind, 2])
        p[behind] = p[behind] + f[:, None] * (q[behind] - p[behind])
    uv = project_camera_points(np.vstack([a, b]), camera)
    return np.stack([uv[: len(a)], uv[len(a) :]], axis=1)


Pose = tuple[float, float, float]
#: Pose (x, y, yaw) of a road user at scenario time t, or None where it is absent.
PoseFn = Callable[[int, float], Pose | None]


def scenario_poses(scenario: Scenario) -> PoseFn:
    """Poses from the scenario's own trajectories (absent outside each one's span and before its start delay)."""
    arrays = {v.id: (v.trajectory.arrays(), v.start_delay_s) for v in scenario.vehicles()}

    def pose(vid: int, t: float) -> Pose | None:
        a, delay = arrays[vid]
        if t < a["t"][0] - 1e-9 or t > a["t"][-1] + 1e-9 or t < delay - 1e-9:
            return None
        return (
            float(np.interp(t, a["t"], a["x"])),
            float(np.interp(t, a["t"], a["y"])),
            float(np.interp(t, a["t"], a["yaw"])),
        )

    return pose
