"""Which drag falloff lets a user move a waypoint 3 m on a processed scenario? (chooses DEFAULT_FALLOFF_S)

For every vehicle of each processed scenario, 12 observed waypoints spread over its path are dragged
3 m in four directions (ahead, behind, left, right of the vehicle's heading); for each drag the
shortest falloff of ``FALLOFF_LADDER_S`` that keeps |acceleration| within the Scenario's physical
limit is found. Prints the share of drags each falloff allows.

Scenarios: KITTI tracking 0008 after stage 2 (tuning set; 0003 and 0010 are held out and printed
separately), plus any ``scenario.json`` paths given on the command line (e.g. an extracted DAD clip).
Run: ``python bench/viewer_drag.py [scenario.json ...]`` (needs ../shared/data).
"""

from __future__ import annotations

import math
import sys
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
KITTI = ROOT.parent / "shared" / "data" / "kitti_tracking"
DRAG_M = 3.0


def shortest_falloffs(sc) -> list[float]:  # type: ignore[no-untyped-def]
    from deepcrashtest.scenario import MAX_ACCEL_MPS2
    from deepcrashtest.viz.edit import FALLOFF_LADDER_S, drag_accel

    out = []
    for v in sc.vehicles():
        tr = v.trajectory
        obs = np.asarray(tr.observed if tr.observed is not None else [True] * len(tr.t))
        idx = np.nonzero(obs)[0]
        if len(idx) < 3:
            continue
        for i in idx[np.linspace(1, len(idx) - 2, 12).astype(int)]:
            yaw = tr.yaw[i]
            for ang in (0.0, math.pi, math.pi / 2, -math.pi / 2):
                dx, dy = DRAG_M * math.cos(yaw + ang), DRAG_M * math.sin(yaw + ang)
                ok = next((f for f in FALLOFF_LADDER_S if drag_accel(v, int(i), dx, dy, f) <= MAX_ACCEL_MPS2), math.inf)
                out.append(ok)
    return out


def report(name: str, falloffs: list[float]) -> None:
    from deepcrashtest.viz.edit import FALLOFF_LADDER_S

    f = np.asarray(falloffs)
    shares = ", ".join(f"{x:g} s: {np.mean(f <= x):.0%}" for x in FALLOFF_LADDER_S)
    print(f"{name}: {len(f)} drags of {DRAG_M:g} m; share drivable at falloff <= {shares}")


def main() -> int:
    from deepcrashtest.datasets.kitti.scenario import scenario_from_kitti
    from deepcrashtest.scenario import Scenario
    from deepcrashtest.trajectory.pipeline import process_scenario

    if KITTI.exists():
        for seq, role in ((8, "tuning"), (3, "held out"), (10, "held out")):
            sc = process_scenario(scenario_from_kitti(KITTI, seq))
            report(f"KITTI {seq:04d} processed ({role})", shortest_falloffs(sc))
    else:
        print(f"skipped KITTI: {KITTI} not found")
    for path in sys.argv[1:]:
        report(path, shortest_falloffs(Scenario.load(path)))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
