"""The ``deepcrashtest`` command line: a thin typer layer that parses, calls the library and prints.

Conventions for every command:

* results go to stdout: a short human summary, or with ``--json`` exactly one JSON object;
* progress bars go to stderr (off with ``--quiet`` or when stderr is not a terminal);
* bad input: one line on stderr, exit code 2, no traceback (``--debug`` shows it);
* nothing already written is overwritten without ``--force``.
"""

from __future__ import annotations

import atexit
import contextlib
import json
import os
import sys
import threading
import traceback
from collections.abc import Callable
from pathlib import Path
from typing import Any, NoReturn

import typer
from typer._click import exceptions as click_exc  # typer >= 0.29 vendors its own click

from deepcrashtest import __version__
from deepcrashtest.cli_text import (
    demo_summary,
    extract_summary,
    fidelity_summary,
    kitti_table,
    search_summary,
    sim_summary,
)
from deepcrashtest.errors import UserError
from deepcrashtest.perception.detector_names import DEFAULT_DETECTOR, DETECTOR_HELP  # no NumPy
from deepcrashtest.ui import console_err, set_quiet
from deepcrashtest.video.size import DEFAULT_MAX_WIDTH  # no NumPy

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
SeedOpt = typer.Option(0, "--seed", min=0, help="Seed for every random choice (a non-negative integer).")
ConfigOpt = typer.Option(
    None, "--config", help="YAML file of settings (sections stage2, search) merged over the defaults."
)
DrivingSideOpt = typer.Option(
    None,
    "--driving-side",
    help="right | left: the side traffic keeps to, for the road's oncoming lanes (default right; left for the UK, "
    "Japan, India, Australia, ...). Overrides stage2.driving_side of --config.",
)


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


def _quiet_if_json(as_json: bool) -> None:
    """No progress bar when the output is one JSON object (the bar also hides when stderr is no terminal)."""
    if as_json:
        set_quiet(True)


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
    import numpy as np

    if isinstance(o, np.generic):
        return o.item()
    if isinstance(o, np.ndarray):
        return o.tolist()
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
    from deepcrashtest.datasets.kitti.scenario import scenario_from_kitti as build
    from deepcrashtest.fileio import output_set
    from deepcrashtest.pipeline.kitti import kitti_scenarios

    if sequence < 0:
        raise UserError(f"--sequence must be >= 0 (got {sequence})")
    with output_set(output, ["scenario.json"], force) as stage:
        sc = build(data, sequence) if raw else kitti_scenarios(data, sequence, seed=seed)[1]
        sc.save(stage / "scenario.json")
    emit(
        {
            "scenario": str(output / "scenario.json"),
            "sequence": sequence,
            "stage": sc.stage,
            "agents": len(sc.agents),
            "duration_s": round(sc.duration(), 3),
            "classes": sc.class_counts(),
        },
        as_json,
    )


@scenario_app.command("build")
def scenario_build(
    raw: Path = typer.Argument(..., help="Raw Scenario JSON (stage=raw: world-frame tracks)."),
    output: Path = typer.Option(..., "-o", "--output", help="Processed Scenario JSON to write."),
    config: Path | None = ConfigOpt,
    driving_side: str | None = DrivingSideOpt,
    force: bool = ForceOpt,
    seed: int = SeedOpt,
    as_json: bool = JsonOpt,
) -> None:
    """Stage 2: smooth, classify, extrapolate, step back -> a simulation-ready Scenario."""
    from deepcrashtest.config import load_config
    from deepcrashtest.fileio import check_writable
    from deepcrashtest.pipeline.stage2 import processed_scenario

    params = _with_driving_side(load_config(config).stage2, driving_side)
    sc_raw = _load(raw)
    check_writable(output, force)
    sc = processed_scenario(sc_raw, seed=seed, params=params)
    path = sc.save(output, force=force)
    c = sc.collision
    emit(
        {
            "scenario": str(path),
            "stage": sc.stage,
            "agents": len(sc.agents),
            "duration_s": round(sc.duration(), 3),
            "t_max_s": round(float(sc.provenance.parameters["t_max_s"]), 3),
            "classes": sc.class_counts(),
            "collision": None
            if c is None
            else {"time_s": round(c.time_s, 3), "other_id": c.other_id, "agent_id": c.agent_id, "source": c.source},
            "warnings": sc.warnings,
        },
        as_json,
    )


