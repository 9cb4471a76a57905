"""``deepcrashtest extract``: one decoding pass over a video -> tracks.csv, annotated.mp4 (, scenario.json).

A fast scan for shot cuts comes first (a compilation gives one extraction per shot, never one scenario
across a cut: :mod:`deepcrashtest.video.shots`).

Stage 1a (this module today): detect + track vehicles, draw them. Later stages hook into the same
pass through ``on_frame`` callbacks and add their outputs after tracking (see the marked place).
"""

from __future__ import annotations

import contextlib
import time
from collections.abc import Callable, Iterable, Iterator
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd

from deepcrashtest.errors import UserError
from deepcrashtest.fileio import atomic_path, check_writable, ensure_output_dir
from deepcrashtest.geometry.camera import default_camera
from deepcrashtest.geometry.extract_geometry import GeometryResult, extract_geometry
from deepcrashtest.perception.annotate import Annotator
from deepcrashtest.perception.crash_detect import GlobalMotion
from deepcrashtest.perception.detect import make_detector
from deepcrashtest.perception.lanes import LaneState, draw_lanes
from deepcrashtest.perception.track import FrameTracks, frame_records, iter_tracks, records_table
from deepcrashtest.pipeline.crash import CrashSpec, crash_for_raw, parse_crash
from deepcrashtest.scenario import Camera, VideoSource
from deepcrashtest.trajectory.pipeline import process_scenario
from deepcrashtest.ui import track as progress
from deepcrashtest.video.shots import Shot
from deepcrashtest.video.source import Frame, VideoMeta, open_video
from deepcrashtest.video.writer import VideoWriter

DEFAULT_DETECTOR = "ssd-mobilenet"
DEFAULT_DETECT_EVERY = 5
#: Shots of a compilation shorter than this (seconds) are not extracted.
MIN_EXTRACT_SHOT_S = 1.0


