"""Tracks that are the ego's own bonnet (or a reflection on it) taken for a vehicle, told by the ground plane.

A detector can report the bonnet at the bottom of the picture as a "car", above all where the camera stands still
and the bonnet cannot be told from the road by its stillness (``geometry.camera.bonnet_contour``; dad_000512: a
"car" 0.95-1.1 x the focal length wide along the picture's bottom at a junction, confidence 0.4). Placed in 3D it
lands inside or across the ego's nose, depending on the heading its box suggests. A road user's box cannot look
like that: a vehicle at most ``2.5`` m wide whose box is wider than ``EGO_PART_WIDTH_F`` x the focal length is within
2.5 m of the camera, at or inside the ego's own front, and its roof there lies above the horizon or just under it;
a box top more than ``EGO_PART_TOP_F`` x the focal length under the horizon at that range is under the camera's
height less 0.375 m (under 1 m for a camera below 1.4 m: lower than any car's roof). A vehicle track whose boxes
reach the picture's bottom edge, are that wide and that low in at least ``EGO_PART_SHARE`` of its detected frames is
part of the ego. Boxes in pixels of the (undistorted) picture; the horizon from the camera's pitch.
"""

from __future__ import annotations

import pandas as pd

from deepcrashtest.geometry.camera import BOTTOM_SHARE
from deepcrashtest.perception.roadusers import MOTOR_VEHICLES
from deepcrashtest.scenario import Camera

#: Box width over the focal length from which a vehicle's box is within 2.5 m of the camera.
EGO_PART_WIDTH_F = 1.0
#: Box top this far under the horizon (x the focal length) at that range: lower than a vehicle's roof.
EGO_PART_TOP_F = 0.15
#: Share of a track's detected frames with such boxes.
EGO_PART_SHARE = 0.5


def ego_part_tracks(tracks: pd.DataFrame, camera: Camera, size: tuple[int, int]) -> list[int]:
    """Ids of the vehicle tracks of ``tracks`` (columns ``track_id, category, x1, y1, x2, y2``, optional
    ``state``; px) that are the ego's own bonnet (see the module docstring), in id order; ``size``: the picture's
    width and height (px)."""
    if not len(tracks):
        return []
    seen = tracks[tracks["state"] == "detected"] if "state" in tracks.columns else tracks
    seen = seen[seen["category"].isin(MOTOR_VEHICLES)]  # a walker's box is narrow, a rider's tall
    height = float(size[1])
    bottom = seen["y2"].to_numpy(float) >= height * (1.0 - BOTTOM_SHARE)
    wide = (seen["x2"] - seen["x1"]).to_numpy(float) >= EGO_PART_WIDTH_F * camera.fx
    low = seen["y1"].to_numpy(float) - camera.horizon_v() >= EGO_PART_TOP_F * camera.fy
    share = pd.Series(bottom & wide & low).groupby(seen["track_id"].to_numpy()).mean()
    return sorted(int(k) for k in share.index[share.to_numpy() >= EGO_PART_SHARE])
