"""The processed road: centre line from the ego's path, lane width and count.

The centre line is the ego's path smoothed heavily (``road_sigma_m``), so it is the centre of the
ego's lane (``Road.source`` ``ego_path``), curved where the ego's path curves. In a head-on
crash it is continued past the collision point along the colliding oncoming agent's path (moved
sideways onto the ego's lane), because the ego's own path stops there (``ego_path+oncoming``).
It always reaches ``road_margin_m`` past every vehicle's first and last position along the road,
continued straight beyond the paths.

Lanes: from the lane stage when the raw road carries a ``lane_timeline`` (its width, count and the
ego's lane are kept). Where no lane lines were seen (most urban clips) the lanes are inferred from
the road users' paths and the road says so (``Road.source`` ``road_users`` and a warning): the
median lateral offsets from the ego's lane of the vehicles moving along the road (pedestrians walk
beside it and crossing traffic crosses it, so neither counts, nor do offsets beyond
``MAX_ROAD_OFFSET_M``: another road or a localisation error)
are fitted with lanes of a plausible width (``LANE_WIDTH_RANGE_M``, the width that puts the paths
nearest to lane centres) and as many lanes as their spread needs, at most ``MAX_INFERRED_LANES``.
"""

from __future__ import annotations

import numpy as np

from deepcrashtest.scenario import Road
from deepcrashtest.trajectory.params import Stage2Params
from deepcrashtest.trajectory.roadframe import RoadFrame

MAX_LANES = 12
#: Plausible lane widths (m) of an inferred road: urban lanes 3.0 m to motorway lanes 3.75 m.
LANE_WIDTH_RANGE_M = (3.0, 3.75)
#: Lateral offsets (m) beyond this from the ego's lane are not lanes of the ego's road.
MAX_ROAD_OFFSET_M = 12.0
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
    s, _ = frame.project(np.asarray(xy, float).reshape(-1, 2))
    tangent = float(frame.tangent(float(np.median(s)))[0])
    return bool(abs(np.cos(heading - tangent)) >= np.cos(np.radians(max_angle_deg)))


def inferred_lanes(offsets_m: list[float], default_width: float) -> tuple[float, int, int]:
    """(lane width m, lane count, ego lane) fitted to the road users' lateral offsets (m, left positive).

    Only offsets within ``MAX_ROAD_OFFSET_M`` count; with none the ego's lane alone at ``default_width``
    (clipped to ``LANE_WIDTH_RANGE_M``). Otherwise the width in ``LANE_WIDTH_RANGE_M`` whose lane centres
    lie nearest the offsets (least squares, 5 cm steps; ties to the wider) and the lanes they span.
    """
    d = np.asarray([v for v in offsets_m if abs(v) <= MAX_ROAD_OFFSET_M], float)
    lo, hi = LANE_WIDTH_RANGE_M
    if d.size == 0:
        return float(np.clip(default_width, lo, hi)), 1, 0
    widths = np.arange(hi, lo - 1e-9, -0.05)
    cost = [float(np.sum((d - np.round(d / w) * w) ** 2)) for w in widths]
    width = float(widths[int(np.argmin(cost))])
    count, ego_lane = lane_layout(list(d), width)
    while count > MAX_INFERRED_LANES:  # drop the outermost lane on the wider side
        left, right = count - 1 - ego_lane, ego_lane
        count, ego_lane = count - 1, ego_lane - (1 if right > left else 0)
    return round(width, 2), count, ego_lane


def build_road(
    frame: RoadFrame,
    raw_road: Road,
    positions: list[np.ndarray],
    moving_offsets_m: list[float],
    p: Stage2Params,
    source: str = "ego_path",
    warnings: list[str] | None = None,
) -> Road:
    """The Road of the processed scenario (world frame, metres).

    ``moving_offsets_m``: median lateral offsets of the moving vehicles (not pedestrians) from the
    ego's lane. A road inferred without lane lines adds a line to ``warnings``.
    """
    pts = np.vstack([q[:: max(1, len(q) // 50)] for q in positions] + [q[-1:] for q in positions])
    s, _ = frame.project(pts)
    s_from = min(float(s.min()), 0.0) - p.road_margin_m
    s_to = max(float(s.max()), frame.length) + p.road_margin_m
    wp = frame.resampled(s_from, s_to, p.road_spacing_m)
    if raw_road.lane_timeline is not None:
        width, count, ego_lane = raw_road.lane_width, raw_road.lane_count, raw_road.ego_lane
    else:
        width, count, ego_lane = inferred_lanes(moving_offsets_m, p.default_lane_width_m)
        source = "road_users" if source == "ego_path" else source
        if warnings is not None:
            users = f"the spread of {len(moving_offsets_m)} road users' paths" if moving_offsets_m else "no other path"
            warnings.append(
                f"no lane lines seen: the road ({count} lane(s) x {width:g} m, ego in lane {ego_lane}) is inferred "
                f"from the ego's path and {users}, not measured"
            )
    return Road(
        centerline_x=wp[:, 0].tolist(),
        centerline_y=wp[:, 1].tolist(),
        lane_width=width,
        lane_count=count,
        ego_lane=ego_lane,
        source=source,  # type: ignore[arg-type]
        lane_timeline=raw_road.lane_timeline,
    )
