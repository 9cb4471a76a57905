"""The ``deepcrashtest`` command line: a thin typer layer that parses, calls the library and prints.

Conventions for every command:

* results go to stdout: a short human summary, or with ``--json`` exactly one JSON object;
* progress bars go to stderr (off with ``--quiet`` or when stderr is not a terminal);
* bad input: one line on stderr, exit code 2, no traceback (``--debug`` shows it);
* nothing already written is overwritten without ``--force``.
"""

from __future__ import annotations

import json
import sys
import traceback
from collections.abc import Callable
from pathlib import Path
from typing import Any

import typer
from typer._click import exceptions as click_exc  # typer >= 0.29 vendors its own click

from deepcrashtest import __version__
from deepcrashtest.errors import NotImplementedYet, UserError
from deepcrashtest.ui import console_err, set_quiet

app = typer.Typer(
    name="deepcrashtest",
    help="Turn a dashcam crash video into a reproducible virtual crash test.",
    add_completion=False,
    no_args_is_help=True,
    pretty_exceptions_enable=False,
)
scenario_app = typer.Typer(help="Create and check Scenario files.", no_args_is_help=True)
evaluate_app = typer.Typer(help="Evaluate tracking and ego-motion against ground truth.", no_args_is_help=True)
app.add_typer(scenario_app, name="scenario")
app.add_typer(evaluate_app, name="evaluate")

_STATE: dict[str, bool] = {"debug": False}

JsonOpt = typer.Option(False, "--json", help="Print one machine-readable JSON object on stdout.")
ForceOpt = typer.Option(False, "--force", help="Overwrite existing outputs.")
SeedOpt = typer.Option(0, "--seed", help="Seed for every random choice.")


def _version(value: bool) -> None:
    if value:
        typer.echo(f"deepcrashtest {__version__}")
        raise typer.Exit()


@app.callback()
def _root(
    version: bool = typer.Option(False, "--version", callback=_version, is_eager=True, help="Print the version."),
    quiet: bool = typer.Option(False, "--quiet", "-q", help="No progress bars."),
    debug: bool = typer.Option(False, "--debug", help="Show tracebacks of errors."),
) -> None:
    _STATE["debug"] = debug
    set_quiet(quiet)


def emit(result: dict[str, Any], as_json: bool, human: Callable[[dict[str, Any]], None] | None = None) -> None:
    """Print a command's result: one JSON object with ``--json``, else a readable summary."""
    if as_json:
        sys.stdout.write(json.dumps(result, default=_json_default, allow_nan=False) + "\n")
        return
    if human is not None:
        human(result)
        return
    for key, value in result.items():
        if isinstance(value, dict | list):
            value = json.dumps(value, default=_json_default)
        typer.echo(f"{key}: {value}")


def _json_default(o: Any) -> Any:
    try:
        import numpy as np

        if isinstance(o, np.generic):
            return o.item()
        if isinstance(o, np.ndarray):
            return o.tolist()
    except ImportError:  # pragma: no cover
        pass
    if isinstance(o, Path):
        return str(o)
    raise TypeError(f"not JSON serialisable: {type(o).__name__}")


def _load(path: Path) -> Any:
    """Load and validate a Scenario file (errors are one-line UserErrors)."""
    from deepcrashtest.scenario import Scenario

    return Scenario.load(path)


# --------------------------------------------------------------------------- scenario files
@app.command()
def schema(
    output: Path | None = typer.Option(None, "-o", "--output", help="Write to this file instead of stdout."),
    force: bool = ForceOpt,
) -> None:
    """Print (or write) the JSON Schema of the Scenario file."""
    from deepcrashtest.fileio import atomic_write_text
    from deepcrashtest.scenario import json_schema

    text = json.dumps(json_schema(), indent=1) + "\n"
    if output is None:
        sys.stdout.write(text)
    else:
        atomic_write_text(output, text, force=force)
        console_err().print(f"wrote {output}")


@scenario_app.command("validate")
def scenario_validate(
    scenario: Path = typer.Argument(..., help="Scenario JSON file."), as_json: bool = JsonOpt
) -> None:
    """Check a Scenario file against the schema and the physical limits."""
    from deepcrashtest.scenario import Scenario

    sc = Scenario.load(scenario)
    emit(
        {
            "valid": True,
            "name": sc.name,
            "schema_version": sc.schema_version,
            "stage": sc.stage,
            "agents": len(sc.agents),
            "duration_s": round(sc.duration(), 3),
        },
        as_json,
    )


