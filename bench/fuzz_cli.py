"""Issue 18 CLI fuzzing: schema-valid odd scenarios and odd option values through the commands after extraction.

Part 1 (scenarios): Hypothesis scenarios of tests/scenario_strategies.py (seeded; processed and raw) are written to
a temporary folder, with a small tracks.csv beside them, and run in-process through ``scenario validate``,
``scenario build`` (raw), ``simulate``, ``search`` (a few variants), ``export --format openscenario|commonroad|csv``,
``report`` and ``evaluate fidelity`` (no labels, no video). Part 2 (options): every option of those commands with odd
values (negative, zero, huge, NaN, inf, empty, missing and unwritable paths, the input's own folder, outputs that
exist with and without ``--force``) on one small hand-built scenario (tests/trajectory_cases.py). The property:
exit 0, or exit 2 with exactly one line on stderr; never an internal error (exit 1) or a traceback. Prints one JSON
line: runs per part, exit codes, failures (0 is the goal) with the command line of each.
Part 2 also runs odd values of extract (a 3-frame image folder), evaluate kitti / egomotion, scenario from-kitti,
view and batch options (only those refused before any work, for view and batch).
Usage: python bench/fuzz_cli.py [--examples 40] [--seed 0] [--part scenarios|options|both] [--keep DIR]
       [--replay DIR] [--verbose]   (--keep: write each failing scenario there; --replay: rerun those files)
"""

from __future__ import annotations

import argparse
import contextlib
import io
import json
import os
import shutil
import signal
import stat
import sys
import tempfile
import time
from collections import Counter
from pathlib import Path
from typing import Any

ROOT = Path(__file__).resolve().parents[1]
sys.path[:0] = [str(ROOT / "src"), str(ROOT / "tests")]

from hypothesis import HealthCheck, Phase, given, seed, settings  # noqa: E402

from deepcrashtest.cli import main as cli_main  # noqa: E402
from deepcrashtest.trajectory.pipeline import process_scenario  # noqa: E402
from scenario_strategies import scenario_dicts  # noqa: E402
from trajectory_cases import CLASS_CASES, raw_scenario  # noqa: E402

SEARCH_SMALL = ["--starts", "2", "--noise-variants", "1", "--method", "random", "--boundary-directions", "0"]
SEARCH_SMALL += ["--max-scenarios", "1", "--no-video", "--workers", "1"]
TIME_LIMIT_S = 120  # one command; a run past it is counted as slow, not as a failure


class Slow(BaseException):
    """A command ran past TIME_LIMIT_S (a BaseException, like KeyboardInterrupt: the command line's own handler of
    internal errors catches Exception, and had reported a run starved under a loaded machine as one)."""


def _alarm(_signum: int, _frame: Any) -> None:
    raise Slow


class Fuzz:
    """Runs CLI commands in-process and keeps the tally of exit codes and failures."""

    def __init__(self) -> None:
        self.runs = 0
        self.codes: Counter[int | str] = Counter()
        self.failures: list[dict[str, Any]] = []
        self.accepted: list[list[str]] = []  # the runs that ended with exit 0 (printed with --verbose)

    def run(self, *args: Any) -> tuple[int, str]:
        """Run ``deepcrashtest ARGS``; record a failure unless exit 0, or exit 2 with one line on stderr."""
        argv = [str(a) for a in args]
        out, err = io.StringIO(), io.StringIO()
        self.runs += 1
        signal.signal(signal.SIGALRM, _alarm)
        signal.alarm(TIME_LIMIT_S)
        try:
            with contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):
                rc = cli_main(argv)
        except Slow:
            self.codes["slow"] += 1
            return -1, ""
        except BaseException as exc:  # main() must turn everything into an exit code
            self.failures.append({"argv": argv, "error": f"raised {type(exc).__name__}: {exc}"})
            return 1, ""
        finally:
            signal.alarm(0)
        self.codes[rc] += 1
        if rc == 0:
            self.accepted.append(argv)
        text = err.getvalue()
        lines = [ln for ln in text.splitlines() if ln.strip()]
        bad = "Traceback" in text or "internal error" in text or rc not in (0, 2) or (rc == 2 and len(lines) != 1)
        if bad:
            self.failures.append({"argv": argv, "rc": rc, "stderr": text[-600:]})
        return rc, out.getvalue()


