"""The processed road: centre line from the ego's path, lane width and count.

The centre line is the ego's path smoothed heavily (``road_sigma_m``), so it is the centre of the
ego's lane (``Road.source`` ``ego_path``), curved where the ego's path curves. In a head-on
crash it is continued past the collision point along the colliding oncoming agent's path (moved
sideways onto the ego's lane), because the ego's own path stops there (``ego_path+oncoming``).
It always reaches ``road_margin_m`` past every vehicle's first and last position along the road,
continued straight beyond the paths.

Lanes cover the vehicles that move along the road (pedestrians walk beside it and crossing traffic crosses
it, so neither counts), each by the median lateral offset of its path from the ego's lane:

* Width: from the lane stage when the raw road carries a ``lane_timeline`` (seen lines), which also puts the
  ego's lane centre where the lines are (the centre line moves by the ego's median offset in its lane).
  Where no lane lines were seen (most urban clips) the width is inferred from the paths and the road says
  so (``Road.source`` ``road_users`` and a warning): the width in ``LANE_WIDTH_RANGE_M`` that puts the
  paths within ``MAX_ROAD_OFFSET_M`` (farther: another road or a localisation error) nearest to lane centres.
* The ego's carriageway: as many lanes on each side of the ego's lane as the same-direction vehicles
  within ``MAX_ROAD_OFFSET_M`` and the lanes the ego itself changed to (lane timeline) need, at most
  ``MAX_INFERRED_LANES``; an oncoming vehicle right of the ego's lane (mislocalised, or against the
  traffic) is held by it too.
* Oncoming lanes (``Road.oncoming_lane_count``, right-hand traffic: left of the ego's carriageway): the
  lanes the oncoming vehicles left of the ego's lane (up to ``MAX_ONCOMING_OFFSET_M``) need, from the
  innermost one outwards. When the innermost lies more than a lane beyond the ego's carriageway (a divided
  road), the gap is the ``Road.median_width``; otherwise the oncoming lanes start at its left edge.
* Left-hand traffic (``Stage2Params.driving_side`` ``left``, given by the user: the video cannot tell a
  wrong-way or mislocalised car from the rule of the road): the same layout mirrored, the oncoming lanes right
  of the ego's carriageway; lane 0 stays the rightmost.
"""

from __future__ import annotations

import numpy as np

from deepcrashtest.scenario import Road
from deepcrashtest.trajectory.params import Stage2Params
from deepcrashtest.trajectory.roadframe import RoadFrame

MAX_LANES = 12
#: Plausible lane widths (m) of an inferred road: urban lanes 3.0 m to motorway lanes 3.75 m.
LANE_WIDTH_RANGE_M = (3.0, 3.75)
#: Lateral offsets (m) beyond this from the ego's lane are not lanes of the ego's carriageway.
MAX_ROAD_OFFSET_M = 12.0
#: Oncoming vehicles farther left than this (m) are on another road (or mislocalised), not the oncoming lanes:
#: the far carriageway of a divided motorway lies up to ~30 m left (Udacity highway clip, mono-localised).
MAX_ONCOMING_OFFSET_M = 35.0
#: The most lanes inferred from paths (a wide urban road: three each way).
MAX_INFERRED_LANES = 6
#: A path within this angle (degrees) of the road's direction runs along it; crossing traffic does not count.
ALONG_ROAD_DEG = 30.0


def extend_head_on(frame: RoadFrame, s_collision: float, agent_xy: np.ndarray, sigma_m: float) -> RoadFrame:
    """Centre line up to the collision station, then the oncoming agent's path beyond it (shifted onto the
    ego's lane by its median lateral offset), smoothed again."""
    s, d = frame.project(agent_xy)
    ahead = s > s_collision + 1.0
    if ahead.sum() < 2:
        return frame
    offset = float(np.median(d))
    shifted = frame.point(s[ahead], d[ahead] - offset)
    order = np.argsort(s[ahead])
    base = frame.pts[frame.s <= s_collision]
    pts = np.vstack([base, shifted[order]])
    return RoadFrame.from_path(pts, sigma_m)


