"""ASAM OpenDRIVE 1.7 road (``road.xodr``) from a Scenario's road, via scenariogeneration.

Geometry. The road reference line passes through every centre-line waypoint of
``Scenario.road`` (world frame: x forward, y left, metres). Between two consecutive waypoints it
is one ``paramPoly3`` (normalised parameter p in [0, 1]): the cubic Hermite curve whose end
tangents are the tangent directions of a natural cubic spline through all waypoints
(parameterised by chord length), scaled by the chord length. So the line hits each waypoint
exactly, its heading is continuous (G1) across geometries, and each geometry's ``length`` is its
arc length integrated numerically (agrees with the ASAM checker's integral to < 1e-6 m).

Lanes. One lane section; the ego's carriageway drives in the reference line's direction (right-hand
traffic: lane ids -1 .. -lane_count, -1 the leftmost). ``Road.lane_width`` and ``lane_count`` set
the lanes; Scenario lane index 0 is the rightmost (OpenDRIVE id -lane_count). Where the road
came from the ego's path (``source`` ``ego_path*``) the waypoints are the centre of the ego's lane
(``ego_lane``), so a constant ``laneOffset`` shifts the lanes to put that lane's centre on the
reference line; otherwise the waypoints are the centre of the carriageway. The oncoming lanes
(``oncoming_lane_count``) are left lanes (positive ids, the opposite direction) beyond the centre lane's
solid line: ids 1 .. n, or 2 .. n + 1 behind a ``median`` lane 1 of ``median_width`` on a divided road.
Left-hand traffic (``Road.driving_side`` ``left``): the road's ``rule`` is ``LHT``, under which the left lanes
drive in the reference line's direction: the ego's carriageway is left lanes 1 .. lane_count (1 the rightmost,
next to the centre lane, which lies on the carriageway's right edge) and the oncoming lanes are right lanes
-1 .. -n (or -2 .. -(n + 1) behind a median lane -1).

Elevation: one record with all coefficients 0 (a flat road; scenariogeneration would otherwise
write an empty, schema-invalid ``<elevationProfile/>``). Header revMajor 1, revMinor 7: the
files follow OpenDRIVE 1.7, whose schema ships with scenariogeneration and whose rules the ASAM
checker applies.
"""

from __future__ import annotations

import math
import os
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
from scipy.integrate import quad
from scipy.interpolate import CubicSpline

from deepcrashtest.errors import UserError
from deepcrashtest.fileio import atomic_path
from deepcrashtest.geometry.road import boundary_offsets
from deepcrashtest.scenario import Road

OPENDRIVE_REV_MAJOR = 1
OPENDRIVE_REV_MINOR = 7
#: Waypoints closer than this to the previous kept one are dropped (metres).
MIN_WAYPOINT_SPACING_M = 0.01
ROAD_ID = 1


@dataclass(frozen=True)
class Poly3Segment:
    """One paramPoly3 geometry: start pose (world), local cubic coefficients, arc length.

    Local frame: origin at (x, y), u along heading ``hdg`` (radians), v to its left. For p in [0, 1]:
    u(p) = au + bu p + cu p^2 + du p^3 and likewise v.
    """

    s: float
    x: float
    y: float
    hdg: float
    u: tuple[float, float, float, float]
    v: tuple[float, float, float, float]
    length: float

    def points(self, p: np.ndarray) -> np.ndarray:
        """World (x, y) at parameters ``p`` (array in [0, 1]), shape (len(p), 2)."""
        u = np.polyval(self.u[::-1], p)
        v = np.polyval(self.v[::-1], p)
        c, s = math.cos(self.hdg), math.sin(self.hdg)
        return np.column_stack([self.x + c * u - s * v, self.y + s * u + c * v])

    def headings(self, p: np.ndarray) -> np.ndarray:
        """World heading (radians) of the curve's tangent at parameters ``p``."""
        du = np.polyval(np.polyder(np.array(self.u[::-1])), p)
        dv = np.polyval(np.polyder(np.array(self.v[::-1])), p)
        return self.hdg + np.arctan2(dv, du)


def clean_waypoints(road: Road) -> np.ndarray:
    """The road's waypoints (N, 2) without (near-)duplicates; UserError if fewer than 2 remain."""
    xy = road.centerline()
    keep = [0]
    for i in range(1, len(xy)):
        if np.hypot(*(xy[i] - xy[keep[-1]])) >= MIN_WAYPOINT_SPACING_M:
            keep.append(i)
    if len(keep) < 2:
        raise UserError("road: the centre-line waypoints span less than 1 cm; cannot build a road")
    return xy[keep]


def reference_line(road: Road) -> list[Poly3Segment]:
    """The reference line as G1-continuous Hermite paramPoly3 segments through all waypoints."""
    xy = clean_waypoints(road)
    chord = np.hypot(*np.diff(xy, axis=0).T)
    s_knots = np.concatenate([[0.0], np.cumsum(chord)])
    if len(xy) == 2:
        tangents = np.repeat((xy[1] - xy[0])[None, :] / chord[0], 2, axis=0)
    else:
        tangents = CubicSpline(s_knots, xy, bc_type="natural")(s_knots, 1)
        tangents /= np.linalg.norm(tangents, axis=1, keepdims=True)
    segments: list[Poly3Segment] = []
    s = 0.0
    for i in range(len(xy) - 1):
        hdg = math.atan2(tangents[i, 1], tangents[i, 0])
        c, sn = math.cos(hdg), math.sin(hdg)
        rot = np.array([[c, sn], [-sn, c]])  # world -> local
        d = rot @ (xy[i + 1] - xy[i])
        m0 = np.array([chord[i], 0.0])
        m1 = chord[i] * (rot @ tangents[i + 1])
        c2 = 3.0 * d - 2.0 * m0 - m1
        c3 = -2.0 * d + m0 + m1
        u = (0.0, float(m0[0]), float(c2[0]), float(c3[0]))
        v = (0.0, float(m0[1]), float(c2[1]), float(c3[1]))
        length = _arc_length(u, v)
        segments.append(Poly3Segment(s, float(xy[i, 0]), float(xy[i, 1]), hdg, u, v, length))
        s += length
    return segments


