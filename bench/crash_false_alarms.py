"""Crash detection on the normal driving before each labelled crash: how often it would report a crash there.

Each labelled crash clip's extraction (``tracks.csv`` + ``scenario_raw.json``, as ``bench/crash_detect_bench.py``
reads them) is cut ``--lead`` seconds before its contact frame: only the tracks and the camera's jolt up to that
frame are given to :func:`deepcrashtest.perception.crash_detect.detect_crash`, as if the video ended there. Its best
candidate's score is what a video of that driving alone would be given; at or above ``detect_crash``'s
``min_score`` (0.35) it is a false alarm (the crash's own road users closing in a second before their contact
count too: they are not in contact yet). Clips whose cut leaves less than 2 s are skipped.

Usage::

    python bench/crash_false_alarms.py --work DIR [--labels FILE ...] [--motion-cache DIR] [--lead 1.0] [--json F]

``--work`` and ``--labels`` as in ``bench/crash_detect_bench.py`` (the variants of ``bench/fidelity_perturbed.py``:
``--work WORK/zoom/out --labels WORK/zoom/labels.json``). Prints one line per clip and the count of false alarms.
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import numpy as np
import pandas as pd

sys.path.insert(0, str(Path(__file__).resolve().parent))

import crash_detect_bench as cdb  # noqa: E402

from deepcrashtest.datasets.crash_labels import CrashLabel, load_crash_labels  # noqa: E402
from deepcrashtest.perception.crash_detect import MIN_CRASH_SCORE, detect_crash  # noqa: E402
from deepcrashtest.pipeline.crash import world_tracks  # noqa: E402
from deepcrashtest.scenario import Scenario  # noqa: E402

MIN_SCORE = MIN_CRASH_SCORE  # detect_crash's default
MIN_LEFT_S = 2.0


def before_crash(name: str, label: CrashLabel, work: Path, cache: Path, lead_s: float) -> dict[str, object] | None:
    """The best crash candidate of clip ``name`` on its frames up to ``lead_s`` before the contact (None: skipped)."""
    d = work / name
    if not label.crash or label.contact_frame is None or not (d / "scenario_raw.json").is_file():
        return None
    cut = int(label.contact_frame - lead_s * label.fps)
    if cut < MIN_LEFT_S * label.fps:
        return None
    raw = Scenario.load(d / "scenario_raw.json")
    tracks = pd.read_csv(d / "tracks.csv")
    video = cdb.DATA / label.video  # an absolute path (a variant's) stays itself
    frames, shifts = cdb.global_motion(video, cache, None)
    keep = frames <= cut
    found = detect_crash(
        tracks[tracks["frame"] <= cut], raw.source.width, raw.source.height, float(raw.source.fps),
        (frames[keep], shifts[keep]), allowed={a.id for a in raw.agents}, min_score=0.0, world=world_tracks(raw),
        picture=cdb.video_picture_area(video),
    )  # fmt: skip
    score = 0.0 if found is None else round(found.confidence, 3)
    return {
        "clip": name,
        "cut_frame": cut,
        "score": score,
        "alarm": score >= MIN_SCORE,
        "pair": None if found is None else list(found.pair),
        "frame": None if found is None else found.frame,
    }


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--work", type=Path, required=True)
    ap.add_argument("--labels", type=Path, action="append", default=[])
    ap.add_argument("--motion-cache", type=Path, default=Path("/tmp/crashdet_motion"))
    ap.add_argument("--lead", type=float, default=1.0)
    ap.add_argument("--json", type=Path, default=None)
    args = ap.parse_args()
    labels: dict[str, CrashLabel] = {}
    for f in (*cdb.LABELS, *args.labels):
        labels.update(load_crash_labels(f))
    rows = [r for n in sorted(labels) if (r := before_crash(n, labels[n], args.work, args.motion_cache, args.lead))]
    for r in rows:
        print(" | ".join(str(r[k]) for k in ("clip", "cut_frame", "score", "alarm", "pair", "frame")))
    scores = [float(r["score"]) for r in rows]  # type: ignore[arg-type]
    print(
        f"{len(rows)} clips cut {args.lead:g} s before their contact: false alarms (score >= {MIN_SCORE}) "
        f"{sum(s >= MIN_SCORE for s in scores)}; score median {np.median(scores) if scores else float('nan'):.3f}, "
        f"max {max(scores, default=float('nan')):.3f}"
    )
    if args.json:
        args.json.write_text(json.dumps(rows, indent=1))


if __name__ == "__main__":
    main()
