"""Crash detection alone against the crash labels: the pair, the time, the confidence, and tracking.

Per clip (the six DAD clips, the 13 CCD clips, the highway clip without a crash): the automatic crash of
:func:`deepcrashtest.pipeline.crash.crash_for_raw` on a stage-1 extraction (``tracks.csv`` +
``scenario_raw.json``) against ``bench/labels/``: is the pair right (each labelled road user resolved
to its track as ``evaluate fidelity`` does), |dt| in seconds (video time), the confidence, and whether
each labelled road user is a track at the contact frame (IoU >= 0.3 within +-2 frames) and an agent.

Split (fixed before tuning, by sorted CCD name): tune on the DAD clips and the CCD clips at even
positions (ccd_000014, 000053, 000132, 000340, 000721, 000882, 001143); report on the odd ones
(ccd_000031, 000080, 000330, 000487, 000755, 001135).

Usage::

    python bench/crash_detect_bench.py [--work DIR ...] [--clips a,b] [--json FILE] [--labels FILE ...]

Each clip's extraction is taken from the first ``--work`` folder that has it (default: the
extractions of ``bench/fidelity_crashes.py`` in /tmp/deepcrashtest_fidelity). The camera's global motion (for
the jolt) needs the video decoded once; it is cached as ``motion_<clip>.npz`` in ``--motion-cache``
(default /tmp/crashdet_motion). ``--labels /tmp/robust/labels.json --work /tmp/robust/out_TAG`` scores the
variants of ``bench/robust_variants.py`` (their own videos, frame rates and picture inside black bars) in
an "other" split.
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

from deepcrashtest.datasets.crash_labels import CrashLabel, load_crash_labels  # noqa: E402
from deepcrashtest.eval.fidelity import LABEL_FRAME_SLACK, LABEL_TRACK_IOU, resolve_participants  # noqa: E402
from deepcrashtest.perception.boxes import iou_matrix  # noqa: E402
from deepcrashtest.perception.crash_detect import GlobalMotion  # noqa: E402
from deepcrashtest.pipeline.crash import crash_for_raw  # noqa: E402
from deepcrashtest.scenario import Scenario  # noqa: E402
from deepcrashtest.video.bars import video_picture_area  # noqa: E402
from deepcrashtest.video.source import open_video  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]
DATA = ROOT.parent / "shared" / "data"
if not DATA.is_dir():
    DATA = Path("/work/shared/data")
LABELS = (ROOT / "bench" / "labels" / "dad_crashes.json", ROOT / "bench" / "labels" / "ccd_crashes.json")
CCD_ALL = sorted(load_crash_labels(LABELS[1]))
HELD_OUT = set(CCD_ALL[1::2])
BASE = {n for f in LABELS for n in load_crash_labels(f)}
CRASH_DT_S = 0.25


def global_motion(video: Path, cache: Path, max_frames: int | None) -> tuple[np.ndarray, np.ndarray]:
    """(frames, shifts) of the camera's global image motion inside black bars (as extract measures it),
    decoded once and cached."""
    area = video_picture_area(video)
    f = cache / f"motion_{video.stem}.npz"
    if area is not None and area[:2] != (0, 0):  # bars: not the cache of a motion measured over them
        f = cache / f"motion_{video.stem}_{'-'.join(map(str, area))}.npz"
    if f.is_file():
        z = np.load(f)
        return z["frames"], z["shifts"]
    gm = GlobalMotion(area=area)
    with open_video(video) as src:
        for fr in src:
            if max_frames is not None and fr.index >= max_frames:
                break
            gm.update(fr.index, fr.image)
    frames, shifts = gm.arrays()
    cache.mkdir(parents=True, exist_ok=True)
    np.savez(f, frames=frames, shifts=shifts)
    return frames, shifts


def tracked(label: CrashLabel, tracks: pd.DataFrame) -> list[int | None]:
    """Per labelled road user: the track id covering its box near the contact frame (None: no track)."""
    out: list[int | None] = []
    for p in label.participants:
        if p.ego or p.box is None or label.contact_frame is None:
            continue
        tid = None
        for slack in range(LABEL_FRAME_SLACK + 1):
            near = tracks[(tracks["frame"] - label.contact_frame).abs() == slack]
            if len(near):
                iou = iou_matrix(np.array(p.box, float), near[["x1", "y1", "x2", "y2"]].to_numpy(float))[0]
                if iou.max() >= LABEL_TRACK_IOU:
                    tid = int(near["track_id"].iloc[int(iou.argmax())])
                    break
        out.append(tid)
    return out


def run_clip(name: str, label: CrashLabel, dirs: list[Path], cache: Path) -> dict[str, Any]:
    """One table row."""
    d = next((w / name for w in dirs if (w / name / "scenario_raw.json").is_file()), None)
    if d is None:
        return {"clip": name, "error": "no extraction"}
    raw = Scenario.load(d / "scenario_raw.json")
    tracks = pd.read_csv(d / "tracks.csv")
    last = int(tracks["frame"].max()) + 1 if len(tracks) else None
    motion = global_motion(DATA / label.video, cache, last if name.startswith("highway") else None)
    picture = video_picture_area(DATA / label.video)
    stored = raw.provenance.parameters.get("frames_scaled_from")  # processed scaled (--max-width): its pixels
    if stored:
        kx, ky = raw.source.width / stored[0], raw.source.height / stored[1]
        label = label.scaled(kx, ky)  # as ``evaluate fidelity`` scales it (pipeline.fidelity.pick_label)
        if picture is not None:
            x0, y0, x1, y1 = picture
            picture = (round(x0 * kx), round(y0 * ky), round(x1 * kx), round(y1 * ky))
    scen, rec = crash_for_raw(raw, tracks, motion, picture=picture)
    col = scen.collision
    split = "held-out" if name in HELD_OUT else "tune" if name in BASE else "other"
    row: dict[str, Any] = {"clip": name, "split": split, "from": str(d.parent)}
    row["found"] = None if col is None else sorted(col.participants)
    row["frame"] = rec.get("frame")
    row["conf"] = rec.get("confidence")
    if not label.crash:
        row.update(ok=col is None, pair_ok=None, dt=None, tracked="-", agents="-")
        return row
    if label.contact_frame is None:
        row.update(ok=None, pair_ok=None, dt=None, tracked="-", agents="-")
        return row
    ids, _notes = resolve_participants(label, raw, tracks)
    tids = tracked(label, tracks)
    n_users = len(tids)
    row["label_ids"] = ids
    row["tracked"] = f"{sum(t is not None for t in tids)}/{n_users}"
    row["agents"] = f"{sum(i is not None for i, p in zip(ids, label.participants, strict=True) if not p.ego)}/{n_users}"
    pair = sorted(i for i in ids if i is not None) if None not in ids else None
    row["pair_ok"] = bool(col is not None and pair is not None and sorted(col.participants) == pair)
    row["dt"] = None if col is None else round(rec["frame"] / label.fps - label.contact_frame / label.fps, 3)
    row["ok"] = bool(row["pair_ok"] and row["dt"] is not None and abs(row["dt"]) <= CRASH_DT_S)
    return row


def summary(rows: list[dict[str, Any]], which: str) -> str:
    """One line per split: crash clips with a contact frame (pair right, and |dt| too), tracking, and the
    clips without a crash that stay without one."""
    sel = [r for r in rows if r.get("split") == which and "error" not in r]
    crash = [r for r in sel if r.get("pair_ok") is not None]
    quiet = [r for r in sel if r.get("tracked") == "-" and r.get("ok") is not None]
    pair = sum(bool(r["pair_ok"]) for r in crash)
    ok = sum(bool(r["ok"]) for r in crash)
    tr = [tuple(map(int, r["tracked"].split("/"))) for r in crash]
    ag = [tuple(map(int, r["agents"].split("/"))) for r in crash]
    dts = [abs(r["dt"]) for r in crash if r.get("pair_ok") and r.get("dt") is not None]
    return (
        f"{which}: {len(crash)} crash clips, pair right {pair}, pair+|dt|<=0.25 s {ok}, labelled road users "
        f"tracked {sum(a for a, _ in tr)}/{sum(b for _, b in tr)}, agents {sum(a for a, _ in ag)}/"
        f"{sum(b for _, b in ag)}, median |dt| (right pair) {np.median(dts) if dts else float('nan'):.2f} s; "
        f"no-crash clips without a crash {sum(bool(r['ok']) for r in quiet)}/{len(quiet)}"
    )


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--work", action="append", type=Path, default=None)
    ap.add_argument("--clips", default=None)
    ap.add_argument("--motion-cache", type=Path, default=Path("/tmp/crashdet_motion"))
    ap.add_argument("--json", type=Path, default=None)
    ap.add_argument("--labels", type=Path, action="append", default=[], help="more label files (variants)")
    args = ap.parse_args()
    dirs = list(args.work or []) + [Path("/tmp/deepcrashtest_fidelity")]
    labels: dict[str, CrashLabel] = {}
    for f in (*LABELS, *args.labels):
        labels.update(load_crash_labels(f))
    names = args.clips.split(",") if args.clips else sorted(labels)
    rows = [run_clip(n, labels[n], dirs, args.motion_cache) for n in names]
    cols = ("clip", "split", "found", "label_ids", "frame", "dt", "conf", "pair_ok", "ok", "tracked", "agents")
    print(" | ".join(cols))
    for r in rows:
        print(" | ".join(str(r.get(c, "")) for c in cols))
    for which in ("tune", "held-out", "other"):
        print(summary(rows, which))
    if args.json:
        args.json.write_text(json.dumps(rows, indent=1))


if __name__ == "__main__":
    main()
