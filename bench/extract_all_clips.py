"""Issue 18: every real clip in ../shared/data through ``deepcrashtest extract`` without an internal error.

Runs the CLI (a subprocess per clip: exit codes as a user meets them) on every video and image-sequence folder
of the shared data; 0 = scenario written, 2 = a clear refusal (one line), anything else = an internal error.
Also checks that each output folder is complete (tracks.csv, annotated.mp4, scenario_raw.json, scenario.json,
report.html) or absent. Prints one JSON line per clip and a summary line. Slow: a benchmark, not a test.
Usage: python bench/extract_all_clips.py [--max-frames N] [--only SUBSTRING] [--keep DIR]
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
DATA = ROOT.parent / "shared" / "data"
FULL_SET = {"tracks.csv", "annotated.mp4", "scenario_raw.json", "scenario.json", "report.html"}


def clips() -> list[tuple[Path, list[str]]]:
    """(input, extra CLI arguments) of every real clip."""
    out: list[tuple[Path, list[str]]] = [(p, []) for p in sorted(DATA.glob("*/*.mp4"))]
    for folder, fps in ((DATA / "kitti_raw_highway_queue" / "image_02" / "data", 10.0),):
        if folder.is_dir():
            out.append((folder, ["--fps", str(fps)]))
    for folder in sorted((DATA / "kitti_odometry").glob("seq*")):
        imgs = folder / "image_0" if (folder / "image_0").is_dir() else folder
        if any(imgs.glob("*.png")):
            out.append((imgs, ["--fps", "10"]))
    return out


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--max-frames", type=int, default=None)
    ap.add_argument("--only", default="", help="run the clips whose path contains this")
    ap.add_argument("--keep", type=Path, default=None, help="write the outputs here instead of a temporary folder")
    args = ap.parse_args()
    if not DATA.exists():
        print(json.dumps({"skipped": f"real data not found: {DATA}"}))
        return
    env_cmd = [sys.executable, "-c", "import sys; from deepcrashtest.cli import main; sys.exit(main())"]
    tally = {"scenario": 0, "clear_error": 0, "internal_error": 0, "incomplete_output": 0}
    with tempfile.TemporaryDirectory() as tmp:
        base = args.keep or Path(tmp)
        for clip, extra in clips():
            if args.only not in str(clip):
                continue
            out = base / clip.relative_to(DATA).as_posix().replace("/", "_")
            cmd = [*env_cmd, "extract", str(clip), "-o", str(out), "--force", "--json", *extra]
            if args.max_frames:
                cmd += ["--max-frames", str(args.max_frames)]
            t0 = time.perf_counter()
            proc = subprocess.run(cmd, capture_output=True, text=True, env={"PYTHONPATH": str(ROOT / "src")}
                                  | dict(__import__("os").environ))  # fmt: skip
            files = sorted(p.name for p in out.iterdir()) if out.exists() else []
            complete = (proc.returncode == 0 and set(files) == FULL_SET) or (proc.returncode != 0 and not files)
            kind = {0: "scenario", 2: "clear_error"}.get(proc.returncode, "internal_error")
            tally[kind] += 1
            tally["incomplete_output"] += 0 if complete else 1
            row = {
                "clip": str(clip.relative_to(DATA)),
                "rc": proc.returncode,
                "seconds": round(time.perf_counter() - t0),
            }
            if proc.returncode == 0:
                r = json.loads(proc.stdout)
                row.update(agents=r.get("agents"), collision=r.get("collision") is not None, warnings=r["warnings"][:3])
            else:
                row["stderr"] = proc.stderr.strip().splitlines()[-1:] if proc.stderr.strip() else []
            row["files"] = files
            print(json.dumps(row), flush=True)
    print(json.dumps({"summary": tally, "max_frames": args.max_frames}))
    if tally["internal_error"] or tally["incomplete_output"]:
        raise SystemExit(1)


if __name__ == "__main__":
    main()