@scenario_app.command("from-kitti")
def scenario_from_kitti(
    data: Path = typer.Option(..., "--data", help="KITTI tracking folder (label_02, calib, orbslam3_poses)."),
    sequence: int = typer.Option(..., "--sequence", help="Sequence number, e.g. 8."),
    output: Path = typer.Option(..., "-o", "--output", help="Output folder."),
    raw: bool = typer.Option(False, "--raw", help="Skip stage-2 processing; write world-frame tracks as is."),
    force: bool = ForceOpt,
    seed: int = SeedOpt,
    as_json: bool = JsonOpt,
) -> None:
    """Build a Scenario from KITTI tracking ground truth (labels + poses + calib)."""
    from deepcrashtest.fileio import ensure_output_dir
    from deepcrashtest.trajectory.from_kitti import scenario_from_kitti as build

    if sequence < 0:
        raise UserError(f"--sequence must be >= 0 (got {sequence})")
    sc = build(data, sequence)
    if not raw:
        try:
            from deepcrashtest.trajectory.pipeline import process_scenario
        except ImportError:
            sc.warnings.append("stage-2 processing is not available in this build; scenario is raw")
        else:
            sc = process_scenario(sc, seed=seed)
    out = ensure_output_dir(output)
    path = sc.save(out / "scenario.json", force=force)
    emit(
        {
            "scenario": str(path),
            "sequence": sequence,
            "stage": sc.stage,
            "agents": len(sc.agents),
            "duration_s": round(sc.duration(), 3),
            "classes": _class_counts(sc),
        },
        as_json,
    )


def _class_counts(sc: Any) -> dict[str, int]:
    counts: dict[str, int] = {}
    for a in sc.agents:
        key = a.trajectory_class or "unclassified"
        counts[key] = counts.get(key, 0) + 1
    return dict(sorted(counts.items()))


# --------------------------------------------------------------------------- pipeline stages
@app.command()
def extract(
    video: Path = typer.Argument(..., help="Video file (mp4/mov/avi/mkv) or image folder."),
    output: Path = typer.Option(..., "-o", "--output", help="Output folder."),
    fps: float | None = typer.Option(None, "--fps", help="Frame rate (required for image folders)."),
    detector: str = typer.Option(
        "ssd-mobilenet", "--detector", help="ssd-mobilenet[:tiles=N,score=S,input=WxH] | onnx:PATH (YOLO ONNX)."
    ),
    detect_every: int = typer.Option(5, "--detect-every", help="Run the detector every N frames; track between."),
    max_frames: int | None = typer.Option(None, "--max-frames", help="Stop after this many frames."),
    force: bool = ForceOpt,
    seed: int = SeedOpt,
    as_json: bool = JsonOpt,
) -> None:
    """Stage 1 (+2): detect, track, localise -> tracks.csv, annotated.mp4, scenario.json."""
    from deepcrashtest.extract import run_extract
    from deepcrashtest.fileio import require_file

    if not video.is_dir():
        require_file(video, "video")
    if fps is not None and not fps > 0:
        raise UserError(f"--fps must be a positive number (got {fps})")
    result = run_extract(
        video, output, detector=detector, detect_every=detect_every, max_frames=max_frames, fps=fps, force=force
    )
    emit(result, as_json, _extract_summary)


def _extract_summary(r: dict[str, Any]) -> None:
    typer.echo(
        f"{r['frames']} frames ({r['width']}x{r['height']} @ {r['fps_video']} fps), {r['tracks']} tracks, "
        f"mean track length {r['mean_track_length_frames']} frames, {r['fps_achieved']} fps achieved"
    )
    typer.echo(f"wrote {r['tracks_csv']}" + (f" and {r['annotated_mp4']}" if r["annotated_mp4"] else ""))
    for w in r["warnings"]:
        typer.echo(f"warning: {w}")


@app.command()
def simulate(
    scenario: Path = typer.Argument(..., help="Scenario JSON file."),
    controller: str = typer.Option("replay", "--controller", help="replay | aeb | module:callable"),
    video: Path | None = typer.Option(None, "--video", help="Write a bird's-eye video (H.264 mp4)."),
    force: bool = ForceOpt,
    seed: int = SeedOpt,
    as_json: bool = JsonOpt,
) -> None:
    """Replay a Scenario in the built-in simulator and report the outcome."""
    _load(scenario)
    raise NotImplementedYet("simulate: not implemented yet")


