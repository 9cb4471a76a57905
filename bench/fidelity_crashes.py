"""Reconstruction fidelity on real crash clips: extract -> scenario -> replay -> fidelity, one table.

Clips: the six DAD clips, the 13 CCD clips and the Udacity highway clip (no crash), with the labels
in ``bench/labels/``. Per clip: the labelled crash, whether the replay's first contact reproduces it
(same pair and |dt| <= 0.25 s, video time), |dt|, mean reprojection IoU of the processed scenario and
of the replay against the tracked boxes, and the contacts the replay has before the labelled crash.

Usage::

    python bench/fidelity_crashes.py [--clips dad_000478,ccd_000014] [--max-frames N] [--work DIR]
                                     [--reuse] [--stage2 [--redetect]] [--video] [--json]

Extraction is the slow part (~2-4 min per DAD clip on a loaded 2-core machine): ``--reuse`` keeps the
extraction outputs already in ``--work`` (default ``/tmp/deepcrashtest_fidelity``); ``--max-frames``
caps the frames of every clip (the highway clip is capped at 300 frames, 12 s, unless given).
``--stage2`` reruns stage 2 from the extraction's ``scenario_raw.json`` (with the crash stage 1 found);
``--redetect`` also reruns the automatic crash detection on its ``tracks.csv`` first (the camera's
global motion decoded once and cached as in ``bench/crash_detect_bench.py``).
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import time
from pathlib import Path
from typing import Any

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "src"))

from deepcrashtest.datasets.crash_labels import CrashLabel, load_crash_labels  # noqa: E402
from deepcrashtest.eval.plausibility import OVERLAP_MIN_S, SLIDE_MAX_DEG, SPIN_DEG  # noqa: E402
from deepcrashtest.pipeline.extract import run_extract  # noqa: E402
from deepcrashtest.pipeline.fidelity import run_fidelity  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]
DATA = ROOT.parent / "shared" / "data"
LABELS = (ROOT / "bench" / "labels" / "dad_crashes.json", ROOT / "bench" / "labels" / "ccd_crashes.json")
HIGHWAY_FRAMES = 300


def all_labels() -> dict[str, tuple[Path, CrashLabel]]:
    """Every labelled clip: name -> (label file, label)."""
    out: dict[str, tuple[Path, CrashLabel]] = {}
    for f in LABELS:
        out.update({k: (f, v) for k, v in load_crash_labels(f).items()})
    return out


def run_clip(name: str, label_file: Path, label: CrashLabel, work: Path, args: argparse.Namespace) -> dict[str, Any]:
    """Extract (unless reused), then evaluate the fidelity of one clip; returns the table row."""
    video = DATA / label.video
    out = work / name
    max_frames = args.max_frames or (HIGHWAY_FRAMES if name.startswith("highway") else None)
    t0 = time.perf_counter()
    restage_only = args.stage2 or args.labelled_crash or args.redetect
    done = out / ("scenario_raw.json" if restage_only else "scenario.json")
    if not (args.reuse and done.is_file()):
        run_extract(video, out, max_frames=max_frames, force=True, report=False, annotate=False)
    t_extract = time.perf_counter() - t0
    crash_given = None
    cpu0, wall0 = time.process_time(), time.perf_counter()
    if restage_only:
        motion = redetect_motion(name, video, max_frames) if args.redetect and not args.labelled_crash else None
        crash_given = restage(out, label, args.labelled_crash, motion, video)
    stage2_cpu_s = time.process_time() - cpu0 if restage_only else None
    stage2_wall_s = time.perf_counter() - wall0 if restage_only else None
    if not (out / "scenario.json").is_file():
        return {"clip": name, "error": "extraction produced no processed scenario"}
    res, summary = run_fidelity(
        out / "scenario.json", out / "fidelity", video=video, tracks=out / "tracks.csv", labels=label_file,
        clip=name, make_video=args.video, force=True,
    )  # fmt: skip
    rep, crash = summary["reprojection"], summary["crash"]
    first = crash["first_contact"]
    dt = crash.get("dt_s")
    return {
        "clip": name,
        "label": "no crash"
        if not label.crash
        else "not seen"
        if label.contact_frame is None
        else " + ".join(p.category or "ego" if not p.ego else "ego" for p in label.participants),
        "label_ids": crash.get("label", {}).get("scenario_ids"),
        "first_contact": None if first is None else first["participants"],
        "first_contact_video_s": None if first is None else first["video_time_s"],
        "same_pair": crash.get("same_pair"),
        "abs_dt_s": None if dt is None else abs(dt),
        "reproduced": crash.get("reproduced"),
        "contacts_before_crash": crash.get("contacts_before_crash"),
        "iou_processed": rep["processed"]["mean_iou"],
        "iou_simulated": rep["simulated"]["mean_iou"],
        "iou_all_boxes": rep.get("all_tracked_boxes"),
        "share50_processed": rep["processed"]["share_iou_ge_0_5"],
        "centre_px_processed": rep["processed"]["median_centre_px"],
        "tracks_in_scenario": f"{rep['tracks_in_scenario']}/{rep['tracks']}",
        "plausibility": {k: v for k, v in summary.get("plausibility", {}).items() if k != "rule"},
        "scenario_collision_same_pair": (crash.get("scenario_collision") or {}).get("same_pair"),
        "notes": summary["notes"],
        "extract_s": round(t_extract, 1),
        "stage2_cpu_s": None if stage2_cpu_s is None else round(stage2_cpu_s, 2),
        "stage2_wall_s": None if stage2_wall_s is None else round(stage2_wall_s, 2),
        "crash_given": crash_given,
        "correction": correction_record(out / "scenario.json"),
    }


def redetect_motion(name: str, video: Path, max_frames: int | None) -> tuple[Any, Any]:
    """The camera's global motion of ``video`` for the automatic crash detection (cached)."""
    from crash_detect_bench import global_motion  # the same cache as the crash detection bench

    return global_motion(video, Path(os.environ.get("CRASHDET_MOTION", "/tmp/crashdet_motion")), max_frames)


