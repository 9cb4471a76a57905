"""Hashes of simulator outputs (single runs, batches, perturbed paths) to compare two code versions bit for bit.

Usage (from a checkout's root): PYTHONPATH=src python bench/sim_fingerprint.py > fp.txt; then diff two outputs.
"""

import hashlib
import json
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from sim_speed import KITTI, bench_scenario  # noqa: E402

from deepcrashtest.datasets.kitti.scenario import scenario_from_kitti  # noqa: E402
from deepcrashtest.sim import simulate, simulate_batch  # noqa: E402
from deepcrashtest.sim.testcases import meet_ego  # noqa: E402


def h(*arrs: np.ndarray) -> str:
    m = hashlib.sha256()
    for a in arrs:
        m.update(np.ascontiguousarray(a).tobytes())
    return m.hexdigest()[:16]


sc = bench_scenario()
out = {}
for ctrl in ("aeb", "replay"):
    r = simulate(sc, controller=ctrl, duration=20.0)
    out[f"single_{ctrl}"] = (
        h(r.states, r.present)
        + " "
        + json.dumps(r.collisions, sort_keys=True)[:80]
        + json.dumps(r.metrics, sort_keys=True)
    )
rng = np.random.default_rng(0)
off = np.column_stack([rng.uniform(-15, 15, 600), rng.uniform(-1.5, 1.5, 600)])
for ctrl in ("aeb", "replay"):
    b = simulate_batch(sc, off, controller=ctrl, duration=20.0, chunk_size=256)
    out[f"batch_{ctrl}"] = h(*[getattr(b, k) for k in b.__dataclass_fields__])
full = meet_ego(scenario_from_kitti(KITTI, 8), 10, 8.8)
r = simulate(full, controller="aeb")
out["full0008_aeb"] = h(r.states, r.present) + json.dumps(r.collisions, sort_keys=True)
r = simulate(scenario_from_kitti(KITTI, 3), controller="replay")
out["kitti3_replay"] = h(r.states, r.present)
tr = full.ego.trajectory
paths = np.stack(
    [
        np.column_stack(
            [
                np.interp(np.linspace(tr.t[0], tr.t[-1], 40), tr.t, tr.x),
                np.interp(np.linspace(tr.t[0], tr.t[-1], 40), tr.t, tr.y),
            ]
        )
        + rng.normal(0, 0.3, (40, 2))
        for _ in range(40)
    ]
)
b = simulate_batch(full, np.zeros((40, 2)), ego_paths=paths, controller="aeb", duration=11.0, seed=5)
out["paths_aeb"] = h(*[getattr(b, k) for k in b.__dataclass_fields__])
for k, v in out.items():
    print(k, v)