def write_tracks(sc: dict[str, Any], path: Path) -> None:
    """A small tracks.csv for ``sc``: one box per agent per frame of its span (at most 30 frames)."""
    rows = ["frame,time,track_id,category,x1,y1,x2,y2,score,state"]
    fps = float(sc["source"]["fps"])
    for a in sc["agents"]:
        for f in range(a["first_frame"], min(a["last_frame"], a["first_frame"] + 29) + 1):
            rows.append(f"{f},{f / fps:.3f},{a['id']},{a['category']},600,340,680,400,0.9,detected")
    path.write_text("\n".join(rows) + "\n")


def after_extraction(fz: Fuzz, sc: Path, work: Path) -> None:
    """Every command after extraction on the processed scenario file ``sc`` (outputs under ``work``)."""
    rc, out = fz.run("scenario", "validate", sc, "--json")
    if rc != 0:
        return
    rc, out = fz.run("simulate", sc, "--json")
    if rc == 0:
        (sc.parent / "simulation.json").write_text(out)
    fz.run("search", sc, "-o", work / "search", *SEARCH_SMALL, "--json")
    for fmt in ("openscenario", "commonroad", "csv"):
        fz.run("export", sc, "--format", fmt, "-o", work / f"export_{fmt}", "--json")
    results = work / "search" / "results.csv"
    extra = ["--search", results] if results.is_file() else []
    fz.run("report", sc, "-o", work / "report.html", *extra, "--json")
    fz.run("evaluate", "fidelity", sc, "--no-video-out", "-o", work / "fidelity", "--json")