def restage(
    out: Path, label: CrashLabel, labelled: bool, motion: tuple[Any, Any] | None = None, video: Path | None = None
) -> str | None:
    """Rerun stage 2 from ``out/scenario_raw.json``; ``labelled``: with the labelled crash given as the
    user's ``--crash FRAME:ID,ID`` (label boxes -> track ids at the contact frame). Returns that spec.
    ``motion`` (the camera's global motion): rerun the automatic crash detection first, inside the picture of
    ``video`` between black bars as extract does (without it, a letterboxed clip's road users never reached the
    picture's bottom: 8 of the 18 portrait copies' ego crashes were not found again)."""
    from deepcrashtest.eval.fidelity import read_tracks, resolve_participants
    from deepcrashtest.pipeline.crash import CrashSpec, crash_for_raw
    from deepcrashtest.pipeline.stage2 import processed_scenario
    from deepcrashtest.scenario import Scenario

    raw = Scenario.load(out / "scenario_raw.json")
    spec = None
    if labelled and label.crash and label.contact_frame is not None:
        ids, _notes = resolve_participants(label, raw, read_tracks(out / "tracks.csv"))
        if None not in ids:
            pair = (int(ids[0] or 0), int(ids[1] or 0))
            text = f"{label.contact_frame}:{pair[0] or 'ego'},{pair[1] or 'ego'}"
            spec = CrashSpec(int(label.contact_frame), pair, text)
            raw, _rec = crash_for_raw(raw, read_tracks(out / "tracks.csv"), None, spec)
    elif motion is not None:
        from deepcrashtest.video.bars import video_picture_area

        picture = video_picture_area(video) if video is not None else None
        raw, _rec = crash_for_raw(raw, read_tracks(out / "tracks.csv"), motion, picture=picture)
        raw.save(out / "scenario_raw.json", force=True)
    processed_scenario(raw).save(out / "scenario.json", force=True)
    return None if spec is None else spec.text


def correction_record(path: Path) -> Any:
    """The crash phase's record of stage 2 (``provenance.parameters["crash"]``), if any."""
    if not path.is_file():
        return None
    return json.loads(path.read_text())["provenance"]["parameters"].get("crash")


def _cell(v: Any) -> str:
    if v is None:
        return "-"
    if isinstance(v, float):
        return f"{v:.2f}"
    if isinstance(v, list):
        return "-".join(str(x) for x in v)
    return str(v)


COLUMNS = (
    ("clip", "clip"), ("label", "labelled crash"), ("label_ids", "label ids"), ("first_contact", "sim 1st contact"),
    ("same_pair", "same pair"), ("abs_dt_s", "|dt| s"), ("reproduced", "reproduced"),
    ("contacts_before_crash", "contacts before"), ("iou_processed", "IoU proc"), ("iou_simulated", "IoU sim"),
    ("tracks_in_scenario", "tracks in sc."), ("scenario_collision_same_pair", "sc. collision pair"),
)  # fmt: skip


def markdown(rows: list[dict[str, Any]]) -> str:
    lines = ["| " + " | ".join(h for _, h in COLUMNS) + " |", "|" + "---|" * len(COLUMNS)]
    for r in rows:
        lines.append("| " + " | ".join(_cell(r.get(k)) for k, _ in COLUMNS) + " |")
    labelled = [r for r in rows if r.get("reproduced") is not None]
    ok = sum(bool(r["reproduced"]) for r in labelled)
    lines.append(f"\nreproduced {ok}/{len(labelled)} labelled outcomes")
    lines.append("mean IoU processed / replay: " + " / ".join(_mean_of(rows, k) for k in ("processed", "simulated")))
    lines.append(
        "the same over every tracked box (coasting ones included): "
        + " / ".join(_mean_of(rows, k, every=True) for k in ("processed", "simulated"))
    )
    lines.append(plausibility_line(rows))
    return "\n".join(lines)


