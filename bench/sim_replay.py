"""Replay accuracy and AEB outcomes on KITTI tracking 0003/0008/0010 (real ground-truth trajectories).

For each sequence: replay RMS position error (simulated centre vs the scenario's samples, every
sample where the vehicle exists) for the ego, the agents and all vehicles; the AEB run's outcome;
then the crash test cases built from real trajectories (sim.testcases.meet_ego). Prints JSON lines.
"""

from __future__ import annotations

import json
import sys
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "src"))

from deepcrashtest.datasets.kitti.scenario import scenario_from_kitti  # noqa: E402
from deepcrashtest.sim import replay_error, simulate  # noqa: E402
from deepcrashtest.sim.testcases import meet_ego  # noqa: E402

KITTI = Path(__file__).resolve().parents[2] / "shared" / "data" / "kitti_tracking"
KEYS = ("collided", "collision_time", "collision_vehicle", "relative_speed", "delta_v_ego", "min_distance", "min_ttc",
        "aeb_time", "warning_time")  # fmt: skip


def _r(v):
    return round(v, 3) if isinstance(v, float) else v


def main() -> None:
    if not KITTI.exists():
        print(json.dumps({"skipped": f"real data not found: {KITTI}"}))
        return
    for seq in (3, 8, 10):
        sc = scenario_from_kitti(KITTI, seq)
        t0 = time.perf_counter()
        rep = simulate(sc)
        wall = time.perf_counter() - t0
        err = replay_error(sc, rep)
        aeb = simulate(sc, controller="aeb")
        print(json.dumps({
            "sequence": f"{seq:04d}", "stage": sc.stage, "vehicles": 1 + len(sc.agents),
            "duration_s": round(float(rep.times[-1]), 2), "replay_wall_s": round(wall, 2),
            "rms_ego_m": _r(err["ego"]), "rms_agents_m": _r(err["agents"]), "rms_all_m": _r(err["all"]),
            "worst_vehicle": max(err["per_vehicle"].items(), key=lambda kv: kv[1]),
            "replay": {k: _r(rep.metrics[k]) for k in KEYS}, "aeb": {k: _r(aeb.metrics[k]) for k in KEYS},
        }))  # fmt: skip
    base = scenario_from_kitti(KITTI, 8)
    for agent, t_c in ((11, 10.0), (8, 5.0)):
        sc = meet_ego(base, agent, t_c)
        for ctrl in ("replay", "aeb"):
            m = simulate(sc, controller=ctrl, duration=t_c + 4.0).metrics
            print(json.dumps({"case": sc.name, "controller": ctrl, **{k: _r(m[k]) for k in KEYS}}))


if __name__ == "__main__":
    main()