def _arc_length(u: tuple[float, ...], v: tuple[float, ...]) -> float:
    du = np.polyder(np.array(u[::-1]))
    dv = np.polyder(np.array(v[::-1]))
    val, _ = quad(lambda p: math.hypot(np.polyval(du, p), np.polyval(dv, p)), 0.0, 1.0, epsabs=1e-10, epsrel=1e-12)
    return float(val)


def sample_reference_line(segments: list[Poly3Segment], step_m: float = 0.5) -> tuple[np.ndarray, np.ndarray]:
    """Points (M, 2) and headings (M,) along the reference line, about every ``step_m`` metres.

    Includes every segment's start and the line's end point (so every waypoint is a sample).
    """
    pts, hdgs = [], []
    for seg in segments:
        n = max(1, math.ceil(seg.length / step_m))
        p = np.arange(n) / n
        pts.append(seg.points(p))
        hdgs.append(seg.headings(p))
    last = segments[-1]
    pts.append(last.points(np.array([1.0])))
    hdgs.append(last.headings(np.array([1.0])))
    return np.vstack(pts), np.concatenate(hdgs)


def opendrive_lane_id(lane_index: int, lane_count: int, driving_side: str = "right") -> int:
    """OpenDRIVE lane id of Scenario lane ``lane_index`` (0 = rightmost) of the ego's carriageway: -lane_count .. -1
    in right-hand traffic, 1 .. lane_count in left-hand traffic."""
    return -(lane_count - lane_index) if driving_side == "right" else lane_index + 1


def build_opendrive(road: Road, name: str = "deepcrashtest"):  # -> scenariogeneration.xodr.OpenDrive
    """The scenariogeneration OpenDrive object of one road (id 1) as described in the module doc."""
    from scenariogeneration import xodr

    planview = xodr.PlanView()
    for seg in reference_line(road):
        geom = xodr.ParamPoly3(*seg.u, *seg.v, prange="normalized", length=seg.length)
        planview.add_fixed_geometry(geom, seg.x, seg.y, seg.hdg, s=seg.s)

    right_hand = road.driving_side == "right"
    offsets = boundary_offsets(road)
    lanes = xodr.Lanes()  # the centre lane on the ego carriageway's edge next to the other direction
    lanes.add_laneoffset(xodr.LaneOffset(0.0, float(offsets[-1] if right_hand else offsets[0]), 0.0, 0.0, 0.0))
    centre = xodr.Lane(a=0.0)
    centre.add_roadmark(xodr.RoadMark(xodr.RoadMarkType.solid, 0.12))
    section = xodr.LaneSection(0.0, centre)
    own_side, other_side = (section.add_right_lane, section.add_left_lane)
    if not right_hand:
        own_side, other_side = other_side, own_side
    n = road.lane_count
    for k in range(n):  # from the centre lane outwards, as scenariogeneration numbers them
        lane = xodr.Lane(xodr.LaneType.driving, a=road.lane_width)
        lane.add_roadmark(xodr.RoadMark(xodr.RoadMarkType.solid if k == n - 1 else xodr.RoadMarkType.broken, 0.12))
        own_side(lane)
    _add_oncoming_lanes(other_side, road)
    lanes.add_lanesection(section)

    rule = xodr.TrafficRule.RHT if right_hand else xodr.TrafficRule.LHT
    xroad = xodr.Road(ROAD_ID, planview, lanes, name=name, rule=rule)
    xroad.add_elevation(0.0, 0.0, 0.0, 0.0, 0.0)
    odr = xodr.OpenDrive(name, revMajor=str(OPENDRIVE_REV_MAJOR), revMinor=str(OPENDRIVE_REV_MINOR))
    odr.add_road(xroad)
    return odr


def _add_oncoming_lanes(add_lane: Callable[[Any], None], road: Road) -> None:
    """The oncoming lanes, inner first, behind a median lane where the road has one, each given to ``add_lane``
    (the lane section's ``add_left_lane`` in right-hand traffic, ``add_right_lane`` in left-hand traffic)."""
    from scenariogeneration import xodr

    if road.oncoming_lane_count == 0:
        return
    if road.median_width > 0:
        median = xodr.Lane(xodr.LaneType.median, a=road.median_width)
        median.add_roadmark(xodr.RoadMark(xodr.RoadMarkType.solid, 0.12))
        add_lane(median)
    for k in range(road.oncoming_lane_count):
        lane = xodr.Lane(xodr.LaneType.driving, a=road.lane_width)
        outer = k == road.oncoming_lane_count - 1
        lane.add_roadmark(xodr.RoadMark(xodr.RoadMarkType.solid if outer else xodr.RoadMarkType.broken, 0.12))
        add_lane(lane)


def write_opendrive(road: Road, path: str | os.PathLike[str], name: str = "deepcrashtest", force: bool = False) -> Path:
    """Write ``road`` as an OpenDRIVE file atomically; refuse to overwrite unless ``force``."""
    odr = build_opendrive(road, name)
    with atomic_path(path, force=force) as tmp:
        odr.write_xml(str(tmp))
    return Path(path)
