"""Road geometry of a Scenario's road, defined once: lane boundaries, offset polylines, lane lines.

Used by the exporters (OpenDRIVE, CommonRoad), the bird's-eye video, the report's plots and the viewer.
Layout: on an ``ego_path*`` or ``road_users`` road the centre line is the ego's path, so it is the centre
of lane ``ego_lane``; on any other road it is the centre of the carriageway. Lane 0 is the rightmost.
The oncoming lanes (``oncoming_lane_count``, the opposite direction) lie ``median_width`` beyond the ego
carriageway's edge next to the other direction: its left edge in right-hand traffic, its right edge where
``driving_side`` is ``left``. World frame, metres.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from deepcrashtest.scenario import Road


def offset_polyline(xy: np.ndarray, offset: float) -> np.ndarray:
    """The polyline ``xy`` (N, 2) moved ``offset`` metres to its left (negative: right)."""
    d = np.gradient(xy, axis=0)
    n = np.hypot(d[:, 0], d[:, 1])
    n[n == 0] = 1.0
    left = np.column_stack([-d[:, 1], d[:, 0]]) / n[:, None]
    return xy + offset * left


def boundary_offsets(road: Road) -> np.ndarray:
    """Lateral offsets (m, left positive) of the lane boundaries from the centre line, right to left.

    ``lane_count + 1`` values; lane k (0 = rightmost) lies between entries k and k + 1.
    """
    j = np.arange(road.lane_count + 1, dtype=float)
    if road.source.startswith("ego_path") or road.source == "road_users":
        return (j - road.ego_lane - 0.5) * road.lane_width
    return (j - road.lane_count / 2.0) * road.lane_width


def oncoming_boundary_offsets(road: Road) -> np.ndarray:
    """Lateral offsets (m, left positive) of the oncoming lanes' boundaries from the centre line, right to left.

    ``oncoming_lane_count + 1`` values (none on a one-way road), from the inner edge, ``median_width`` beyond
    the ego's carriageway (left of it, or right in left-hand traffic), outwards. Oncoming lane k (0 = the one
    next to the ego's carriageway) lies between entries k and k + 1.
    """
    if road.oncoming_lane_count == 0:
        return np.zeros(0)
    side = side_sign(road)
    inner = float(divider_offset(road)) + side * road.median_width
    return inner + side * np.arange(road.oncoming_lane_count + 1, dtype=float) * road.lane_width


def side_sign(road: Road) -> float:
    """+1 where the oncoming lanes lie left of the ego's carriageway (right-hand traffic), -1 right of it."""
    return 1.0 if road.driving_side == "right" else -1.0


def divider_index(road: Road) -> int:
    """Index, in :func:`boundary_offsets` / :func:`boundary_polylines`, of the ego carriageway's edge next to the
    other direction: its leftmost (-1) in right-hand traffic, its rightmost (0) in left-hand traffic."""
    return -1 if road.driving_side == "right" else 0


def divider_offset(road: Road) -> float:
    """Lateral offset (m, left positive) of the ego carriageway's edge next to the other direction."""
    return float(boundary_offsets(road)[divider_index(road)])


def lane_lines(road: Road) -> dict[str, Any]:
    """``{"center": [[x, y], ...], "boundaries": [[[x, y], ...], ...], "oncoming": [...], "driving_side": ...}``:
    the ego's carriageway's boundaries (rightmost edge first, leftmost last), then the oncoming lanes' (inner edge
    first; empty on a one-way road), and the side traffic keeps to (``right``: the ego carriageway's last boundary
    is the edge between the directions; ``left``: its first)."""
    xy = road.centerline()
    return {
        "center": xy.tolist(),
        "boundaries": [b.tolist() for b in boundary_polylines(road)],
        "oncoming": [b.tolist() for b in oncoming_polylines(road)],
        "driving_side": road.driving_side,
    }


def boundary_polylines(road: Road) -> list[np.ndarray]:
    """Every lane boundary of the ego's carriageway as an (N, 2) polyline, rightmost edge first, leftmost edge
    last (metres)."""
    xy = road.centerline()
    return [offset_polyline(xy, float(o)) for o in boundary_offsets(road)]


def oncoming_polylines(road: Road) -> list[np.ndarray]:
    """Every boundary of the oncoming lanes as an (N, 2) polyline, inner edge first (metres); [] if none."""
    xy = road.centerline()
    return [offset_polyline(xy, float(o)) for o in oncoming_boundary_offsets(road)]
