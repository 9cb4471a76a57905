"""Export KITTI 0003/0008/0010 to every format; print timings and the accuracy of what was written.

Figures: seconds per format, max deviation of the OpenDRIVE reference line (re-read by pyxodr) from
the road waypoints, and max position error of the OpenSCENARIO polylines and CommonRoad states
against the Scenario. Run: ``python bench/export_bench.py`` (needs ../shared/data).
"""

from __future__ import annotations

import json
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
import shapely

ROOT = Path(__file__).resolve().parents[1]
KITTI = ROOT.parent / "shared" / "data" / "kitti_tracking"


def main() -> int:
    if not KITTI.exists():
        print(f"skipped: {KITTI} not found")
        return 0
    sys.path.insert(0, str(ROOT / "tests"))
    from pyxodr.road_objects.network import RoadNetwork

    from deepcrashtest.datasets.kitti.scenario import scenario_from_kitti
    from deepcrashtest.export import FORMATS, export_scenario
    from deepcrashtest.export.commonroad import OBSTACLE_ID_BASE
    from deepcrashtest.export.openscenario import entity_name, entry_time
    from export_helpers import read_xosc

    rows = []
    for seq in (3, 8, 10):
        sc = scenario_from_kitti(KITTI, seq)
        with tempfile.TemporaryDirectory() as tmp:
            out = Path(tmp)
            secs = {fmt: export_scenario(sc, fmt, out)["seconds"] for fmt in FORMATS}
            line = shapely.LineString(
                RoadNetwork(str(out / "road.xodr"), resolution=0.05).get_roads()[0].reference_line
            )
            ref_dev = max(line.distance(shapely.Point(p)) for p in sc.road.centerline())
            # OpenSCENARIO polylines replayed by the tests' independent reader vs the Scenario
            ents = read_xosc(out / "scenario.xosc")
            osc_err = 0.0
            for veh in sc.vehicles():
                ent = ents[entity_name(veh, sc.ego.id)]
                if ent.times.size < 2:
                    continue
                a = veh.trajectory.arrays()
                keep = a["t"] >= entry_time(veh) - 1e-9
                got = ent.centre_at(a["t"][keep])
                osc_err = max(osc_err, float(np.hypot(got[:, 0] - a["x"][keep], got[:, 1] - a["y"][keep]).max()))
            from commonroad.common.file_reader import CommonRoadFileReader

            cr, _ = CommonRoadFileReader(str(out / "commonroad.xml")).open()
            cr_err = 0.0
            for agent in sc.agents:
                try:
                    obs = cr.obstacle_by_id(OBSTACLE_ID_BASE + agent.id)
                except (KeyError, AttributeError):
                    continue
                if obs is None:
                    continue
                for st in [obs.initial_state, *obs.prediction.trajectory.state_list]:
                    ref = agent.trajectory.state_at(st.time_step * cr.dt)
                    cr_err = max(cr_err, float(np.hypot(st.position[0] - ref["x"], st.position[1] - ref["y"])))
        rows.append(
            {
                "sequence": seq,
                "vehicles": len(sc.vehicles()),
                "waypoints": len(sc.road.centerline_x),
                "seconds": secs,
                "xodr_reference_line_max_dev_m": ref_dev,
                "xosc_max_position_error_m": osc_err,
                "commonroad_max_position_error_m": cr_err,
            }
        )
    for r in rows:
        print(json.dumps(r))
    return 0


if __name__ == "__main__":
    t0 = time.perf_counter()
    rc = main()
    print(
        f"total {time.perf_counter() - t0:.1f} s (2 shared cores; timings contaminated by other jobs)", file=sys.stderr
    )
    raise SystemExit(rc)