def plausibility_line(rows: list[dict[str, Any]]) -> str:
    """The clips' vehicles' plausibility (``eval.plausibility``) summed over the clips, as one line."""
    p = [r["plausibility"] for r in rows if r.get("plausibility")]
    if not p:
        return "plausibility: not in these rows (written before it was measured)"
    steps, over = sum(x["steps"] for x in p), sum(x["over_turning"] for x in p)
    moving, sliding = sum(x["moving"] for x in p), sum(x["sliding"] for x in p)
    traction = sum(x.get("over_traction", 0) for x in p)
    unseen, unseen_over = sum(x.get("unseen_steps", 0) for x in p), sum(x.get("unseen_over_turning", 0) for x in p)
    flipped = sum(len(x["vehicles_with_half_turns"]) for x in p)
    spinning = sum(len(x.get("vehicles_spinning", [])) for x in p)
    through = [len(x["overlapping_pairs"]) for x in p if "overlapping_pairs" in x]
    joining = [len(x["overlapping_on_joining"]) for x in p if "overlapping_on_joining" in x]
    return (
        f"vehicles turned half round between two samples: {flipped} of {sum(x['vehicles'] for x in p)}; "
        f"steps turning beyond the steering limit {over}/{steps} ({100 * over / max(steps, 1):.1f} %); "
        f"steps beyond the vehicle's traction {traction}/{steps} ({100 * traction / max(steps, 1):.1f} %); "
        f"moving samples sliding > {SLIDE_MAX_DEG:g} deg off their motion {sliding}/{moving} "
        f"({100 * sliding / max(moving, 1):.1f} %); unseen steps (lead-in, extrapolation) turning beyond the "
        f"steering limit {unseen_over}/{unseen} ({100 * unseen_over / max(unseen, 1):.1f} %); vehicles spinning (a "
        f"heading > {SPIN_DEG:g} deg beyond the steering limit over the distance driven) {spinning}"
        + (
            f"; pairs of road users passing through each other (>= {OVERLAP_MIN_S:g} s) {sum(through)} in "
            f"{sum(1 for n in through if n)} of {len(through)} clips"
            if through
            else ""
        )
        + (
            f"; pairs inside each other where the later one joins the scenario {sum(joining)} in "
            f"{sum(1 for n in joining if n)} of {len(joining)} clips"
            if joining
            else ""
        )
    )


def _mean_of(rows: list[dict[str, Any]], source: str, every: bool = False) -> str:
    """Mean over the clips of one IoU column (``every``: over all tracked boxes), as text."""
    key = "iou_processed" if source == "processed" else "iou_simulated"
    vals = [(r.get("iou_all_boxes") or {}).get(source) if every else r.get(key) for r in rows]
    vals = [v for v in vals if v is not None]
    return f"{sum(vals) / len(vals):.3f}" if vals else "-"


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--clips", default=None, help="Comma-separated clip names (default: all labelled clips).")
    ap.add_argument("--max-frames", type=int, default=None, help="Frames per clip (default: all; highway 300).")
    ap.add_argument("--work", type=Path, default=Path("/tmp/deepcrashtest_fidelity"), help="Working folder.")
    ap.add_argument("--reuse", action="store_true", help="Reuse extraction outputs already in --work.")
    ap.add_argument("--stage2", action="store_true", help="Rerun stage 2 from scenario_raw.json in --work.")
    ap.add_argument(
        "--labelled-crash",
        action="store_true",
        help="Rerun stage 2 with the labelled crash given as the user's --crash.",
    )
    ap.add_argument(
        "--redetect",
        action="store_true",
        help="With --stage2: rerun the automatic crash detection on tracks.csv first (rewrites scenario_raw.json).",
    )
    ap.add_argument("--video", action="store_true", help="Also write fidelity.mp4 per clip.")
    ap.add_argument("--json", action="store_true", help="Print one JSON object instead of the table.")
    args = ap.parse_args()
    if not DATA.exists():
        print(json.dumps({"skipped": f"real data not found: {DATA}"}))
        return
    labels = all_labels()
    names = args.clips.split(",") if args.clips else list(labels)
    unknown = [n for n in names if n not in labels]
    if unknown:
        sys.exit(f"unknown clips {unknown} (labelled: {', '.join(labels)})")
    rows = []
    for name in names:
        f, lab = labels[name]
        rows.append(run_clip(name, f, lab, args.work, args))
        if not args.json:
            print(json.dumps(rows[-1]), file=sys.stderr)
    if args.json:
        print(json.dumps({"clips": rows}, indent=1))
    else:
        print(markdown(rows))


if __name__ == "__main__":
    main()
