"""Stage 2 on KITTI tracking 0003/0008/0010 (real labels + ORB-SLAM3 poses): classes, smoothing error
and jerk, step-back t_max, run time; bird's-eye PNGs into out/bench/trajectory/.

Run from the project root: ``python bench/trajectory_kitti.py``. Timings on a shared machine are
indicative only.
"""

from __future__ import annotations

import time
from collections import Counter
from pathlib import Path

import numpy as np

from deepcrashtest.datasets.kitti.scenario import scenario_from_kitti
from deepcrashtest.trajectory.pipeline import process_scenario
from deepcrashtest.viz.plots import plot_birdseye

ROOT = Path(__file__).resolve().parents[1]
KITTI = ROOT.parent / "shared" / "data" / "kitti_tracking"
OUT = ROOT / "out" / "bench" / "trajectory"


def rms_jerk(t: np.ndarray, xy: np.ndarray) -> float:
    j = np.diff(xy, n=3, axis=0) / float(np.mean(np.diff(t))) ** 3
    return float(np.sqrt((j**2).sum(axis=1).mean()))


def main() -> None:
    if not KITTI.exists():
        print(f"skipped: {KITTI} not found")
        return
    OUT.mkdir(parents=True, exist_ok=True)
    for seq in (3, 8, 10):
        raw = scenario_from_kitti(KITTI, seq)
        t0 = time.perf_counter()
        sc = process_scenario(raw)
        dt = time.perf_counter() - t0
        t_max = sc.provenance.parameters["t_max_s"]
        sq, n, worst, jr, js = 0.0, 0, 0.0, [], []
        for v in sc.vehicles():
            a = v.trajectory.arrays()
            if v.trajectory_class is not None and np.all(a["speed"] == 0):
                continue  # parked: held at the mean position on purpose
            r = raw.vehicle(v.id).trajectory.arrays()
            obs = np.asarray(v.trajectory.observed)
            xy_raw = np.column_stack([r["x"], r["y"]])
            xy = np.column_stack([a["x"][obs], a["y"][obs]])
            e2 = ((xy - xy_raw) ** 2).sum(axis=1)
            sq, n, worst = sq + e2.sum(), n + len(e2), max(worst, float(np.sqrt(e2.mean())))
            if len(r["t"]) >= 10:
                jr.append(rms_jerk(r["t"], xy_raw))
                js.append(rms_jerk(r["t"], xy))
        classes = dict(sorted(Counter(str(a.trajectory_class) for a in sc.agents).items()))
        png = plot_birdseye(sc, raw, OUT / f"kitti_{seq:04d}_birdseye.png", force=True)
        print(
            f"{seq:04d}: agents {len(sc.agents)}/{len(raw.agents)} classes {classes} t_max {t_max:.2f} s "
            f"road lanes {sc.road.lane_count} (ego lane {sc.road.ego_lane}) | smoothing RMS {np.sqrt(sq / n):.3f} m "
            f"(worst vehicle {worst:.3f} m) | RMS jerk median raw {np.median(jr):.1f} -> smoothed "
            f"{np.median(js):.2f} m/s^3 ({np.median(jr) / np.median(js):.0f}x lower) | max |accel| "
            f"{max(v.trajectory.max_abs_accel()[0] for v in sc.vehicles()):.1f} m/s^2 | {dt:.2f} s | {png}"
        )


if __name__ == "__main__":
    main()