# --------------------------------------------------------------------------- pipeline stages
@app.command()
def extract(
    video: Path = typer.Argument(
        ..., help="Video file (any FFmpeg reads: mp4, mov, avi, mkv, webm, ts, ...) or image folder."
    ),
    output: Path = typer.Option(..., "-o", "--output", help="Output folder."),
    fps: float | None = typer.Option(None, "--fps", help="Frame rate (required for image folders)."),
    detector: str = typer.Option(DEFAULT_DETECTOR, "--detector", help=DETECTOR_HELP),
    detect_every: int = typer.Option(
        5, "--detect-every", help="Run the detector every N frames (at least every 0.25 s); track between."
    ),
    max_frames: int | None = typer.Option(None, "--max-frames", help="Stop after this many frames."),
    max_width: int = typer.Option(
        DEFAULT_MAX_WIDTH, "--max-width", help="Process frames wider than this (px) scaled down to it; 0: as stored."
    ),
    lens: str = typer.Option(
        "none",
        "--lens",
        help="none: frames as a pinhole camera's; auto: read a wide-angle lens's distortion from "
        "straight edges when no calibration is given.",
    ),
    camera: Path | None = typer.Option(None, "--camera", help="Camera YAML: fx, fy, cx, cy [, height_m, ...]."),
    hfov: float | None = typer.Option(None, "--hfov", help="Horizontal field of view, degrees (no YAML)."),
    chessboard: Path | None = typer.Option(None, "--chessboard", help="Folder of 9x6 chessboard photos."),
    camera_height: float | None = typer.Option(None, "--camera-height", help="Camera height above road, m."),
    ego_speed: float | None = typer.Option(
        None,
        "--ego-speed",
        help="The ego's speed before the crash, km/h, as its GPS overlay or log shows it: sets the scene's metric "
        "scale (an uncalibrated camera's focal length).",
    ),
    overlay: bool = typer.Option(
        True,
        "--overlay/--no-overlay",
        help="Read what the dashcam burns into the picture: its GPS speed ('58KM/H'), used as --ego-speed where no "
        "speed or calibration is given, and its clock, which tells a slow-motion video.",
    ),
    retime: bool = typer.Option(
        True,
        "--retime/--no-retime",
        help="Where the dashcam's clock shows the video is slow motion or sped up (and no --fps is given), extract "
        "it at the frame rate that plays it in real time; --no-retime keeps the file's, with a warning.",
    ),
    dashboard_rows: int | None = typer.Option(
        None, "--dashboard-rows", help="Rows of dashboard/bonnet at the bottom to ignore (default: detect)."
    ),
    lanes: bool = typer.Option(True, "--lanes/--no-lanes", help="Detect and track lane lines."),
    geometry: bool = typer.Option(
        True, "--geometry/--no-geometry", help="Build the scenario (ego-motion, 3D positions, stage 2)."
    ),
    report: bool = typer.Option(True, "--report/--no-report", help="Write report.html."),
    shots: bool = typer.Option(
        True, "--shots/--no-shots", help="Find shot cuts first: a compilation gives one scenario per shot."
    ),
    crash: str | None = typer.Option(
        None,
        "--crash",
        help="The crash, overriding its detection: FRAME[:ID,ID] (0-based frame; track ids as in tracks.csv "
        "and the annotated video, 'ego' allowed; FRAME alone = the likeliest pair there), e.g. 95:ego,7.",
    ),
    config: Path | None = ConfigOpt,
    driving_side: str | None = DrivingSideOpt,
    force: bool = ForceOpt,
    seed: int = SeedOpt,
    as_json: bool = JsonOpt,
) -> None:
    """Stage 1 + 2: detect, track, ego-motion, lanes, 3D positions -> tracks.csv, annotated.mp4, scenario.json."""
    _quiet_if_json(as_json)
    from functools import partial

    from deepcrashtest.fileio import require_file
    from deepcrashtest.geometry.camera import camera_for_video
    from deepcrashtest.pipeline.extract import run_extract
    from deepcrashtest.video.source import check_fps

    if not video.is_dir():
        require_file(video, "video")
    check_fps(fps)
    if dashboard_rows is not None and dashboard_rows < 0:
        raise UserError(f"--dashboard-rows must be >= 0 (got {dashboard_rows})")
    stage2 = _stage2_config(config, driving_side)
    if camera is not None:
        require_file(camera, "camera file")
    if chessboard is not None and not chessboard.is_dir():
        raise UserError(f"{chessboard}: chessboard folder not found")
    if ego_speed is not None and (camera or hfov or chessboard):
        raise UserError(
            "--ego-speed reads an uncalibrated camera's focal length: --camera, --hfov and --chessboard give it"
        )
    # the picture inside black bars (area=) comes from the pass's own first frames
    cam = partial(camera_for_video, yaml_path=camera, hfov_deg=hfov, chessboard=chessboard, height_m=camera_height)
    result = run_extract(
        video,
        output,
        detector=detector,
        detect_every=detect_every,
        max_frames=max_frames,
        fps=fps,
        force=force,
        geometry=geometry,
        camera=cam,
        dashboard_rows=dashboard_rows,
        lanes=lanes,
        report=report,
        seed=seed,
        shots=shots,
        crash=crash,
        stage2=stage2,
        max_width=max_width,
        lens=lens,
        ego_speed_kmh=ego_speed,
        overlay=overlay,
        retime=retime,
    )
    emit(result, as_json, extract_summary)