def lane_layout(offsets_m: list[float], lane_width: float) -> tuple[int, int]:
    """(lane_count, ego_lane) covering lateral offsets (metres, left positive) from the ego's lane."""
    idx = [int(round(d / lane_width)) for d in offsets_m] or [0]
    left = max(0, max(idx))
    right = max(0, -min(idx))
    left = min(left, MAX_LANES - 1)
    right = min(right, MAX_LANES - 1 - left)
    return left + right + 1, right


def along_road(frame: RoadFrame, xy: np.ndarray, heading: float, max_angle_deg: float = ALONG_ROAD_DEG) -> bool:
    """True when a road user travelling ``heading`` (rad) through ``xy`` (metres) drives along the road (either
    direction, within ``max_angle_deg``), not across it: only such paths say where lanes are."""
    pts = np.asarray(xy, float).reshape(-1, 2)
    if len(pts) == 0:  # no observed sample left (e.g. all cut away after the collision): no lane evidence
        return False
    s, _ = frame.project(pts)
    tangent = float(frame.tangent(float(np.median(s)))[0])
    return bool(abs(np.cos(heading - tangent)) >= np.cos(np.radians(max_angle_deg)))


def fitted_lane_width(offsets_m: list[float], default_width: float) -> float:
    """Lane width (m) in ``LANE_WIDTH_RANGE_M`` whose lane centres lie nearest the lateral offsets (m, left
    positive) within ``MAX_ROAD_OFFSET_M`` (least squares, 5 cm steps; ties to the wider); with none
    ``default_width`` clipped to the range."""
    d = np.asarray([v for v in offsets_m if abs(v) <= MAX_ROAD_OFFSET_M], float)
    lo, hi = LANE_WIDTH_RANGE_M
    if d.size == 0:
        return float(np.clip(default_width, lo, hi))
    widths = np.arange(hi, lo - 1e-9, -0.05)
    cost = [float(np.sum((d - np.round(d / w) * w) ** 2)) for w in widths]
    return round(float(widths[int(np.argmin(cost))]), 2)


def carriageway(offsets_m: list[float], lane_width: float) -> tuple[int, int]:
    """(lane count, ego lane) of the ego's carriageway covering the offsets (m, left positive) within
    ``MAX_ROAD_OFFSET_M`` of the ego's lane, at most ``MAX_INFERRED_LANES`` (the outermost lanes of the wider
    side dropped first)."""
    count, ego_lane = lane_layout([v for v in offsets_m if abs(v) <= MAX_ROAD_OFFSET_M], lane_width)
    while count > MAX_INFERRED_LANES:  # drop the outermost lane on the wider side
        left, right = count - 1 - ego_lane, ego_lane
        count, ego_lane = count - 1, ego_lane - (1 if right > left else 0)
    return count, ego_lane


def inferred_lanes(offsets_m: list[float], default_width: float) -> tuple[float, int, int]:
    """(lane width m, lane count, ego lane) fitted to the road users' lateral offsets (m, left positive):
    :func:`fitted_lane_width` and the :func:`carriageway` they span; with none the ego's lane alone."""
    width = fitted_lane_width(offsets_m, default_width)
    count, ego_lane = carriageway(offsets_m, width)
    return width, count, ego_lane


def oncoming_lanes(offsets_m: list[float], left_edge_m: float, lane_width: float) -> tuple[int, float]:
    """(oncoming lane count, median width m) covering the oncoming vehicles' lateral offsets (m, left positive,
    from the ego's lane centre) left of the ego's lane and within ``MAX_ONCOMING_OFFSET_M``.

    ``left_edge_m``: the ego carriageway's left edge. The innermost vehicle's lane is the first oncoming lane;
    it starts at the edge unless that leaves a gap of a lane or more (a median, whose width is returned).
    """
    d = np.asarray([v for v in offsets_m if 0.0 < v <= MAX_ONCOMING_OFFSET_M], float)
    if d.size == 0:
        return 0, 0.0
    gap = float(d.min()) - lane_width / 2 - left_edge_m
    median = round(gap, 2) if gap >= lane_width else 0.0
    count = int(np.floor((float(d.max()) - left_edge_m - median) / lane_width)) + 1
    return int(np.clip(count, 1, MAX_INFERRED_LANES)), median


