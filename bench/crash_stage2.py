"""Crash detection + crash-consistent stage 2 on already extracted clips, scored by `evaluate fidelity`.

    python bench/crash_stage2.py EXTRACTIONS_DIR OUT_DIR [CLIP ...]

EXTRACTIONS_DIR holds one folder per clip (``deepcrashtest extract`` output: ``scenario_raw.json``,
``tracks.csv``), named like the clip (``ccd_000031``, ``dad_000478``, ``highway_project_video``).
Per clip: the camera's image motion is measured from the source video (one decode), the crash is
detected (``pipeline.crash.crash_for_raw``), stage 2 runs, the replay is scored against
``bench/labels/{ccd,dad}_crashes.json``. Prints one JSON line per clip and a summary (crash reproduced:
right pair, |dt| <= 0.25 s, no contact before; mean reprojection IoU processed / replay).
Extraction itself is slow (minutes per clip on 2 cores): extract once, rerun this.
"""

from __future__ import annotations

import json
import shutil
import sys
import time
from pathlib import Path

import av
import numpy as np
import pandas as pd

from deepcrashtest.perception.crash_detect import GlobalMotion
from deepcrashtest.pipeline.crash import crash_for_raw
from deepcrashtest.pipeline.fidelity import run_fidelity
from deepcrashtest.scenario import Scenario
from deepcrashtest.trajectory.pipeline import process_scenario

LABELS = Path(__file__).resolve().parent / "labels"


def image_motion(video: Path) -> tuple[np.ndarray, np.ndarray]:
    gm = GlobalMotion()
    with av.open(str(video)) as c:
        for i, f in enumerate(c.decode(video=0)):
            gm.update(i, f.to_ndarray(format="bgr24"))
    return gm.arrays()


def run_clip(folder: Path, out: Path) -> dict:
    raw = Scenario.load(folder / "scenario_raw.json")
    tracks = pd.read_csv(folder / "tracks.csv")
    t0 = time.perf_counter()
    raw2, det = crash_for_raw(raw, tracks, image_motion(Path(raw.source.path)))
    sc = process_scenario(raw2)
    out.mkdir(parents=True, exist_ok=True)
    sc.save(out / "scenario.json", force=True)
    shutil.copy(folder / "tracks.csv", out / "tracks.csv")
    labels = LABELS / ("ccd_crashes.json" if folder.name.startswith("ccd") else "dad_crashes.json")
    _, summ = run_fidelity(out / "scenario.json", out, labels=labels, make_video=False, force=True)
    cr, rp = summ["crash"], summ["reprojection"]
    first = cr.get("first_contact")
    return {
        "clip": folder.name,
        "detected": [det.get("frame"), det.get("pair"), det.get("confidence")] if det.get("found") else None,
        "label": [cr.get("label", {}).get("contact_frame"), cr.get("label", {}).get("scenario_ids")],
        "replay_first_contact": None if first is None else [first["video_frame"], first["participants"]],
        "dt_s": cr.get("dt_s"),
        "reproduced": cr.get("reproduced"),
        "contacts_before": cr.get("contacts_before_crash"),
        "correction_m": sc.provenance.parameters.get("crash", {}).get("correction", {}).get("max_m"),
        "iou_processed": rp["processed"]["mean_iou"],
        "iou_replay": rp["simulated"]["mean_iou"],
        "seconds": round(time.perf_counter() - t0, 1),
    }


def main(argv: list[str]) -> None:
    root, out_root, only = Path(argv[0]), Path(argv[1]), set(argv[2:])
    rows = []
    for folder in sorted(p for p in root.iterdir() if (p / "scenario_raw.json").exists()):
        if only and folder.name not in only:
            continue
        row = run_clip(folder, out_root / folder.name)
        rows.append(row)
        print(json.dumps(row), flush=True)
    for prefix in ("ccd", "dad"):
        sel = [r for r in rows if r["clip"].startswith(prefix)]
        if sel:
            ious = [(r["iou_processed"], r["iou_replay"]) for r in sel if r["iou_processed"] is not None]
            print(
                f"{prefix}: reproduced {sum(bool(r['reproduced']) for r in sel)}/{len(sel)}; mean IoU processed "
                f"{np.mean([a for a, _ in ious]):.3f}, replay {np.mean([b or 0 for _, b in ious]):.3f}"
            )


if __name__ == "__main__":
    main(sys.argv[1:])
