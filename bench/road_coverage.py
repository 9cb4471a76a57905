"""How many road users the processed road holds: vehicles moving along it whose seen path lies on its lanes.

For each raw scenario (a ``scenario_raw.json`` of an extraction, or ``kitti:N`` for a KITTI tracking sequence
from its labels with road users) stage 2 runs and every agent that is not a pedestrian, moves > 5 m and
travels within 30 deg of the road's direction (either way) counts; it is held when the median lateral offset
of its observed positions from the road's centre line lies within the ego's carriageway or the oncoming lanes
(:mod:`deepcrashtest.geometry.road`; a 1.2 build has no oncoming lanes). Prints one line per input (held /
counted, lane count, width, ego lane, oncoming lanes, median m, source, the ones off the road) and the total.

Usage::

    python bench/road_coverage.py /work/cache/fid_s9f/*/scenario_raw.json kitti:9 [--kitti DIR]

Compare two builds in one run by calling it with each ``PYTHONPATH``.
"""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np

from deepcrashtest.scenario import Scenario
from deepcrashtest.trajectory.pipeline import process_scenario
from deepcrashtest.trajectory.roadframe import RoadFrame

KITTI = Path(__file__).resolve().parents[2] / "shared" / "data" / "kitti_tracking"


def lane_span(sc: Scenario) -> tuple[tuple[float, float], tuple[float, float] | None]:
    """(right, left) edge offsets (m) of the ego's carriageway and of the oncoming lanes (None if none)."""
    r = sc.road
    j = np.arange(r.lane_count + 1)
    centred = r.source.startswith("ego_path") or r.source == "road_users"
    b = (j - r.ego_lane - 0.5) * r.lane_width if centred else (j - r.lane_count / 2) * r.lane_width
    n_on, median = getattr(r, "oncoming_lane_count", 0), getattr(r, "median_width", 0.0)
    inner = float(b[-1]) + median
    return (float(b[0]), float(b[-1])), ((inner, inner + n_on * r.lane_width) if n_on else None)


def moving_along(sc: Scenario) -> dict[int, tuple[float, bool]]:
    """{agent id: (median lateral offset m of its observed positions from the road's centre line, oncoming)} of
    the vehicles that move (> 5 m) along the road (within 30 deg of its direction, either way)."""
    frame = RoadFrame.from_polyline(sc.road.centerline())
    out = {}
    for v in sc.agents:
        a = v.trajectory.arrays()
        seen = v.trajectory.observed
        xy = np.column_stack([a["x"], a["y"]])[np.asarray(seen, bool) if seen is not None else slice(None)]
        if v.category == "pedestrian" or len(xy) < 2 or np.hypot(*(xy[-1] - xy[0])) < 5.0:
            continue
        s, d = frame.project(xy)
        travel = float(np.arctan2(*(xy[-1] - xy[0])[::-1])) - float(frame.tangent(float(np.median(s)))[0])
        if abs(np.cos(travel)) >= np.cos(np.radians(30.0)):
            out[v.id] = (float(np.median(d)), bool(np.cos(travel) < 0))
    return out


def coverage(sc: Scenario) -> tuple[int, int, list[tuple[int, float]]]:
    """(held, counted, [(id, offset m) off the road]) of the vehicles moving along the road."""
    own, other = lane_span(sc)
    users = moving_along(sc)
    off = [
        (i, round(d, 1))
        for i, (d, _) in users.items()
        if not (own[0] <= d <= own[1] or (other is not None and other[0] <= d <= other[1]))
    ]
    return len(users) - len(off), len(users), off


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("inputs", nargs="+", help="scenario_raw.json files or kitti:N")
    ap.add_argument("--kitti", type=Path, default=KITTI, help="KITTI tracking root")
    args = ap.parse_args()
    total = [0, 0]
    for item in args.inputs:
        if item.startswith("kitti:"):
            from deepcrashtest.datasets.kitti.scenario import scenario_from_kitti

            raw, name = scenario_from_kitti(args.kitti, int(item[6:]), road_users=True), item
        else:
            raw, name = Scenario.load(item), Path(item).parent.name
        sc = process_scenario(raw, seed=0)
        held, counted, off = coverage(sc)
        total = [total[0] + held, total[1] + counted]
        r = sc.road
        onc = f"{getattr(r, 'oncoming_lane_count', '-')} oncoming, median {getattr(r, 'median_width', '-')}"
        print(f"{name}: {held}/{counted}  {r.lane_count} x {r.lane_width:.2f} m, ego {r.ego_lane}, {onc}, "
              f"{r.source}  off: {off}", flush=True)  # fmt: skip
    print(f"TOTAL held {total[0]}/{total[1]}")


if __name__ == "__main__":
    main()