def road_layout(
    same_m: list[float], oncoming_m: list[float], width: float, driving_side: str = "right"
) -> tuple[int, int, int, float]:
    """(lane count, ego lane (0 = rightmost), oncoming lane count, median width m) of a road holding the lateral
    offsets (m, left positive, from the ego's lane centre) of the same-direction and oncoming vehicles.

    Right-hand traffic: :func:`carriageway` (an oncoming vehicle on the ego's side of the road, mislocalised or
    against the traffic, is held by it too) and :func:`oncoming_lanes` left of it. Left-hand traffic: the same
    on the offsets mirrored, the ego's lane index turned back to count from the right.
    """
    sign = 1.0 if driving_side == "right" else -1.0
    same = [sign * v for v in same_m]
    oncoming = [sign * v for v in oncoming_m]
    count, ego_lane = carriageway(same + [v for v in oncoming if v < 0], width)
    n_on, median = oncoming_lanes(oncoming, (count - ego_lane - 0.5) * width, width)
    if sign < 0:
        ego_lane = count - 1 - ego_lane
    return count, ego_lane, n_on, median


def build_road(
    frame: RoadFrame,
    raw_road: Road,
    positions: list[np.ndarray],
    offsets_m: tuple[list[float], list[float]],
    p: Stage2Params,
    source: str = "ego_path",
    warnings: list[str] | None = None,
) -> Road:
    """The Road of the processed scenario (world frame, metres).

    ``offsets_m``: median lateral offsets (m, left positive) from the ego's path of the vehicles (not
    pedestrians) moving along the road, (same direction as the ego, oncoming). A road inferred without lane
    lines adds a line to ``warnings``.
    """
    pts = np.vstack([q[:: max(1, len(q) // 50)] for q in positions] + [q[-1:] for q in positions])
    s, _ = frame.project(pts)
    s_from = min(float(s.min()), 0.0) - p.road_margin_m
    s_to = max(float(s.max()), frame.length) + p.road_margin_m
    same, oncoming = offsets_m
    lt = raw_road.lane_timeline
    if lt is not None:
        width = raw_road.lane_width
        shift = float(np.clip(-np.median(lt.lateral_offset), -width / 2, width / 2))  # lane centre from the path
        visited = [(k - lt.lane_index[0]) * width for k in sorted(set(lt.lane_index))]
        same, oncoming = [v - shift for v in same] + visited, [v - shift for v in oncoming]
    else:
        width, shift = fitted_lane_width(same + oncoming, p.default_lane_width_m), 0.0
        source = "road_users" if source == "ego_path" else source
    count, ego_lane, n_on, median = road_layout(same, oncoming, width, p.driving_side)
    if lt is None and warnings is not None:
        users = f"the spread of {len(same) + len(oncoming)} road users' paths" if same or oncoming else "no other path"
        on = f", {n_on} oncoming" + (f" beyond a {median:g} m median" if median else "") if n_on else ""
        warnings.append(
            f"no lane lines seen: the road ({count} lane(s){on} x {width:g} m, ego in lane {ego_lane}) is inferred "
            f"from the ego's path and {users}, not measured"
        )
    wp = frame.resampled(s_from, s_to, p.road_spacing_m, shift)
    return Road(
        centerline_x=wp[:, 0].tolist(),
        centerline_y=wp[:, 1].tolist(),
        lane_width=width,
        lane_count=count,
        ego_lane=ego_lane,
        oncoming_lane_count=n_on,
        median_width=median,
        driving_side=p.driving_side,  # type: ignore[arg-type]
        source=source,  # type: ignore[arg-type]
        lane_timeline=raw_road.lane_timeline,
    )
