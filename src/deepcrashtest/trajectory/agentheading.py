"""A moving road user's processed heading where the video saw it: the raw scenario's (fitted to its boxes).

Stage 2's heading of a moving agent is the direction of its fitted path; a monocular path's direction is
range noise for a slow road user and can be tens of degrees off for a moving one, and its projected 3D box
then comes out wider than the detector's box. Stage 1 fits each agent's heading to its image boxes
(:mod:`deepcrashtest.geometry.box_heading`, pulled towards the direction of motion by its speed): over the
observed span that heading is kept; outside it (extrapolation, step-back lead-in) the path's direction, with
a linear blend over ``blend_s``. Times in seconds (scenario time), angles in radians (world frame).
"""

from __future__ import annotations

import math

import numpy as np

from deepcrashtest.scenario import Vehicle

BLEND_S = 0.5
"""Seconds over which the observed heading hands over to the path's direction outside the observed span."""


def with_observed_yaw(final: Vehicle, raw: Vehicle, t_shift: float, blend_s: float = BLEND_S) -> Vehicle:
    """``final`` (a processed agent) with its heading replaced by ``raw``'s over ``raw``'s span.

    ``t_shift``: scenario time minus the raw scenario's time (s). The raw heading is turned by a half turn
    where it points against the path's direction (a box fits both ways)."""
    a = final.trajectory.arrays()
    r = raw.trajectory.arrays()
    if len(r["t"]) < 2 or len(a["t"]) < 2:
        return final
    t_raw = r["t"] + t_shift
    motion = np.unwrap(a["yaw"])
    box = np.interp(a["t"], t_raw, np.unwrap(r["yaw"]))
    diff = (box - motion + 0.5 * math.pi) % math.pi - 0.5 * math.pi  # modulo a half turn
    outside = np.maximum(t_raw[0] - a["t"], a["t"] - t_raw[-1])
    w = np.clip(1.0 - np.maximum(outside, 0.0) / max(blend_s, 1e-6), 0.0, 1.0)
    yaw = np.unwrap(motion + w * diff)
    traj = final.trajectory.model_copy(update={"yaw": [float(v) for v in yaw]})
    return final.model_copy(update={"trajectory": traj})