def _stage2_config(path: Path | None, driving_side: str | None = None) -> Any:
    """Stage 2's settings from ``--config`` and ``--driving-side`` (None without either: the defaults, and no
    import of the search package that ``config`` pulls in: ~0.3 s of extract's start-up)."""
    if path is None and driving_side is None:
        return None
    if path is None:
        from deepcrashtest.trajectory.params import Stage2Params

        return _with_driving_side(Stage2Params(), driving_side)
    from deepcrashtest.config import load_config

    return _with_driving_side(load_config(path).stage2, driving_side)


def _with_driving_side(params: Any, driving_side: str | None) -> Any:
    """``params`` (Stage2Params) with ``--driving-side`` on top when given (refused unless right or left)."""
    if driving_side is None:
        return params
    from dataclasses import replace

    from deepcrashtest.trajectory.params import DRIVING_SIDES

    if driving_side not in DRIVING_SIDES:
        raise UserError(f"--driving-side must be one of {', '.join(DRIVING_SIDES)} (got {driving_side!r})")
    return replace(params, driving_side=driving_side)


@app.command()
def simulate(
    scenario: Path = typer.Argument(..., help="Scenario JSON file."),
    controller: str = typer.Option("replay", "--controller", help="replay | aeb | module:callable | file.py:callable"),
    video: Path | None = typer.Option(None, "--video", help="Write a bird's-eye video (H.264 mp4)."),
    duration: float | None = typer.Option(None, "--duration", help="Seconds to simulate (default: the scenario's)."),
    dt: float = typer.Option(0.02, "--dt", help="Time step, seconds."),
    force: bool = ForceOpt,
    seed: int = SeedOpt,
    as_json: bool = JsonOpt,
) -> None:
    """Replay a Scenario in the built-in simulator and report the outcome."""
    from deepcrashtest.fileio import check_not_input, check_writable
    from deepcrashtest.sim import replay_error
    from deepcrashtest.sim import simulate as run_sim

    sc = _load(scenario)
    if video is not None:
        check_not_input(video, scenario)
        check_writable(video, force)
    res = run_sim(sc, controller=controller, dt=dt, seed=seed, duration=duration)
    out: dict[str, Any] = {
        "scenario": str(scenario),
        "controller": res.controller,
        "seed": seed,
        "dt": res.dt,
        "duration_s": round(float(res.times[-1]), 3),
        "vehicles": len(res.vehicle_ids),
        "metrics": res.metrics,
        "collisions": res.collisions,
        "replay_rms_m": replay_error(sc, res),
    }
    if video is not None:
        from deepcrashtest.viz.birdseye import write_birdseye

        out["video"] = write_birdseye(sc, res, video, force=force)
    emit(out, as_json, sim_summary)


