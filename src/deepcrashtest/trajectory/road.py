"""The processed road: centre line from the ego's path, lane width and count.

The centre line is the ego's path smoothed heavily (``road_sigma_m``), so it is the centre of the
ego's lane (``Road.source`` ``ego_path``), curved where the ego's path curves. In a head-on
crash it is continued past the collision point along the colliding oncoming agent's path (moved
sideways onto the ego's lane), because the ego's own path stops there (``ego_path+oncoming``).
It always reaches ``road_margin_m`` past every vehicle's first and last position along the road,
continued straight beyond the paths.

Lanes: from the lane stage when the raw road carries a ``lane_timeline`` (its width, count and the
ego's lane are kept); otherwise ``default_lane_width_m`` and as many lanes as the moving agents'
lateral offsets from the ego's lane need (offset / width rounded), the ego's lane placed among them.
"""

from __future__ import annotations

import numpy as np

from deepcrashtest.scenario import Road
from deepcrashtest.trajectory.params import Stage2Params
from deepcrashtest.trajectory.roadframe import RoadFrame

MAX_LANES = 12


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


def build_road(
    frame: RoadFrame,
    raw_road: Road,
    positions: list[np.ndarray],
    moving_offsets_m: list[float],
    p: Stage2Params,
    source: str = "ego_path",
) -> Road:
    """The Road of the processed scenario (world frame, metres)."""
    pts = np.vstack([q[:: max(1, len(q) // 50)] for q in positions] + [q[-1:] for q in positions])
    s, _ = frame.project(pts)
    s_from = min(float(s.min()), 0.0) - p.road_margin_m
    s_to = max(float(s.max()), frame.length) + p.road_margin_m
    wp = frame.resampled(s_from, s_to, p.road_spacing_m)
    if raw_road.lane_timeline is not None:
        width, count, ego_lane = raw_road.lane_width, raw_road.lane_count, raw_road.ego_lane
    else:
        width = p.default_lane_width_m
        count, ego_lane = lane_layout(moving_offsets_m, width)
    return Road(
        centerline_x=wp[:, 0].tolist(),
        centerline_y=wp[:, 1].tolist(),
        lane_width=width,
        lane_count=count,
        ego_lane=ego_lane,
        source=source,  # type: ignore[arg-type]
        lane_timeline=raw_road.lane_timeline,
    )
