"""How much of the raw stage's reprojection IoU is lost vertically (camera pitch, road slope, depth)?

For each clip folder of a fidelity work dir (``bench/fidelity_crashes.py --work DIR``: ``scenario_raw.json``
and ``tracks.csv``), the raw scenario's boxes are projected (:func:`deepcrashtest.eval.fidelity.reprojection_pairs`,
with the camera's per-frame attitude when it has one) and then moved up or down so that their bottom edges meet
the tracked boxes': by one offset for the clip (a wrong mean pitch), one per frame (the camera's pitch at that
frame, a uniform road grade), one per track, or one per box (every vertical error gone). The mean IoU of each
is an upper bound of what a model of that kind could win; ``frame_std_px`` is the spread of the per-frame
offsets (a camera that nods, a road that changes grade). Nothing is written.

Usage::

    python bench/fidelity_vertical.py --work DIR [--clips a,b]
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np
import pandas as pd

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "src"))

from deepcrashtest.eval.fidelity import read_tracks, reprojection_pairs  # noqa: E402
from deepcrashtest.perception.boxes import iou_matrix  # noqa: E402
from deepcrashtest.scenario import Scenario  # noqa: E402


def _mean_iou(boxes: np.ndarray, tracked: np.ndarray, shift: np.ndarray) -> float:
    moved = boxes.copy()
    moved[:, [1, 3]] -= shift[:, None]
    return float(np.mean([iou_matrix(moved[k], tracked[k])[0, 0] for k in range(len(boxes))]))


def clip_row(folder: Path) -> dict[str, float | str | int]:
    """The raw IoU and its vertically aligned upper bounds for one clip folder (see the module docstring)."""
    raw = Scenario.load(folder / "scenario_raw.json")
    pairs = reprojection_pairs(raw, read_tracks(folder / "tracks.csv"))
    pairs = pairs[[b is not None for b in pairs["processed_box"]]] if len(pairs) else pairs
    if not len(pairs):
        return {"clip": folder.name, "pairs": 0}
    boxes = np.stack(list(pairs["processed_box"]))
    tracked = pairs[["x1", "y1", "x2", "y2"]].to_numpy(float)
    dv = pd.Series(boxes[:, 3] - tracked[:, 3])
    frame, track = pairs["frame"].to_numpy(), pairs["agent_id"].to_numpy()
    return {
        "clip": folder.name,
        "pairs": len(pairs),
        "raw": round(float(pairs["processed_iou"].mean()), 3),
        "clip_shift": round(_mean_iou(boxes, tracked, np.full(len(dv), dv.median())), 3),
        "per_frame": round(_mean_iou(boxes, tracked, dv.groupby(frame).transform("median").to_numpy()), 3),
        "per_track": round(_mean_iou(boxes, tracked, dv.groupby(track).transform("median").to_numpy()), 3),
        "per_box": round(_mean_iou(boxes, tracked, dv.to_numpy()), 3),
        "frame_std_px": round(float(dv.groupby(frame).median().std()), 1),
    }


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--work", type=Path, required=True)
    ap.add_argument("--clips", default="")
    args = ap.parse_args()
    names = args.clips.split(",") if args.clips else sorted(p.name for p in args.work.iterdir() if p.is_dir())
    rows = [clip_row(args.work / n) for n in names if (args.work / n / "scenario_raw.json").is_file()]
    table = pd.DataFrame(rows)
    print(table.to_string(index=False))
    print("mean", table.drop(columns=["clip", "pairs"]).mean().round(3).to_dict())


if __name__ == "__main__":
    main()