@app.command()
def search(
    scenario: Path = typer.Argument(..., help="Scenario JSON file."),
    output: Path = typer.Option(..., "-o", "--output", help="Output folder."),
    starts: int | None = typer.Option(None, "--starts", help="Random ego start positions in the box [32]."),
    noise_variants: int | None = typer.Option(None, "--noise-variants", help="Noisy ego paths per start [4]."),
    box_lateral: float | None = typer.Option(None, "--box-lateral", help="Start box width, metres (+-half) [4]."),
    box_longitudinal: float | None = typer.Option(
        None, "--box-longitudinal", help="Start box length, metres (+-half) [8]."
    ),
    noise_sigma: float | None = typer.Option(None, "--noise-sigma", help="Std of the control-point noise, m [0.3]."),
    controller: str | None = typer.Option(
        None, "--controller", help="Ego controller: replay | aeb | module:callable [replay]"
    ),
    method: str | None = typer.Option(None, "--method", help="random | cem | both [both]"),
    workers: int | None = typer.Option(None, "--workers", help="Processes (local) or Ray CPUs [default: the cores]."),
    engine: str = typer.Option("local", "--engine", help="local | ray"),
    boundary_directions: int | None = typer.Option(
        None, "--boundary-directions", help="Rays of the boundary scan (0: none) [16]."
    ),
    max_scenarios: int | None = typer.Option(None, "--max-scenarios", help="Safe variants written as files [32]."),
    duration: float | None = typer.Option(None, "--duration", help="Seconds simulated (default: whole scenario)."),
    no_video: bool = typer.Option(False, "--no-video", help="Skip the bird's-eye comparison video."),
    config: Path | None = ConfigOpt,
    force: bool = ForceOpt,
    seed: int = SeedOpt,
    as_json: bool = JsonOpt,
) -> None:
    """Search perturbed ego starts and trajectories for variants that avoid the crash.

    Defaults in brackets come from ``SearchConfig``; a ``--config`` file's ``search:`` section overrides them.
    """
    _quiet_if_json(as_json)
    from deepcrashtest.search.plot import start_helper  # light: the helper forks before the search's imports

    with start_helper() as helper:  # it loads OpenCV on the other core while this process loads the simulator
        from deepcrashtest.config import load_config
        from deepcrashtest.search.run import run_search

        cfg = load_config(config).with_search(
            starts=starts,
            noise_variants=noise_variants,
            box_lateral=box_lateral,
            box_longitudinal=box_longitudinal,
            noise_sigma=noise_sigma,
            controller=controller,
            method=method,
            seed=seed,
            boundary_directions=boundary_directions,
            max_scenarios=max_scenarios,
            video=False if no_video else None,
            duration=duration,
        )
        sc = _load(scenario)
        summary = run_search(sc, output, cfg, engine=engine, workers=_workers(workers), force=force, helper=helper)
    emit(summary, as_json, search_summary)


def _workers(workers: int | None) -> int:
    """``--workers``: the CPU cores this process may use unless given."""
    if workers is None:
        from deepcrashtest.forking import usable_cores

        return usable_cores()
    return workers


@app.command()
def export(
    scenario: Path = typer.Argument(..., help="Scenario JSON file."),
    fmt: str = typer.Option(..., "--format", help="openscenario | commonroad | csv"),
    output: Path = typer.Option(..., "-o", "--output", help="Output folder."),
    ego_free: bool = typer.Option(
        False, "--ego-free", help="OpenSCENARIO: no trajectory for the ego (your system under test drives it)."
    ),
    force: bool = ForceOpt,
    as_json: bool = JsonOpt,
) -> None:
    """Export a Scenario to OpenSCENARIO + OpenDRIVE, CommonRoad or CSV."""
    from deepcrashtest.export import export_scenario

    emit(export_scenario(_load(scenario), fmt, output, ego_free=ego_free, force=force), as_json)


