"""First contact between the ego's and an agent's oriented boxes (shapely), world frame.

Boxes are centred on the trajectory points, ``length`` along the heading and ``width`` across
(metres). The overlap is tested at the ego's sample times where the agent exists (the agent's
state linearly interpolated), then the first contact time is refined by bisection between the
last separated and the first overlapping sample.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from functools import cached_property
from typing import TYPE_CHECKING

import numpy as np
import shapely

from deepcrashtest.scenario import heading_axis, interp_heading_axis

if TYPE_CHECKING:
    from deepcrashtest.scenario import Vehicle

CHECK_STEP_S = 0.02
"""Contacts are checked at least this often (s), the simulator's step: between two video frames 0.1 s apart two
road users 3 m/s apart can graze and part again (ccd_000031 mirrored: two vans 8 cm deep 0.05 s before the crash,
the replay's first contact)."""
MOVING_MPS = 0.3  # below this speed the heading is taken from the neighbouring samples


def headings(t: np.ndarray, xy: np.ndarray, fallback: float, vel: np.ndarray | None = None) -> np.ndarray:
    """Unwrapped heading (radians) of the motion; where slower than 0.3 m/s, the nearest moving sample's
    heading (``fallback`` if it never moves)."""
    if vel is None:
        vel = np.column_stack([np.gradient(xy[:, 0], t), np.gradient(xy[:, 1], t)]) if len(t) > 1 else np.zeros((1, 2))
    pick = heading_sources(vel)
    if pick is None:
        return np.full(len(t), fallback)
    moving = np.hypot(vel[:, 0], vel[:, 1]) > MOVING_MPS
    yaw = np.unwrap(np.arctan2(vel[moving, 1], vel[moving, 0]))
    out = yaw[np.searchsorted(np.nonzero(moving)[0], pick)]
    return np.unwrap(out)


def heading_sources(vel: np.ndarray) -> np.ndarray | None:
    """For each sample of velocities ``vel`` (N, 2) m/s, the index of the sample whose direction of motion
    is its heading (itself where faster than :data:`MOVING_MPS`, else the nearest such); None if none is."""
    moving = np.hypot(vel[:, 0], vel[:, 1]) > MOVING_MPS
    if not moving.any():
        return None
    n = len(vel)
    idx = np.nonzero(moving)[0]
    nearest = idx[np.clip(np.searchsorted(idx, np.arange(n)), 0, len(idx) - 1)]
    prev = idx[np.clip(np.searchsorted(idx, np.arange(n)) - 1, 0, len(idx) - 1)]
    return np.where(np.abs(prev - np.arange(n)) < np.abs(nearest - np.arange(n)), prev, nearest)


@dataclass(frozen=True)
class Contact:
    time_s: float
    x: float
    y: float
    relative_speed: float


@dataclass(frozen=True)
class BoxTrack:
    """Dense states of one vehicle: t (s), x, y (m), yaw (rad, unwrapped), its box size (m)."""

    t: np.ndarray
    x: np.ndarray
    y: np.ndarray
    yaw: np.ndarray
    length: float
    width: float

    @cached_property
    def _heading_axis(self) -> tuple[np.ndarray, np.ndarray]:
        return heading_axis(self.yaw)  # unwrapped once: a contact search samples a track thousands of times

    def at(self, t: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Centre x, y (m) and heading (rad, :func:`~deepcrashtest.scenario.interp_heading`) at times ``t`` (s)."""
        return *self.centre_at(t), interp_heading_axis(t, self.t, *self._heading_axis)

    def centre_at(self, t: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Centre x, y (m) at times ``t`` (s)."""
        return np.interp(t, self.t, self.x), np.interp(t, self.t, self.y)

    def velocity(self, t: float) -> np.ndarray:
        vx = np.interp(t, self.t, np.gradient(self.x, self.t)) if len(self.t) > 1 else 0.0
        vy = np.interp(t, self.t, np.gradient(self.y, self.t)) if len(self.t) > 1 else 0.0
        return np.array([vx, vy], dtype=float)


def vehicle_box(v: Vehicle, margin_m: float = 0.0) -> BoxTrack:
    """A scenario vehicle's box at its trajectory samples (world frame), ``margin_m`` (m) larger on each side."""
    a = v.trajectory.arrays()
    return BoxTrack(a["t"], a["x"], a["y"], np.unwrap(a["yaw"]), v.length + 2 * margin_m, v.width + 2 * margin_m)


def boxes(x: np.ndarray, y: np.ndarray, yaw: np.ndarray, length: float, width: float) -> np.ndarray:
    """Shapely polygons (N,) of oriented boxes."""
    c, s = np.cos(yaw), np.sin(yaw)
    hl, hw = length / 2, width / 2
    corners = np.array([[hl, hw], [-hl, hw], [-hl, -hw], [hl, -hw]])
    px = x[:, None] + corners[None, :, 0] * c[:, None] - corners[None, :, 1] * s[:, None]
    py = y[:, None] + corners[None, :, 0] * s[:, None] + corners[None, :, 1] * c[:, None]
    return shapely.polygons(np.stack([px, py], axis=-1))


def overlaps(a: BoxTrack, b: BoxTrack, t: np.ndarray) -> np.ndarray:
    pa = boxes(*a.at(t), a.length, a.width)
    pb = boxes(*b.at(t), b.length, b.width)
    return np.asarray(shapely.intersects(pa, pb), dtype=bool)


def within_reach(a: BoxTrack, b: BoxTrack, t: np.ndarray, margin_m: float = 0.0) -> np.ndarray:
    """Whether the two boxes' centres are within the sum of their half diagonals plus ``margin_m`` (m) at times
    ``t`` (s): farther apart, the boxes cannot touch, nor come within ``margin_m`` of touching."""
    xa, ya = a.centre_at(t)
    xb, yb = b.centre_at(t)
    reach = 0.5 * (math.hypot(a.length, a.width) + math.hypot(b.length, b.width)) + margin_m
    return np.hypot(xa - xb, ya - yb) <= reach + 1e-9


def first_contact(ego: BoxTrack, agent: BoxTrack, t_from: float = -np.inf, tol_s: float = 1e-3) -> Contact | None:
    """Earliest time >= ``t_from`` at which the two boxes touch (None if they never do)."""
    lo, hi = max(ego.t[0], agent.t[0], t_from), min(ego.t[-1], agent.t[-1])
    if hi < lo:
        return None
    t = np.unique(np.concatenate([[lo], ego.t[(ego.t > lo) & (ego.t < hi)], np.arange(lo, hi, CHECK_STEP_S), [hi]]))
    hit = np.zeros(len(t), dtype=bool)
    near = within_reach(ego, agent, t)  # boxes farther apart than their half diagonals cannot touch
    hit[near] = overlaps(ego, agent, t[near])
    if not hit.any():
        return None
    k = int(np.argmax(hit))
    if k == 0:
        tc = float(t[0])
    else:
        a, b = float(t[k - 1]), float(t[k])
        while b - a > tol_s:
            m = 0.5 * (a + b)
            if overlaps(ego, agent, np.array([m]))[0]:
                b = m
            else:
                a = m
        tc = b
    pa = boxes(*ego.at(np.array([tc])), ego.length, ego.width)[0]
    pb = boxes(*agent.at(np.array([tc])), agent.length, agent.width)[0]
    inter = shapely.intersection(pa, pb)
    pt = inter.centroid if not inter.is_empty else shapely.shortest_line(pa, pb).centroid
    rel = float(np.hypot(*(ego.velocity(tc) - agent.velocity(tc))))
    return Contact(tc, float(pt.x), float(pt.y), rel)
