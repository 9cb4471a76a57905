"""Road users' 3D boxes projected into the video frames, for drawing over the video (viewer).

The boxes come from a Scenario's trajectories or from a simulation's states; the camera rides on
the ego (its pose from the same source) and the projection is :mod:`deepcrashtest.geometry.project`.
Frames are the video's, mapped to scenario time by the one mapping (:meth:`Scenario.frame_time`).
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import numpy as np

from deepcrashtest.geometry.project import Pose, PoseFn, scenario_poses
from deepcrashtest.scenario import Scenario

__all__ = ["Pose", "PoseFn", "projected_frames", "scenario_poses", "sim_poses"]


def sim_poses(times: Sequence[float], vehicle_ids: Sequence[int], states: Any) -> PoseFn:
    """Poses from simulated states (``states[k][i] = x, y, yaw, speed`` of ``vehicle_ids[i]`` at ``times[k]``;
    None/NaN where absent): the nearest simulated time, absent outside the run."""
    t = np.asarray(times, float)
    st = np.asarray([[[np.nan if q is None else q for q in s] for s in row] for row in states], float)
    col = {int(v): i for i, v in enumerate(vehicle_ids)}

    def pose(vid: int, tq: float) -> Pose | None:
        if vid not in col or not len(t) or tq < t[0] - 1e-6 or tq > t[-1] + 1e-6:
            return None
        k = int(np.abs(t - tq).argmin())
        x, y, yaw = st[k, col[vid], :3]
        return None if not np.isfinite([x, y, yaw]).all() else (float(x), float(y), float(yaw))

    return pose


def projected_frames(scenario: Scenario, pose: PoseFn, frame_count: int, source: str) -> dict[str, Any]:
    """For every video frame, the edges of each road user's 3D box in the image (pixels of the full frame).

    ``{"width", "height", "source", "frames": {"<frame>": [[id, [[u0, v0, u1, v1], ...]], ...]}}``: the
    edges in front of the camera's near plane, clipped at it (:func:`project_box_edges`); a road user
    with no edge inside the image is left out.
    """
    from deepcrashtest.geometry.project import project_box_edges

    w, h = scenario.source.width, scenario.source.height
    frames: dict[str, list[Any]] = {}
    for f in range(frame_count):
        t = scenario.frame_time(f)
        ego = pose(scenario.ego.id, t)
        if ego is None:
            continue
        boxes = []
        cam = scenario.camera.at_video_time(f / scenario.source.fps)
        for v in scenario.agents:
            p = pose(v.id, t)
            if p is None:
                continue
            seg = project_box_edges(cam, ego, *p, v.length, v.width, v.height).reshape(-1, 4)
            seg = seg[np.isfinite(seg).all(axis=1)]
            u, vv = seg[:, 0::2], seg[:, 1::2]
            if not len(seg) or u.max() < 0 or u.min() > w or vv.max() < 0 or vv.min() > h:
                continue
            boxes.append([v.id, np.round(seg, 1).tolist()])
        if boxes:
            frames[str(f)] = boxes
    return {"width": w, "height": h, "source": source, "frames": frames}