@evaluate_app.command("kitti")
def evaluate_kitti(
    data: Path = typer.Option(..., "--data", help="KITTI tracking folder."),
    sequences: str = typer.Option("3,8,10", "--sequences", help="Comma-separated sequence numbers, or 'all'."),
    detections: str = typer.Option(
        "pointrcnn", "--detections", help="'pointrcnn' (the folder's detections_pointrcnn_Car) or a folder of NNNN.txt."
    ),
    match: str = typer.Option("distance", "--match", help="distance (2 m bird's-eye) | iou3d (0.25) | iou2d (0.5)."),
    tracks: Path | None = typer.Option(
        None, "--tracks", help="Score these KITTI-format tracker results (NNNN.txt) instead of our tracker."
    ),
    online: bool = typer.Option(False, "--online", help="Score the online tracker output, without the offline pass."),
    mono: bool = typer.Option(
        False,
        "--mono",
        help="Score the monocular video path (2D boxes, ego poses, camera) instead of the LiDAR tracker.",
    ),
    boxes: str = typer.Option(
        "pointrcnn", "--boxes", help="With --mono: pointrcnn (its 2D columns only) | labels-noisy (seeded noise)."
    ),
    camera: str = typer.Option(
        "kitti", "--camera", help="With --mono: kitti (calibration file) | unknown (self-calibration)."
    ),
    detect_every: int = typer.Option(
        1,
        "--detect-every",
        help="With --mono: the boxes of every N-th frame only, as extract's detector runs on a video (2 at 10 fps).",
    ),
    object_class: str = typer.Option(
        "car",
        "--class",
        help="car | pedestrian | cyclist (with --tracks or --mono; PointRCNN's are cars: others from noisy labels).",
    ),
    output: Path | None = typer.Option(None, "-o", "--output", help="Also write results.json and results.md here."),
    force: bool = ForceOpt,
    as_json: bool = JsonOpt,
) -> None:
    """CLEAR-MOT of the tracker on KITTI tracking, in world coordinates."""
    _quiet_if_json(as_json)
    from deepcrashtest.eval.kitti import evaluate_kitti as run_eval
    from deepcrashtest.eval.kitti import parse_sequences, results_markdown

    if not data.is_dir():
        raise UserError(f"{data}: KITTI tracking folder not found")
    if tracks is not None and not tracks.is_dir():
        raise UserError(f"{tracks}: tracker results folder not found")
    from deepcrashtest.fileio import output_set
    from deepcrashtest.pipeline.kitti import RESULT_FILES, write_results

    if mono and tracks is not None:
        raise UserError("--mono scores the monocular path: it cannot be combined with --tracks")
    seqs = parse_sequences(sequences)

    def score() -> dict[str, Any]:
        if mono:
            from deepcrashtest.eval.kitti_mono import evaluate_mono

            return evaluate_mono(
                data, seqs, boxes=boxes, camera=camera, match=match, detect_every=detect_every,
                object_class=object_class,
            )  # fmt: skip
        kwargs: dict[str, Any] = {
            "match": match, "detections": detections, "tracks": tracks, "object_class": object_class,
        }  # fmt: skip
        if online:
            kwargs["offline"] = None
        return run_eval(data, seqs, **kwargs)

    if output is None:
        result = score()
    else:
        with output_set(output, RESULT_FILES, force) as stage:  # both files of one run, or none
            result = score()
            write_results(result, stage, results_markdown(result))
    emit(result, as_json, kitti_table)


@evaluate_app.command("egomotion")
def evaluate_egomotion(
    data: Path = typer.Option(..., "--data", help="KITTI odometry frames folder with poses.txt (or a folder of them)."),
    max_frames: int | None = typer.Option(None, "--max-frames", help="Use only the first N frames of each sequence."),
    as_json: bool = JsonOpt,
) -> None:
    """Monocular ego-motion speed error and yaw drift against ground-truth poses."""
    _quiet_if_json(as_json)
    from deepcrashtest.eval.egomotion import evaluate_egomotion as run

    if not data.is_dir():
        raise UserError(f"{data}: odometry folder not found")
    if max_frames is not None and max_frames < 2:
        raise UserError(f"--max-frames must be >= 2 (got {max_frames})")
    emit(run(data, max_frames), as_json)