@app.command()
def search(
    scenario: Path = typer.Argument(..., help="Scenario JSON file."),
    output: Path = typer.Option(..., "-o", "--output", help="Output folder."),
    force: bool = ForceOpt,
    seed: int = SeedOpt,
    as_json: bool = JsonOpt,
) -> None:
    """Search perturbed ego starts and trajectories for variants that avoid the crash."""
    _load(scenario)
    raise NotImplementedYet("search: not implemented yet")


@app.command()
def export(
    scenario: Path = typer.Argument(..., help="Scenario JSON file."),
    fmt: str = typer.Option(..., "--format", help="openscenario | commonroad | csv"),
    output: Path = typer.Option(..., "-o", "--output", help="Output folder."),
    force: bool = ForceOpt,
    as_json: bool = JsonOpt,
) -> None:
    """Export a Scenario to OpenSCENARIO + OpenDRIVE, CommonRoad or CSV."""
    _load(scenario)
    raise NotImplementedYet("export: not implemented yet")


@evaluate_app.command("kitti")
def evaluate_kitti(
    data: Path = typer.Option(..., "--data", help="KITTI tracking folder."),
    sequences: str = typer.Option("3,8,10", "--sequences", help="Comma-separated sequence numbers."),
    as_json: bool = JsonOpt,
) -> None:
    """CLEAR-MOT of the tracker on KITTI tracking, in world coordinates."""
    if not data.is_dir():
        raise UserError(f"{data}: KITTI tracking folder not found")
    raise NotImplementedYet("evaluate kitti: not implemented yet")


@evaluate_app.command("egomotion")
def evaluate_egomotion(
    data: Path = typer.Option(..., "--data", help="KITTI odometry frames folder with poses.txt."),
    as_json: bool = JsonOpt,
) -> None:
    """Monocular ego-motion speed error and yaw drift against ground-truth poses."""
    if not data.is_dir():
        raise UserError(f"{data}: odometry folder not found")
    raise NotImplementedYet("evaluate egomotion: not implemented yet")


@app.command()
def batch(
    videos: Path = typer.Argument(..., help="Folder of videos."),
    output: Path = typer.Option(..., "-o", "--output", help="Output folder (one subfolder per video)."),
    as_json: bool = JsonOpt,
) -> None:
    """Run extract -> scenario -> search over a folder of videos."""
    if not videos.is_dir():
        raise UserError(f"{videos}: video folder not found")
    raise NotImplementedYet("batch: not implemented yet")


@app.command()
def demo(
    output: Path = typer.Option(Path("out/demo"), "-o", "--output", help="Output folder."),
    video: Path | None = typer.Option(None, "--video", help="Video to use instead of the bundled sample."),
    as_json: bool = JsonOpt,
) -> None:
    """Run the whole pipeline on the bundled sample clip and write everything to OUTPUT."""
    from deepcrashtest.demo import run_demo

    emit(run_demo(output, video), as_json)


# --------------------------------------------------------------------------- entry point
def main(argv: list[str] | None = None) -> int:
    """Console entry point: run the app, turn errors into one line and exit code 2."""
    args = list(sys.argv[1:] if argv is None else argv)
    debug = "--debug" in args
    try:
        app(args=args, prog_name="deepcrashtest", standalone_mode=False)
    except typer.Exit as exc:
        return int(exc.exit_code or 0)
    except typer.Abort:
        sys.stderr.write("deepcrashtest: aborted\n")
        return 130
    except click_exc.NoArgsIsHelpError as exc:
        sys.stderr.write(exc.format_message() + "\n")
        return 2
    except click_exc.UsageError as exc:
        sys.stderr.write(f"deepcrashtest: error: {exc.format_message()}\n")
        return 2
    except click_exc.ClickException as exc:
        sys.stderr.write(f"deepcrashtest: error: {exc.format_message()}\n")
        return 2
    except (UserError, NotImplementedYet) as exc:
        if debug:
            traceback.print_exc()
        sys.stderr.write(f"deepcrashtest: error: {exc}\n")
        return 2
    except OSError as exc:  # unreadable/unwritable paths are the user's input too
        if debug:
            traceback.print_exc()
        sys.stderr.write(f"deepcrashtest: error: {exc.strerror or exc}: {exc.filename or ''}\n")
        return 2
    except KeyboardInterrupt:
        sys.stderr.write("deepcrashtest: interrupted\n")
        return 130
    except Exception as exc:  # an internal error: still one line unless --debug
        if debug:
            traceback.print_exc()
        sys.stderr.write(f"deepcrashtest: internal error: {type(exc).__name__}: {exc} (rerun with --debug)\n")
        return 1
    return 0


if __name__ == "__main__":  # pragma: no cover
    raise SystemExit(main())