def part_scenarios(fz: Fuzz, examples: int, seed_value: int, tmp: Path, keep: Path | None) -> dict[str, int]:
    """Part 1: Hypothesis scenarios (half processed, half raw) through the commands; the input of each failure
    is written into ``keep`` (when given)."""
    counts = {"processed": 0, "raw": 0}
    cfg = settings(
        max_examples=max(1, examples // 2),
        deadline=None,
        database=None,
        phases=(Phase.generate,),
        suppress_health_check=list(HealthCheck),
    )

    def one(stage: str, data: dict[str, Any]) -> None:
        counts[stage] += 1
        work = tmp / f"{stage}_{counts[stage]:04d}"
        work.mkdir()
        path = work / ("scenario.json" if stage == "processed" else "scenario_raw.json")
        path.write_text(json.dumps(data))
        write_tracks(data, work / "tracks.csv")
        before = len(fz.failures)
        if stage == "raw":
            rc, _ = fz.run("scenario", "build", path, "-o", work / "scenario.json", "--json")
            if rc != 0:
                return
            path = work / "scenario.json"
        after_extraction(fz, path, work)
        if keep is not None and len(fz.failures) > before:  # the input of a failure, to reproduce it
            keep.mkdir(parents=True, exist_ok=True)
            (keep / f"{stage}_{counts[stage]:04d}.json").write_text(json.dumps(data))
        shutil.rmtree(work, ignore_errors=True)

    @seed(seed_value)
    @cfg
    @given(scenario_dicts("processed"))
    def processed(data: dict[str, Any]) -> None:
        one("processed", data)

    @seed(seed_value)
    @cfg
    @given(scenario_dicts("raw"))
    def raw(data: dict[str, Any]) -> None:
        one("raw", data)

    processed()
    raw()
    return counts


# --------------------------------------------------------------------------- part 2: odd option values
FLOATS = ["-1", "0", "1e-12", "1e308", "nan", "inf", "-inf", "", "abc"]
INTS = ["-1", "0", "1000000000000", "", "1.5", "nan"]
OPTIONS: dict[str, dict[str, list[str]]] = {
    "simulate": {"--duration": FLOATS, "--dt": FLOATS, "--seed": INTS, "--controller": ["", "aeb", "nosuch"]},
    "search": {
        "--starts": INTS,
        "--noise-variants": INTS,
        "--box-lateral": FLOATS,
        "--box-longitudinal": FLOATS,
        "--noise-sigma": FLOATS,
        "--workers": INTS,
        "--boundary-directions": INTS,
        "--max-scenarios": INTS,
        "--duration": FLOATS,
        "--seed": INTS,
        "--method": ["", "cem", "both", "nosuch"],
        "--engine": ["", "nosuch"],
        "--controller": ["", "aeb", "nosuch"],
    },
    "build": {"--seed": INTS},
    "fidelity": {"--controller": ["", "aeb", "nosuch"], "--clip": ["", "x"], "--seed": INTS},
}


def part_options(fz: Fuzz, tmp: Path) -> int:
    """Part 2: each option of the commands with odd values, then odd paths; returns the runs made."""
    start = fz.runs
    good = process_scenario(raw_scenario([CLASS_CASES["D0T1"]]))
    d = tmp / "opts"
    d.mkdir()
    sc = good.save(d / "scenario.json")
    raw = raw_scenario([CLASS_CASES["D0T1"]]).save(d / "scenario_raw.json")
    write_tracks(json.loads(sc.read_text()), d / "tracks.csv")
    small = {"search": SEARCH_SMALL + ["--duration", "3"], "simulate": ["--duration", "3"]}
    for cmd, opts in OPTIONS.items():
        for opt, values in opts.items():
            for k, v in enumerate(values):
                out = tmp / f"o_{cmd}_{opt.strip('-')}_{k}"
                base = list(small.get(cmd, []))
                if opt in base:  # the odd value replaces the small default (each of them takes a value)
                    i = base.index(opt)
                    del base[i : i + 2]
                if cmd == "simulate":
                    fz.run("simulate", sc, *base, opt, v, "--json")
                elif cmd == "search":
                    fz.run("search", sc, "-o", out, *base, opt, v, "--json")
                elif cmd == "build":
                    fz.run("scenario", "build", raw, "-o", out / "p.json", opt, v, "--json")
                else:
                    fz.run("evaluate", "fidelity", sc, "--no-video-out", "-o", out, opt, v, "--json")
    odd_paths(fz, d, sc, raw, tmp)
    odd_other_commands(fz, d, tmp)
    return fz.runs - start


def odd_other_commands(fz: Fuzz, d: Path, tmp: Path) -> None:
    """Odd values of the other commands' options (extract on a 3-frame image folder; the KITTI commands on the
    shared data when present, else on a missing folder; view and batch only where refused before any work)."""
    import cv2
    import numpy as np

    frames = tmp / "frames"
    frames.mkdir()
    for k in range(3):
        cv2.imwrite(str(frames / f"{k:06d}.png"), np.full((48, 64, 3), 40 * k, np.uint8))
    fast = ["--no-lanes", "--no-report", "--max-frames", "3", "--fps", "10"]
    extract_opts = {
        "--fps": FLOATS,
        "--detect-every": INTS,
        "--max-frames": INTS,
        "--hfov": FLOATS + ["179.9", "180", "360"],
        "--camera-height": FLOATS,
        "--ego-speed": FLOATS + ["0.5", "1", "60", "400", "401"],
        "--dashboard-rows": INTS + ["48", "47"],
        "--crash": ["", "-1", "x", "1:ego", "2:ego,ego", "1:7,8", "999999999999", "1:", ":", "1e3"],
        "--detector": ["", "nosuch", "/no/such/model.onnx"],
        "--lens": ["", "AUTO", "fisheye", "auto", "none"],
        "--max-width": INTS + ["159", "160"],
    }
    for k, (opt, values) in enumerate(extract_opts.items()):
        for j, v in enumerate(values):
            base = list(fast)
            if opt in base:
                i = base.index(opt)
                del base[i : i + 2]
            fz.run("extract", frames, "-o", tmp / f"x_{k}_{j}", *base, opt, v, "--json")
    odd_frame_sizes(fz, tmp)
    kitti = ROOT.parent / "shared" / "data" / "kitti_tracking"
    data = kitti if kitti.is_dir() else tmp / "no_kitti"
    for v in ("", "-1", "abc", "99999999999999999999", "nan", ",", "3,-8", "9999"):
        fz.run("evaluate", "kitti", "--data", data, "--sequences", v, "--json")
    for v in ("-1", "99999999999999999999", "9999"):
        fz.run("scenario", "from-kitti", "--data", data, "--sequence", v, "-o", tmp / "fk", "--json")
    for opt, v in (
        ("--match", "nosuch"), ("--boxes", "nosuch"), ("--camera", "nosuch"), ("--detections", ""),
        ("--class", "nosuch"), ("--class", ""),
    ):  # fmt: skip
        fz.run("evaluate", "kitti", "--data", data, "--sequences", "9999", opt, v, "--mono", "--json")
    for v in ("pedestrian", "cyclist", "nosuch"):  # the LiDAR tracker's detections are cars
        fz.run("evaluate", "kitti", "--data", data, "--sequences", "12", "--class", v, "--json")
    for v in ("0", "-1", "abc", "99999999999999999999"):
        fz.run("evaluate", "kitti", "--data", data, "--sequences", "9999", "--detect-every", v, "--mono", "--json")
    for v in ("-1", "0", "1", "99999999999999999999"):
        fz.run("evaluate", "egomotion", "--data", tmp / "no_odometry", "--max-frames", v, "--json")
    for v in ("-1", "0", "65536", "99999999999999999999", "", "abc"):
        fz.run("view", d / "scenario.json", "--port", v)
    for opt, values in (
        ("--workers", INTS),
        ("--jobs", INTS),
        ("--starts", INTS),
        ("--duration", FLOATS),
        ("--engine", ["", "x"]),
    ):
        for v in values:
            if (opt, v) not in (("--duration", "1e308"), ("--duration", "1e-12")):  # valid: would run the batch
                fz.run("batch", d, "-o", tmp / "batch", opt, v, "--json")


#: Frame sizes (width, height, px) of the whole extract (geometry, report): tiny, slivers, portraits; 4000 x 8 is
#: processed at 1280 x 2 (--max-width).
ODD_FRAME_SIZES = [(2, 2), (3, 3), (4, 400), (400, 4), (1280, 2), (4000, 8), (2, 600), (9, 16), (2000, 3)]


def odd_frame_sizes(fz: Fuzz, tmp: Path) -> None:
    """``extract`` with every stage on 12 frames of noise at each of ``ODD_FRAME_SIZES``."""
    import cv2
    import numpy as np

    rng = np.random.default_rng(0)
    for w, h in ODD_FRAME_SIZES:
        frames = tmp / f"frames_{w}x{h}"
        frames.mkdir()
        for k in range(12):
            cv2.imwrite(str(frames / f"{k:06d}.png"), rng.integers(0, 255, (h, w, 3), dtype=np.uint8))
        fz.run("extract", frames, "-o", tmp / f"x_{w}x{h}", "--fps", "10", "--json")


def odd_paths(fz: Fuzz, d: Path, sc: Path, raw: Path, tmp: Path) -> None:
    """Empty, missing, unwritable and clashing paths for every command, with and without --force."""
    missing = tmp / "no" / "such" / "file.json"
    unwritable = Path("/proc/deepcrashtest_fuzz")
    for path in ("", str(missing), str(d), "/dev/null"):
        fz.run("scenario", "validate", path)
        fz.run("simulate", path, "--duration", "1")
        fz.run("scenario", "build", path, "-o", tmp / "b.json")
        fz.run("export", path, "--format", "csv", "-o", tmp / "e")
        fz.run("report", path, "-o", tmp / "r.html")
        fz.run("evaluate", "fidelity", path, "--no-video-out", "-o", tmp / "f")
    fifo = tmp / "out.pipe"  # a special file as the output (never /dev/null: a rename onto it replaces the device)
    os.mkfifo(fifo)
    for out in ("", str(unwritable), str(unwritable / "x"), str(fifo), str(d), str(sc), str(tmp / "new" / "deep")):
        for force in ([], ["--force"]):
            fz.run("simulate", sc, "--duration", "1", "--video", out, *force)
            fz.run("search", sc, "-o", out, *SEARCH_SMALL, "--duration", "2", *force)
            fz.run("scenario", "build", raw, "-o", out, *force)
            for fmt in ("openscenario", "commonroad", "csv"):
                fz.run("export", sc, "--format", fmt, "-o", out, *force)
            fz.run("report", sc, "-o", out, *force)
            fz.run("evaluate", "fidelity", sc, "--no-video-out", "-o", out, *force)
            fz.run("schema", "-o", out, *force)
    if not stat.S_ISFIFO(fifo.stat().st_mode):
        fz.failures.append({"argv": ["--force", str(fifo)], "error": "a FIFO given as output was replaced"})
    for fmt in ("", "OpenSCENARIO", "nosuch"):
        fz.run("export", sc, "--format", fmt, "-o", tmp / "e2")
    for opt in ("--video", "--sim", "--search"):
        for value in ("", str(missing), str(d), str(sc), "/dev/null"):
            fz.run("report", sc, "-o", tmp / "r2.html", opt, value, "--force")
    for opt in ("--video", "--tracks", "--labels", "--config"):
        for value in ("", str(missing), str(d), str(sc), "/dev/null"):
            if opt == "--config":
                fz.run("scenario", "build", raw, "-o", tmp / "b2.json", opt, value, "--force")
                fz.run("search", sc, "-o", tmp / "s2", *SEARCH_SMALL, opt, value, "--force")
            else:
                fz.run("evaluate", "fidelity", sc, "--no-video-out", "-o", tmp / "f2", opt, value, "--force")


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--examples", type=int, default=40, help="scenarios (half processed, half raw)")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--part", choices=("scenarios", "options", "both"), default="both")
    ap.add_argument("--keep", type=Path, default=None, help="write the scenario of each failure into this folder")
    ap.add_argument("--replay", type=Path, default=None, help="run the commands on the *.json of this folder only")
    ap.add_argument("--verbose", action="store_true", help="also list the runs that ended with exit 0")
    args = ap.parse_args()
    fz = Fuzz()
    t0 = time.process_time()
    result: dict[str, Any] = {}
    with tempfile.TemporaryDirectory(prefix="fuzz_cli_") as tmp, contextlib.chdir(tmp):  # -o "" is the cwd
        if args.replay is not None:  # the kept inputs of earlier failures
            for k, path in enumerate(sorted(args.replay.glob("*.json"))):
                work = Path(tmp) / f"replay_{k}"
                work.mkdir()
                data = json.loads(path.read_text())
                write_tracks(data, work / "tracks.csv")
                sc = work / "scenario.json"
                sc.write_text(json.dumps(data))
                after_extraction(fz, sc, work)
        elif args.part in ("scenarios", "both"):
            result["scenarios"] = part_scenarios(fz, args.examples, args.seed, Path(tmp), args.keep)
            result["scenario_runs"] = fz.runs
        if args.replay is None and args.part in ("options", "both"):
            result["option_runs"] = part_options(fz, Path(tmp))
    result.update(
        runs=fz.runs,
        exit_codes={str(k): v for k, v in sorted(fz.codes.items(), key=str)},
        internal_errors=len(fz.failures),
        failures=fz.failures[:50],
        cpu_s=round(time.process_time() - t0, 1),
    )
    if args.verbose:
        result["accepted"] = fz.accepted
    print(json.dumps(result))
    if fz.failures:
        raise SystemExit(1)


if __name__ == "__main__":
    main()
