"""CSV of every vehicle's states: one row per vehicle per trajectory sample.

File ``trajectories.csv`` (UTF-8, comma-separated, header row, ``.`` decimal point), rows sorted
by time, then vehicle id. Frame: the Scenario's world frame (origin at the ego's centre at its
first sample, x forward along the ego's initial heading, y left). Positions are the centre of the
vehicle's bounding box on the ground. Columns:

=============  ======  ===========================================================
column         unit    meaning
=============  ======  ===========================================================
t_s            s       scenario time of the sample
vehicle_id     -       Scenario vehicle id (the ego is ``role`` ego)
role           -       ``ego`` or ``agent``
category       -       car, van, truck, bus, motorcycle, bicycle (with rider), pedestrian
x_m            m       centre x (forward)
y_m            m       centre y (left)
yaw_rad        rad     heading, counter-clockwise from +x, unwrapped
speed_mps      m/s     speed along the heading
length_m       m       box length
width_m        m       box width
height_m       m       box height
observed       -       1 where seen in the video, 0 where extrapolated, empty if unknown
active         -       1 from the vehicle's start delay on, 0 before it enters
=============  ======  ===========================================================

Times are the trajectories' own samples (no resampling), in scenario time: a vehicle seen from
frame 40 to 120 of a 10 fps video has rows for t = 4.0 + o .. 12.0 + o s only, o being the
Scenario's ``source.time_offset_s`` (the one time mapping: ``Scenario.frame_time``; video time =
t - o), plus any extrapolated samples (``observed`` 0).
"""

from __future__ import annotations

import os
from pathlib import Path

import pandas as pd

from deepcrashtest.fileio import atomic_write_text
from deepcrashtest.scenario import Scenario

COLUMNS = (
    "t_s",
    "vehicle_id",
    "role",
    "category",
    "x_m",
    "y_m",
    "yaw_rad",
    "speed_mps",
    "length_m",
    "width_m",
    "height_m",
    "observed",
    "active",
)


def scenario_table(sc: Scenario) -> pd.DataFrame:
    """All vehicles' samples as a table with :data:`COLUMNS`, sorted by (t_s, vehicle_id)."""
    frames = []
    for veh in sc.vehicles():
        a = veh.trajectory.arrays()
        n = len(a["t"])
        observed = veh.trajectory.observed
        frames.append(
            pd.DataFrame(
                {
                    "t_s": a["t"],
                    "vehicle_id": veh.id,
                    "role": "ego" if veh.id == sc.ego.id else "agent",
                    "category": veh.category,
                    "x_m": a["x"],
                    "y_m": a["y"],
                    "yaw_rad": a["yaw"],
                    "speed_mps": a["speed"],
                    "length_m": veh.length,
                    "width_m": veh.width,
                    "height_m": veh.height,
                    "observed": pd.array([int(b) for b in observed] if observed else [None] * n, dtype="Int64"),
                    "active": (a["t"] >= veh.start_delay_s - 1e-9).astype(int),
                }
            )
        )
    table = pd.concat(frames, ignore_index=True)
    return table.sort_values(["t_s", "vehicle_id"], kind="stable").reset_index(drop=True)[list(COLUMNS)]


def write_csv(sc: Scenario, path: str | os.PathLike[str], force: bool = False) -> Path:
    """Write :func:`scenario_table` to ``path`` (floats with full precision); refuse to overwrite."""
    text = scenario_table(sc).to_csv(index=False, float_format="%.9g", lineterminator="\n")
    return atomic_write_text(path, text, force=force)