@evaluate_app.command("fidelity")
def evaluate_fidelity(
    scenario: Path = typer.Argument(..., help="Scenario JSON file (from extract)."),
    video: Path | None = typer.Option(None, "--video", help="Video (default: the source video, else annotated.mp4)."),
    tracks: Path | None = typer.Option(None, "--tracks", help="tracks.csv (default: beside the scenario)."),
    labels: Path | None = typer.Option(None, "--labels", help="Crash labels JSON (bench/labels/*_crashes.json)."),
    clip: str | None = typer.Option(None, "--clip", help="Clip name in the labels (default: the video's name)."),
    controller: str = typer.Option("replay", "--controller", help="Ego controller of the replay."),
    output: Path | None = typer.Option(None, "-o", "--output", help="Output folder (default: beside the scenario)."),
    make_video: bool = typer.Option(True, "--video-out/--no-video-out", help="Write fidelity.mp4."),
    force: bool = ForceOpt,
    seed: int = SeedOpt,
    as_json: bool = JsonOpt,
) -> None:
    """Reprojection and crash fidelity of a scenario and its replay against its video (+ fidelity.mp4)."""
    from deepcrashtest.pipeline.fidelity import run_fidelity

    _, summary = run_fidelity(
        scenario, output, video, tracks, labels, clip, controller, make_video=make_video, force=force, seed=seed
    )
    emit(summary, as_json, fidelity_summary)


@app.command()
def batch(
    videos: Path = typer.Argument(..., help="Folder of videos (and/or Scenario *.json files)."),
    output: Path = typer.Option(..., "-o", "--output", help="Output folder (one subfolder per video)."),
    engine: str = typer.Option("local", "--engine", help="local | ray"),
    workers: int | None = typer.Option(
        None, "--workers", help="Processes (local) or Ray CPUs for each search [default: the cores]."
    ),
    resume: bool = typer.Option(False, "--resume", help="Skip the inputs the manifest marks done."),
    jobs: int | None = typer.Option(
        None,
        "--jobs",
        help="Inputs processed at once, each in its own process [default: the cores, at most 4, and no more than "
        "the free memory holds at 1.5 GB each; 1 with --engine ray].",
    ),
    starts: int | None = typer.Option(None, "--starts", help="Random ego start positions per video [32]."),
    noise_variants: int | None = typer.Option(None, "--noise-variants", help="Noisy ego paths per start [4]."),
    method: str | None = typer.Option(None, "--method", help="random | cem | both [both]"),
    controller: str | None = typer.Option(None, "--controller", help="Ego controller [replay]."),
    duration: float | None = typer.Option(None, "--duration", help="Seconds simulated (default: whole scenario)."),
    config: Path | None = ConfigOpt,
    force: bool = ForceOpt,
    seed: int = SeedOpt,
    as_json: bool = JsonOpt,
) -> None:
    """Run extract -> scenario -> search over a folder of videos (resumable; manifest.json).

    A failed input is recorded and the batch goes on; the exit code is 1 when any input failed.
    """
    _quiet_if_json(as_json)
    from deepcrashtest.config import load_config
    from deepcrashtest.pipeline.batch import default_jobs, run_batch

    cfg = load_config(config).with_search(
        starts=starts,
        noise_variants=noise_variants,
        method=method,
        controller=controller,
        seed=seed,
        video=False,
        duration=duration,
    )
    jobs = (default_jobs() if engine == "local" else 1) if jobs is None else jobs
    result = run_batch(
        videos, output, cfg, engine=engine, workers=_workers(workers), resume=resume, force=force, jobs=jobs
    )
    emit(result, as_json)
    if result.get("failed"):  # the batch went on; the exit code still tells a script that some inputs failed
        sys.stderr.write(f"deepcrashtest: {result['failed']} input(s) failed; see {Path(output) / 'manifest.json'}\n")
        raise typer.Exit(1)


@app.command()
def view(
    scenario: Path = typer.Argument(..., help="Scenario JSON file (its folder is the only one read or written)."),
    port: int = typer.Option(8765, "--port", help="TCP port."),
    host: str = typer.Option("127.0.0.1", "--host", help="Address to bind (loopback by default)."),
) -> None:
    """Open a Scenario in the browser viewer: inspect, edit waypoints, simulate, save as a new file."""
    from deepcrashtest.viz.server import bind, serve

    if not 0 < port < 65536:  # options first, then the input (as every command)
        raise UserError(f"--port must be 1-65535 (got {port})")
    _load(scenario)
    sock = bind(host, port)  # an unresolvable host or a port in use fails here, before the banner
    if host not in ("127.0.0.1", "localhost", "::1"):
        console_err().print(f"warning: binding {host}: anyone who can reach it can read and write {scenario.parent}")
    console_err().print(f"viewer on http://{'[' + host + ']' if ':' in host else host}:{port}/ (Ctrl+C to stop)")
    serve(scenario, host=host, port=port, sock=sock)


