"""Shared set-up of the search benchmarks: KITTI 0008 with the oncoming car 10 moved to meet the ego."""

from __future__ import annotations

from pathlib import Path

from deepcrashtest.scenario import Scenario

KITTI = Path(__file__).resolve().parents[1].parent / "shared" / "data" / "kitti_tracking"
DURATION_S = 11.0  # the crash happens at ~8.7 s


def crash_scenario() -> Scenario:
    from deepcrashtest.datasets.kitti.scenario import scenario_from_kitti
    from deepcrashtest.sim.testcases import meet_ego

    if not KITTI.exists():
        raise SystemExit(f"real data not found: {KITTI}")
    return meet_ego(scenario_from_kitti(KITTI, 8), 10, 8.8)