def run_extract(
    video: str | Path,
    output: str | Path,
    detector: str = DEFAULT_DETECTOR,
    detect_every: int = DEFAULT_DETECT_EVERY,
    max_frames: int | None = None,
    fps: float | None = None,
    force: bool = False,
    annotate: bool = True,
    geometry: bool = True,
    camera: Camera | Callable[[int, int], Camera] | None = None,
    dashboard_rows: int | None = None,
    lanes: bool = True,
    report: bool = True,
    seed: int = 0,
    shots: bool = True,
    frame_range: tuple[int, int] | None = None,
    crash: str | None = None,
) -> dict[str, Any]:
    """Extract a video in ONE decoding pass: detect + track, ego-motion, lanes, localisation.

    Compilations: with ``shots`` the video is first scanned for shot cuts
    (:func:`deepcrashtest.video.shots.detect_shots`); a video of several shots gives one extraction
    per shot in ``output/shot_NN/`` (see :func:`_extract_shots`), never one scenario across a cut.
    ``frame_range`` (first, last video frame, inclusive) restricts the extraction to those frames.

    Writes into ``output``: ``tracks.csv``, ``annotated.mp4`` (boxes, ids, trails, lane lines),
    ``scenario_raw.json`` (world-frame tracks), ``scenario.json`` (after stage 2) and
    ``report.html``. ``camera`` defaults to :func:`deepcrashtest.geometry.camera.default_camera`
    (horizon from the lanes' vanishing point or the flow's focus of expansion); a callable gets the
    video's width and height and returns the Camera. Returns a summary.

    The crash (:mod:`deepcrashtest.pipeline.crash`): detected from image evidence in the same pass,
    or ``crash`` = ``"FRAME[:ID,ID]"`` (the user's, ids as in tracks.csv, ``ego`` allowed); it is the
    raw scenario's ``collision`` and stage 2 makes it happen.
    """
    crash_spec = parse_crash(crash) if crash is not None else None
    if detect_every < 1:
        raise UserError(f"--detect-every must be >= 1 (got {detect_every})")
    if max_frames is not None and max_frames < 1:
        raise UserError(f"--max-frames must be >= 1 (got {max_frames})")
    src_path = Path(video)
    if not src_path.exists():
        raise UserError(f"{src_path}: no such video file or image folder")
    out = Path(output)
    if out.exists() and not out.is_dir():
        raise UserError(f"{out}: exists and is not a directory")
    paths = {
        "tracks_csv": out / "tracks.csv",
        "annotated_mp4": out / "annotated.mp4",
        "scenario_raw": out / "scenario_raw.json",
        "scenario": out / "scenario.json",
        "report": out / "report.html",
    }
    wanted = ["tracks_csv"] + (["annotated_mp4"] if annotate else [])
    wanted += ["scenario_raw", "scenario"] if geometry else []
    wanted += ["report"] if geometry and report else []
    for key in wanted:  # refuse before any work, so nothing already written is lost
        check_writable(paths[key], force)
    if shots and frame_range is None:
        from deepcrashtest.video.shots import detect_shots

        found = detect_shots(src_path, fps, max_frames)
        if len(found) > 1:
            options = dict(detector=detector, detect_every=detect_every, fps=fps, annotate=annotate, geometry=geometry)
            options |= dict(camera=camera, dashboard_rows=dashboard_rows, lanes=lanes, report=report, seed=seed)
            return _extract_shots(src_path, out, found, force, options, crash_spec)
    det = make_detector(detector)
    t0 = time.perf_counter()
    records: list[tuple[object, ...]] = []
    geo: GeometryResult | None = None
    with open_video(src_path, fps) as source, contextlib.ExitStack() as stack:
        meta = source.meta
        ensure_output_dir(out)
        total = min(meta.frame_count, max_frames) if max_frames else meta.frame_count
        if frame_range is not None:
            total = min(total or frame_range[1] + 1, frame_range[1] + 1) - frame_range[0]
        frames = progress(_in_range(source, frame_range), "extract", total=total or None)
        writer = (
            stack.enter_context(VideoWriter(paths["annotated_mp4"], meta.fps, meta.width, meta.height, force=force))
            if annotate
            else None
        )
        drawer = Annotator(meta.fps)
        tracked = iter_tracks(frames, det, detect_every, max_frames, fps=meta.fps)
        if not geometry:
            for ft in tracked:
                records.extend(frame_records(ft))
                if writer is not None:
                    writer.write(drawer.draw(ft))
        else:
            pending: dict[int, FrameTracks] = {}
            motion = GlobalMotion()

            def pairs() -> Iterator[tuple[Any, pd.DataFrame]]:
                for ft in tracked:
                    rows = frame_records(ft)
                    records.extend(rows)
                    pending[ft.frame.index] = ft
                    yield ft.frame, records_table(rows)

            def on_frame(frame: Any, _trk: pd.DataFrame, lane_state: LaneState | None) -> None:
                motion.update(int(frame.index), frame.image)
                ft = pending.pop(int(frame.index))
                if writer is not None:
                    img = drawer.draw(ft)
                    writer.write(draw_lanes(img, lane_state) if lane_state is not None else img)

            if callable(camera):
                cam = camera(meta.width, meta.height)
            else:
                cam = camera or default_camera(meta.width, meta.height)
            geo = extract_geometry(
                pairs(),
                _video_source(meta),
                cam,
                dashboard_rows=dashboard_rows,
                lanes=lanes,
                name=src_path.stem,
                seed=seed,
                on_frame=on_frame,
            )
    elapsed = time.perf_counter() - t0
    if meta.decoded_frames == 0:
        raise UserError(f"{src_path}: no frame could be decoded")
    df = records_table(records).sort_values(["frame", "track_id"], ignore_index=True)
    crash_info: dict[str, Any] | None = None
    if geo is not None:  # before anything is written: a bad --crash id refuses the whole set
        geo.scenario, crash_info = crash_for_raw(geo.scenario, df, motion.arrays(), crash_spec)
    with atomic_path(paths["tracks_csv"], force=force) as tmp:
        df.to_csv(tmp, index=False, float_format="%.3f")

    n_frames = min(meta.decoded_frames, max_frames) if max_frames else meta.decoded_frames
    if frame_range is not None:
        n_frames = min(meta.decoded_frames - frame_range[0], frame_range[1] - frame_range[0] + 1)
        n_frames = min(n_frames, max_frames) if max_frames else n_frames
    lengths = df.groupby("track_id").size() if len(df) else None
    warnings = list(meta.warnings)
    result: dict[str, Any] = {
        "video": str(src_path),
        "output": str(out),
        "tracks_csv": str(paths["tracks_csv"]),
        "annotated_mp4": str(paths["annotated_mp4"]) if annotate else None,
        "detector": getattr(det, "name", detector),
        "detect_every": detect_every,
        "fps_video": round(meta.fps, 3),
        "width": meta.width,
        "height": meta.height,
        "frames": int(n_frames),
        "tracks": int(df["track_id"].nunique()) if len(df) else 0,
        "mean_track_length_frames": round(float(lengths.mean()), 2) if lengths is not None else 0.0,
        "fps_achieved": round(n_frames / elapsed, 2) if elapsed > 0 else None,
        "seconds": round(elapsed, 2),
        "scenario_raw": None,
        "scenario": None,
        "report": None,
        "crash_detection": crash_info,
        "warnings": warnings,
    }
    if geo is not None:
        result.update(_finish_scenario(geo, paths, force, seed, report, warnings))
    return result


