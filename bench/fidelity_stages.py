"""Where does reprojection IoU get lost? Raw localisation vs processed scenario vs replay, per clip.

For each clip folder of a fidelity work dir (``bench/fidelity_crashes.py --work DIR``: each holds
``scenario_raw.json`` and ``tracks.csv`` from stage 1), this runs stage 2 again on the raw scenario
(the code of this checkout), replays it, and measures the reprojection IoU of the tracked boxes
(:func:`deepcrashtest.eval.fidelity.reprojection_pairs`) for three sources:

* ``raw``: the raw scenario's own trajectories (localisation + ego-motion, no stage 2),
* ``proc``: the processed scenario (stage 2),
* ``sim``: its replay (``controller="replay"``),

each over the same tracked boxes (those of agents present in the raw scenario; an agent missing from
a later stage scores 0 there, the ``*_all`` columns), plus the IoU over the pairs each stage keeps
(``*_kept``, the figure ``evaluate fidelity`` reports). Nothing is written into DIR unless
``--write`` (then ``scenario.json`` is replaced by the new stage-2 output, for
``fidelity_crashes.py --reuse``).

Usage::

    python bench/fidelity_stages.py --work DIR [--clips a,b] [--write] [--json]
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "src"))

from deepcrashtest.eval.fidelity import read_tracks, reprojection_pairs  # noqa: E402
from deepcrashtest.scenario import Scenario  # noqa: E402
from deepcrashtest.trajectory.pipeline import process_scenario  # noqa: E402


def _iou(pairs: pd.DataFrame, src: str, keys: pd.Index) -> tuple[float | None, float | None]:
    """(mean IoU over ``keys`` with absent pairs as 0, mean IoU over the pairs this source has)."""
    if not len(keys):
        return None, None
    col = f"{src}_iou"
    s = pairs.set_index(["frame", "agent_id"])[col] if len(pairs) else pd.Series(dtype=float)
    s = s[~s.index.duplicated()]
    v = s.reindex(keys).to_numpy(float)
    kept = v[np.isfinite(v)]
    return float(np.nan_to_num(v, nan=0.0).mean()), (float(kept.mean()) if len(kept) else None)


def stage_row(folder: Path, write: bool = False) -> dict[str, Any]:
    """IoU of raw / processed / replay for one clip folder (see the module docstring)."""
    from deepcrashtest.sim import simulate

    raw = Scenario.load(folder / "scenario_raw.json")
    tracks = read_tracks(folder / "tracks.csv")
    proc = process_scenario(raw)
    if write:
        proc.save(folder / "scenario.json", force=True)
    sim = simulate(proc, controller="replay")
    p_raw = reprojection_pairs(raw, tracks)
    p_proc = reprojection_pairs(proc, tracks, sim)
    keys = p_raw.set_index(["frame", "agent_id"]).index if len(p_raw) else pd.MultiIndex.from_arrays([[], []])
    keys = keys[~keys.duplicated()]
    r_all, r_kept = _iou(p_raw, "processed", keys)
    p_all, p_kept = _iou(p_proc, "processed", keys)
    s_all, s_kept = _iou(p_proc, "simulated", keys)
    return {
        "clip": folder.name,
        "agents_raw": len(raw.agents),
        "agents_proc": len(proc.agents),
        "pairs": len(keys),
        "raw": r_kept,
        "proc_all": p_all,
        "proc_kept": p_kept,
        "sim_all": s_all,
        "sim_kept": s_kept,
        "t_max_s": proc.provenance.parameters.get("t_max_s"),
        "collision": None if proc.collision is None else sorted(proc.collision.participants),
        "warnings": [w for w in proc.warnings if w not in raw.warnings],
    }


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--work", type=Path, required=True, help="Fidelity work dir (one folder per clip).")
    ap.add_argument("--clips", default=None, help="Comma-separated clip names (default: every folder).")
    ap.add_argument("--write", action="store_true", help="Replace each clip's scenario.json by the new stage 2.")
    ap.add_argument("--json", action="store_true", help="One JSON object instead of the table.")
    args = ap.parse_args()
    names = args.clips.split(",") if args.clips else sorted(p.name for p in args.work.iterdir() if p.is_dir())
    rows = []
    for n in names:
        f = args.work / n
        if not (f / "scenario_raw.json").is_file():
            continue
        rows.append(stage_row(f, args.write))
        if not args.json:
            r = rows[-1]
            cells = [f"{r[k]:.2f}" if isinstance(r[k], float) else str(r[k]) for k in list(r)[:10]]
            print(" | ".join(cells), file=sys.stderr)
    if args.json:
        print(json.dumps({"clips": rows}, indent=1))
        return
    keys = ("raw", "proc_all", "proc_kept", "sim_all", "sim_kept")
    print("| clip | agents raw/proc | pairs | " + " | ".join(keys) + " | t_max s |")
    print("|---|---|---|" + "---|" * len(keys) + "---|")
    for r in rows:
        cells = ["-" if r[k] is None else f"{r[k]:.2f}" for k in keys]
        head = f"| {r['clip']} | {r['agents_raw']}/{r['agents_proc']} | {r['pairs']} | "
        print(head + " | ".join(cells) + f" | {r['t_max_s']:.2f} |")
    for k in keys:
        v = [r[k] for r in rows if r[k] is not None]
        print(f"mean {k}: {np.mean(v):.3f} over {len(v)} clips" if v else f"mean {k}: -")


if __name__ == "__main__":
    main()