@app.command()
def report(
    scenario: Path = typer.Argument(..., help="Scenario JSON file."),
    output: Path = typer.Option(..., "-o", "--output", help="The HTML file to write."),
    video: Path | None = typer.Option(None, "--video", help="Annotated video (default: annotated.mp4 beside)."),
    sim: Path | None = typer.Option(
        None, "--sim", help="Simulation metrics JSON, e.g. `simulate --json` output (default: simulation.json beside)."
    ),
    search_table: Path | None = typer.Option(
        None, "--search", help="Search results CSV with dx, dy, collided, robustness (default: results.csv beside)."
    ),
    force: bool = ForceOpt,
    as_json: bool = JsonOpt,
) -> None:
    """Write one self-contained report.html of a scenario (+ video, simulation, search beside it)."""
    from deepcrashtest.fileio import check_not_input
    from deepcrashtest.viz.report import build_report

    check_not_input(output, scenario, video, sim, search_table)
    emit(build_report(scenario, output, video=video, sim=sim, search=search_table, force=force), as_json)


@app.command()
def demo(
    output: Path = typer.Option(Path("out/demo"), "-o", "--output", help="Output folder."),
    video: Path | None = typer.Option(None, "--video", help="Video to use instead of the bundled sample."),
    as_json: bool = JsonOpt,
) -> None:
    """Run the whole pipeline on the bundled sample clip and write everything to OUTPUT."""
    from deepcrashtest.pipeline.demo import run_demo

    emit(run_demo(output, video), as_json, demo_summary)


# --------------------------------------------------------------------------- entry point
def main(argv: list[str] | None = None) -> int:
    """Console entry point: run the app, turn errors into one line and exit code 2."""
    args = list(sys.argv[1:] if argv is None else argv)
    debug = "--debug" in args
    try:
        rv = app(args=args, prog_name="deepcrashtest", standalone_mode=False)
        if isinstance(rv, int) and not isinstance(rv, bool):  # typer.Exit(n) comes back as a return value
            return rv
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
    except UserError as exc:
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


#: The BLAS libraries' thread-count variables the command sets to one where the environment leaves them unset. Every
#: pass runs its BLAS on one thread already (``threadpoolctl``: its matrices are small, and a multi-threaded OpenBLAS
#: splits reductions by its thread count, so results would differ between machines), but OpenBLAS starts its thread
#: pool when NumPy (and again when SciPy) is imported, and again in each forked worker: ~0.07 s of CPU a process,
#: spinning, a sixth of a 2,000-variant search of a one-agent crash scene (``bench/search_speed.py``).
BLAS_THREAD_VARIABLES = ("OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS")


def run() -> NoReturn:
    """The ``deepcrashtest`` console command: :func:`main`, then leave without Python's interpreter teardown.

    After a command every output file is closed; what is left is freeing the process's objects and modules one
    by one (a search: ~0.15 s of CPU, ~6 % of a 2,000-variant KITTI search on 2 cores). The exit handlers still
    run and the standard streams are flushed; with another thread still running, the usual exit waits for it.
    Before anything loads, the BLAS libraries are told to run on one thread (:data:`BLAS_THREAD_VARIABLES`) unless
    the environment says otherwise.
    """
    for variable in BLAS_THREAD_VARIABLES:  # the command's own setting, not the library's (an importer keeps theirs)
        os.environ.setdefault(variable, "1")
    code = main()
    if threading.active_count() > 1:
        sys.exit(code)
    atexit._run_exitfuncs()  # logging, multiprocessing, ... (what the interpreter's exit runs first)
    for stream in (sys.stdout, sys.stderr):
        with contextlib.suppress(OSError, ValueError):  # a closed pipe: nothing more to say
            stream.flush()
    os._exit(code)


if __name__ == "__main__":  # pragma: no cover
    run()