def _finish_scenario(
    geo: GeometryResult, paths: dict[str, Path], force: bool, seed: int, report: bool, warnings: list[str]
) -> dict[str, Any]:
    """Save the raw scenario, run stage 2 on it, save the processed one and the report."""
    raw = geo.scenario
    raw.save(paths["scenario_raw"], force=force)
    ego = raw.ego.trajectory.arrays()
    info: dict[str, Any] = {
        "scenario_raw": str(paths["scenario_raw"]),
        "agents": len(raw.agents),
        "ego_distance_m": round(float(np.hypot(np.diff(ego["x"]), np.diff(ego["y"])).sum()), 2),
        "ego_mean_speed_mps": round(float(np.mean(ego["speed"])), 2),
        "camera": {
            "fx": round(geo.camera.fx, 1),
            "pitch_rad": round(geo.camera.pitch_rad, 4),
            "pitch_source": geo.camera.pitch_source,
            "height_m": geo.camera.height_m,
        },
        "dashboard_rows": geo.dashboard_rows,
    }
    warnings.extend(raw.warnings)
    try:
        processed = process_scenario(raw, seed=seed)
    except UserError as exc:  # e.g. no usable track: keep the raw scenario, say why
        warnings.append(f"stage 2 could not process the extracted tracks: {exc}")
        return info
    processed.save(paths["scenario"], force=force)
    info["scenario"] = str(paths["scenario"])
    info["collision"] = processed.collision.model_dump() if processed.collision is not None else None
    info["classes"] = processed.class_counts()
    if report:
        from deepcrashtest.viz.report import build_report

        build_report(paths["scenario"], paths["report"], force=force)
        info["report"] = str(paths["report"])
    return info


def _in_range(frames: Iterable[Frame], frame_range: tuple[int, int] | None) -> Iterator[Frame]:
    """The frames numbered ``frame_range[0] .. frame_range[1]`` (all without a range)."""
    for frame in frames:
        if frame_range is not None and frame.index < frame_range[0]:
            continue
        if frame_range is not None and frame.index > frame_range[1]:
            break
        yield frame


def _extract_shots(
    video: Path, out: Path, shots: list[Shot], force: bool, options: dict[str, Any], crash: CrashSpec | None = None
) -> dict[str, Any]:
    """A compilation: one extraction per shot into ``out/shot_NN/``; shots shorter than
    ``MIN_EXTRACT_SHOT_S`` are skipped with a warning (too short for ego-motion and tracks)."""
    from deepcrashtest.video.shots import cut_times

    cuts = cut_times(shots)
    warnings = [f"{video}: a compilation of {len(shots)} shots (cuts at {cuts} s): one scenario per shot"]
    results: list[dict[str, Any]] = []
    for shot in shots:
        name = f"shot_{shot.index + 1:02d}"
        span = f"frames {shot.first_frame}-{shot.last_frame} ({shot.start_s:.2f}-{shot.end_s:.2f} s)"
        if shot.end_s - shot.start_s < MIN_EXTRACT_SHOT_S:
            warnings.append(f"{name}: {span} is shorter than {MIN_EXTRACT_SHOT_S} s; not extracted")
            continue
        res = run_extract(
            video,
            out / name,
            force=force,
            shots=False,
            frame_range=(shot.first_frame, shot.last_frame),
            crash=crash.text if crash is not None and shot.first_frame <= crash.frame <= shot.last_frame else None,
            **options,
        )
        results.append({"shot": name, "first_frame": shot.first_frame, "last_frame": shot.last_frame, **res})
    return {
        "video": str(video),
        "output": str(out),
        "cuts_s": cuts,
        "shots": results,
        "scenario": None,
        "warnings": warnings + [f"{r['shot']}: {w}" for r in results for w in r.get("warnings", [])],
    }


def _video_source(meta: VideoMeta) -> VideoSource:
    return VideoSource(
        kind=meta.kind,
        path=str(meta.path),
        fps=meta.fps,
        frame_count=meta.frame_count,
        width=meta.width,
        height=meta.height,
        sha256=meta.sha256,
    )


def extract_video(video: str | Path, output: str | Path, seed: int = 0, force: bool = False, **options: Any) -> dict:
    """Library entry point used by ``batch``: :func:`run_extract` with its defaults."""
    return run_extract(video, output, seed=seed, force=force, **options)
