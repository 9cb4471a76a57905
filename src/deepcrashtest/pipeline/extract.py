"""``deepcrashtest extract``: one decoding pass over a video -> tracks.csv, annotated.mp4 (, scenario.json).

Shot cuts are looked for in the same pass (a compilation gives one extraction per shot, never one
scenario across a cut: :mod:`deepcrashtest.video.shots`); a cut abandons the pass, nothing written, and
each shot is extracted on its own.

Phases of :func:`run_extract`: check the options and outputs, the one decoding pass (:class:`_Pass`,
with the shot watch), tracks.csv, the summary, then stage 2 and the report (:func:`_finish_scenario`).
The pass is pipelined, one thread per stage with bounded queues between: decode | detect | track |
ego-motion (+ lanes in a second thread, :mod:`.geometry_pass`) | draw + H.264 encode. Decoding,
onnxruntime, OpenCV and the encoder release the GIL, so two cores stay busy; results are the same as
a sequential run (each stage sees the frames in order).
"""

from __future__ import annotations

import contextlib
import ctypes
import gc
import importlib
import itertools
import threading
import time
from collections.abc import Callable, Iterable, Iterator
from contextlib import closing
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any, Protocol

import numpy as np

from deepcrashtest.errors import UserError
from deepcrashtest.fileio import atomic_path, check_writable, ensure_output_dir, output_set
from deepcrashtest.geometry.camera import default_camera, portrait_size, scale_camera
from deepcrashtest.geometry.egomotion import MAX_RATE_HZ
from deepcrashtest.geometry.known_speed import KnownSpeed
from deepcrashtest.perception.annotate import Annotator
from deepcrashtest.perception.detect import DEFAULT_DETECTOR, make_detector
from deepcrashtest.perception.detections import Detector, in_picture
from deepcrashtest.perception.global_motion import GlobalMotion  # no pandas: the crash modules load in the background
from deepcrashtest.perception.lanes import LaneState, draw_lanes
from deepcrashtest.perception.overlay import CLOCK_MAX_S, SAMPLE_S, OverlayReader
from deepcrashtest.perception.track import (
    FrameTracks,
    bridged_records,
    detect_ahead,
    frame_records,
    records_table,
    track_detected,
)
from deepcrashtest.pipeline.geometry_pass import GeometryResult, TrackRows, cut_at_crash, extract_geometry
from deepcrashtest.pipeline.threads import Worker, prefetch
from deepcrashtest.scenario import Camera, Scenario, VideoSource
from deepcrashtest.trajectory.params import Stage2Params
from deepcrashtest.ui import status
from deepcrashtest.ui import track as progress
from deepcrashtest.video.bars import SAMPLE_FRAMES, picture_area
from deepcrashtest.video.shots import Shot, ShotWatch
from deepcrashtest.video.size import DEFAULT_MAX_WIDTH, MIN_MAX_WIDTH
from deepcrashtest.video.source import Frame, VideoMeta, open_video
from deepcrashtest.video.writer import VideoWriter
from deepcrashtest.viz.sheet_thumbs import SheetThumbs

if TYPE_CHECKING:  # imported where used: pandas, SciPy and the crash modules load while the first frames decode
    import pandas as pd

    from deepcrashtest.pipeline.crash import CrashSpec

DEFAULT_DETECT_EVERY = 5
#: The detector runs at least this often (s) whatever ``detect_every`` says: at 10 fps (the CCD crash clips)
#: every 5th frame left half a second between detections, and the road user the ego hits went untracked.
MAX_DETECT_GAP_S = 0.25
#: Every file ``extract`` may write into its output folder (one set per run: see fileio.output_set).
OUTPUT_NAMES = ("tracks.csv", "annotated.mp4", "scenario_raw.json", "scenario.json", "report.html")
#: The shot watch's PySceneDetect, first of the background imports: it loads while the main thread opens the
#: detector's session (the pass's first frame waits for both; ~0.1-0.2 s of wall time less before it, load 3-7).
SHOT_IMPORTS = ("scenedetect",)
#: Modules the pass needs only after its first frames (the tracker's first association, the lanes after the
#: calibration buffer, the crash's image motion), then those of the later phases (world tracks and
#: self-calibration, stage 2, the report), imported in the background from the start (:func:`_warm_imports`).
PASS_IMPORTS = ("scipy.optimize", "scipy.sparse.csgraph", "scipy.spatial", "pandas", "deepcrashtest.pipeline.crash")
WARM_IMPORTS = (
    "deepcrashtest.geometry.selfcalib",
    "deepcrashtest.geometry.world_tracks",
    "deepcrashtest.trajectory.pipeline",
)
REPORT_IMPORTS = ("deepcrashtest.viz.report", "matplotlib.figure")


class CameraForVideo(Protocol):
    """The camera of a video from its size (px) and the picture inside its black bars (``(x0, y0, x1, y1)``
    px from the pass's first frames, :func:`deepcrashtest.video.bars.picture_area`; None without frames),
    e.g. ``functools.partial(geometry.camera.camera_for_video, hfov_deg=...)``."""

    def __call__(self, width: int, height: int, *, area: tuple[int, int, int, int] | None) -> Camera: ...


#: Shots of a compilation shorter than this (seconds) are not extracted.
MIN_EXTRACT_SHOT_S = 1.0


#: ``extract --ego-speed`` at most (km/h).
MAX_EGO_SPEED_KMH = 400.0
#: ``extract --lens``: ``none`` (frames as a pinhole camera's) or ``auto`` (the lens read from straight edges).
LENS_MODES = ("none", "auto")


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
    camera: Camera | CameraForVideo | None = None,
    dashboard_rows: int | None = None,
    lanes: bool = True,
    report: bool = True,
    seed: int = 0,
    shots: bool = True,
    frame_range: tuple[int, int] | None = None,
    crash: str | None = None,
    stage2: Stage2Params | None = None,
    max_width: int | None = DEFAULT_MAX_WIDTH,
    lens: str = "none",
    ego_speed_kmh: float | None = None,
    overlay: bool = True,
    retime: bool = True,
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
    video's width and height and, as ``area``, the picture inside black bars (:class:`CameraForVideo`)
    and returns the Camera. Returns a summary.

    The crash (:mod:`deepcrashtest.pipeline.crash`): detected from image evidence in the same pass,
    or ``crash`` = ``"FRAME[:ID,ID]"`` (the user's, ids as in tracks.csv, ``ego`` allowed); it is the
    raw scenario's ``collision`` and stage 2 makes it happen.

    ``max_width`` (px; None or 0: none): frames wider than this are processed scaled down to it
    (:data:`DEFAULT_MAX_WIDTH`); ``tracks.csv``, ``annotated.mp4`` and the scenario's camera and source size are then
    in the scaled frames' pixels, and the scenario's provenance says the file's size (``frames_scaled_from``). A
    ``camera`` and ``dashboard_rows`` are in the file's pixels (scaled along).

    ``lens``: ``"auto"`` reads a wide-angle lens's radial distortion from the video's straight edges when no
    calibration is given (:mod:`deepcrashtest.geometry.lens`); ``"none"`` (default) takes the frames as a pinhole
    camera's. A given camera's distortion is always used.

    ``ego_speed_kmh``: the ego's speed before the crash as its GPS overlay or log shows it (km/h, about constant over
    the clip): an uncalibrated camera's focal length is read from it (the image ego-motion's median speed scales with
    it, and so does every road user's distance), so the scenario takes the video's metric scale. A camera with its
    own intrinsics keeps them (the speed is not used; the CLI refuses the two together).

    ``overlay``: read what the dashcam burns into the picture (:mod:`deepcrashtest.perception.overlay`; a text reader
    must be installed): its GPS speed, used as a given speed where neither a speed nor a calibration is given, and its
    clock, which tells a slow-motion or sped-up video.

    ``retime``: where that clock clearly disagrees with the file's frame rate and no ``fps`` is given, the video is
    extracted again at the rate that plays it in real time (:meth:`~deepcrashtest.perception.overlay.OverlayClock.\
real_time_fps`; the DAD clips' 20 fps files hold 25 fps footage): the scenario's times, speeds and crash follow the
    clock, and its provenance (``time_base``) and warnings say so. ``False``: the file's rate, with a warning.
    """
    crash_spec = _parse_crash(crash) if crash is not None else None
    max_width = max_width or None  # 0: the frames as stored
    _check_options(detect_every, max_frames, max_width, lens, ego_speed_kmh)
    ego_speed = None if ego_speed_kmh is None else ego_speed_kmh / 3.6
    src_path, out = Path(video), Path(output)
    paths = _output_paths(src_path, out, annotate, geometry, report, force)
    watch = shots and frame_range is None  # cuts are looked for in the same decoding pass
    later = WARM_IMPORTS + REPORT_IMPORTS * report if geometry else ()

    loaded: dict[str, Any] = {}  # the detector and the text reader, loaded once for a pass again

    def one_pass(fps: float | None, time_base: ClockTimeBase | None) -> dict[str, Any]:
        with _one_blas_thread() as pin_blas:
            imports = _warm_imports(SHOT_IMPORTS * watch + PASS_IMPORTS + later, then=pin_blas)
            if "detector" not in loaded:
                loaded["detector"] = make_detector(detector)
            det = loaded["detector"]
            with output_set(out, OUTPUT_NAMES, force) as stage:  # the whole set of one run, or nothing
                staged = {key: stage / path.name for key, path in paths.items()}
                args = (src_path, out, staged, det, detect_every, max_frames, fps, False, frame_range, seed, watch)
                plan = _Pass(*args, max_width=max_width, lens=lens, ego_speed=ego_speed, overlay=overlay)
                plan.imports, plan.time_base, plan.loaded = imports, time_base, loaded
                plan.retime = retime and fps is None  # a pass again runs at the clock's fps
                result = _run_pass(plan, camera, dashboard_rows, geometry, lanes, report, crash_spec, stage2)
        return _final_paths(result, stage, out)

    try:
        try:
            return one_pass(fps, None)
        except _Retime as retimed:  # nothing was written
            time_base = retimed.time_base
        _release_memory()  # the first pass's frames and tables, outside the handler that held them
        return one_pass(time_base.fps, time_base)  # again at the clock's frame rate
    except _Compilation as comp:  # nothing was written: one extraction per shot instead
        from deepcrashtest.video.shots import detect_shots

        found = comp.shots or detect_shots(src_path, fps, max_frames)
        options: dict[str, Any] = dict(detector=detector, detect_every=detect_every, fps=fps, annotate=annotate)
        options |= dict(camera=camera, dashboard_rows=dashboard_rows, lanes=lanes, report=report, seed=seed)
        options |= dict(stage2=stage2, geometry=geometry, max_width=max_width, lens=lens, ego_speed_kmh=ego_speed_kmh)
        options |= dict(overlay=overlay, retime=retime)
        if len(found) > 1:
            return _extract_shots(src_path, out, found, force, options, crash_spec)
        return run_extract(src_path, out, force=force, shots=False, crash=crash, max_frames=max_frames, **options)


@dataclass(frozen=True)
class ClockTimeBase:
    """The frame rate ``fps`` (1/s) the picture's clock gives a video stored at ``file_fps``; ``rate``: the clock
    seconds per second of the file's video and its 95 % interval; ``sample``: the clock as read."""

    fps: float
    file_fps: float
    rate: tuple[float, float, float]
    sample: str

    @property
    def time_scale(self) -> float:
        """Frames a second of the clock's time base per frame a second of the file's (> 1: a slow-motion file)."""
        return self.fps / self.file_fps

    def record(self) -> dict[str, Any]:
        """The scenario provenance's ``time_base``."""
        lo, hi = self.rate[1:]
        record: dict[str, Any] = {"fps": round(self.fps, 3), "file_fps": round(self.file_fps, 3)}
        record |= {"source": "overlay clock", "clock_rate_at_file_fps": round(self.rate[0], 4)}
        return record | {"interval_95": [round(lo, 4), round(hi, 4)]}

    def warning(self) -> str:
        kind = "slow motion" if self.rate[0] < 1.0 else "sped up"
        return (
            f"the picture's clock ({self.sample!r}) runs {self.rate[0]:.2f} s per second of the file's video "
            f"({self.rate[1]:.2f}-{self.rate[2]:.2f}, 95 %: {kind}): extracted at {self.fps:.4g} fps, the clock's "
            f"real time, not the file's {self.file_fps:g} fps (--fps {self.file_fps:g} or --no-retime keeps the file's)"
        )


def _release_memory() -> None:
    """Collect the garbage of a pass and hand the C heap's free pages back to the system (glibc's ``malloc_trim``;
    elsewhere nothing more): a pass again otherwise grows on top of the first one's freed but resident memory
    (dad_000478 re-timed: peak RSS 924 -> 781 MB)."""
    gc.collect()
    try:
        ctypes.CDLL("libc.so.6").malloc_trim(0)
    except (OSError, AttributeError):  # not glibc
        pass


class _Retime(Exception):
    """The picture's clock says the video is not real time: extract again at ``time_base.fps``."""

    def __init__(self, time_base: ClockTimeBase) -> None:
        super().__init__("time base")
        self.time_base = time_base


class _Compilation(Exception):
    """The decoding pass met a shot cut: the video is a compilation (``shots``: all of them when known)."""

    def __init__(self, shots: list[Shot]) -> None:
        super().__init__("shot cut")
        self.shots = shots


def _final_paths(value: Any, stage: Path, out: Path) -> Any:
    """The summary with every path inside the staging folder named by its final place in ``out``."""
    if isinstance(value, dict):
        return {k: _final_paths(v, stage, out) for k, v in value.items()}
    if isinstance(value, str) and value.startswith(str(stage)):
        return str(out) + value[len(str(stage)) :]
    return value


def _run_pass(
    plan: _Pass,
    camera: Camera | CameraForVideo | None,
    dashboard_rows: int | None,
    geometry: bool,
    lanes: bool,
    report: bool,
    crash_spec: CrashSpec | None,
    stage2: Stage2Params | None = None,
) -> dict[str, Any]:
    """The decoding pass, the tracks table, the crash and stage 2, all written to ``plan.paths``."""
    src_path = plan.src_path
    t0 = time.perf_counter()
    with _few_gc_passes(), _opencv_threads(1):
        records, geo, meta = plan.run(camera, dashboard_rows, geometry, lanes)
    elapsed = time.perf_counter() - t0
    if meta.decoded_frames == 0:
        raise UserError(f"{src_path}: no frame could be decoded")
    if plan.shot_watch is not None and len(shots := plan.shot_watch.shots()) > 1:
        raise _Compilation(shots)
    if geo is not None and plan.retime and (time_base := _clock_time_base(plan.overlay_reader, meta.fps)) is not None:
        raise _Retime(time_base)
    if geo is not None and meta.scaled_from is not None:  # the file's size beside the frames' (the source's)
        params = {**geo.scenario.provenance.parameters, "frames_scaled_from": list(meta.scaled_from)}
        geo.scenario = geo.scenario.evolve(provenance=geo.scenario.provenance.model_copy(update={"parameters": params}))
    with status("building the scenario: crash, stage 2, report" if geo is not None else "writing the tracks"):
        return _after_pass(plan, records, geo, meta, elapsed, dashboard_rows, report, crash_spec, stage2)


def _after_pass(
    plan: _Pass,
    records: list[tuple[object, ...]],
    geo: GeometryResult | None,
    meta: VideoMeta,
    elapsed: float,
    dashboard_rows: int | None,
    report: bool,
    crash_spec: CrashSpec | None,
    stage2: Stage2Params | None,
) -> dict[str, Any]:
    """:func:`_run_pass` after the decoding pass: the tracks table, the crash, stage 2 and the report."""
    paths, force, seed = plan.paths, plan.force, plan.seed
    df = records_table(records).sort_values(["frame", "track_id"], ignore_index=True)
    crash_info: dict[str, Any] | None = None
    if geo is not None:  # before anything is written: a bad --crash id refuses the whole set
        from deepcrashtest.pipeline.crash import crash_for_raw, weak_pair_note

        motion = plan.motion
        geo.scenario, crash_info = crash_for_raw(geo.scenario, df, motion.arrays(), crash_spec, motion.area)
        geo = _cut_at_crash(geo, crash_info)
        geo.scenario = _with_overlay_clock(geo.scenario, plan.overlay_reader, meta.fps, plan.time_base)
    with atomic_path(paths["tracks_csv"], force=force) as tmp:
        df.to_csv(tmp, index=False, float_format="%.3f")
    result = _summary(plan, meta, df, elapsed)
    result["crash_detection"] = crash_info
    if geo is not None:
        result["warnings"] += weak_pair_note(crash_info) + _dashboard_note(dashboard_rows, geo.dashboard_rows, meta)
        result.update(_finish_scenario(geo, paths, force, seed, report, result["warnings"], stage2, plan.kept))
    return result


def _cut_at_crash(geo: GeometryResult, crash_info: dict[str, Any]) -> GeometryResult:
    """``geo`` with the ego speeds before the crash found (if any) smoothed from readings before it only
    (:func:`~deepcrashtest.pipeline.geometry_pass.cut_at_crash`), the crash kept as it was found."""
    if not crash_info.get("found") or geo.scenario.collision is None:
        return geo
    cut = cut_at_crash(geo, float(crash_info["video_time_s"]))
    if cut is geo:
        return geo
    params = {**geo.scenario.provenance.parameters, **cut.scenario.provenance.parameters}
    prov = cut.scenario.provenance.model_copy(update={"parameters": params})
    cut.scenario = cut.scenario.evolve(collision=geo.scenario.collision, provenance=prov)
    return cut


def _parse_crash(text: str) -> CrashSpec:
    from deepcrashtest.pipeline.crash import parse_crash

    return parse_crash(text)


def _warm_imports(modules: tuple[str, ...], then: Callable[[], None] | None = None) -> threading.Thread:
    """Import what the later phases need in a background thread while the frames flow.

    The frame loop spends most of its time in OpenCV / onnxruntime / PyAV with the GIL released, so the
    ~2 s of CPU these imports cost (SciPy, pandas, filterpy's scipy.stats, matplotlib) overlap it, and the
    pass starts with the few modules its first frames need. Python's import lock makes a phase that gets
    there first wait for the module instead of importing it twice. The modules come in the order the pass
    needs them (a thread that imports one lazily waits for this one's lock holding none itself); the pass
    joins the returned thread after its last frame, before the later phases import anything. ``then`` runs
    after the last import (:func:`_one_blas_thread`'s ``pin``).
    """

    def load() -> None:
        for name in modules:
            with contextlib.suppress(ImportError):
                importlib.import_module(name)
        if then is not None:
            then()

    thread = threading.Thread(target=load, name="imports", daemon=True)
    thread.start()
    return thread


@contextlib.contextmanager
def _one_blas_thread() -> Iterator[Callable[[], None]]:
    """Every BLAS library of the process on one thread for the run, then restored; yields ``pin``, which puts
    those loaded since (SciPy's own OpenBLAS, loaded by the background imports) on one thread too.

    Determinism: a multi-threaded OpenBLAS splits some reductions by its thread count (OPENBLAS_NUM_THREADS,
    else the machine's cores), so the same clip gave another scenario on another machine: SciPy's SLSQP
    (stage 2's crash correction) found another optimum of the phone-filmed ccd_000053 with 1 thread than with
    2. NumPy and SciPy each bundle their own OpenBLAS; SciPy's loads during the pass (the background imports
    pin it once loaded; the pass joins them before the later phases, the first to use SciPy's BLAS), or is
    loaded already by an earlier import (pinned at entry). Speed: OpenBLAS's threads mostly spin and wait
    for each other on the small matrices (a few to a few hundred rows) of the pass and stage 2.
    """
    from threadpoolctl import threadpool_limits

    lock = threading.Lock()
    limits: list[Any] = []
    done = False

    def pin() -> None:
        with lock:
            if not done:  # an import thread that outlived a failed run leaves the libraries alone
                limits.append(threadpool_limits(limits=1, user_api="blas"))

    pin()
    try:
        yield pin
    finally:
        with lock:
            done = True
            for limit in reversed(limits):
                limit.restore_original_limits()


@contextlib.contextmanager
def _few_gc_passes() -> Iterator[None]:
    """Fewer cyclic-GC passes during the frame loop, none over the imported modules' objects.

    Profiled: the collector took ~9 % of the main thread's time, walking the long-lived objects of the
    imports on every full pass; the loop makes few reference cycles.
    """
    gc.freeze()
    threshold = gc.get_threshold()
    gc.set_threshold(max(threshold[0], 10_000), threshold[1], threshold[2])
    try:
        yield
    finally:
        gc.set_threshold(*threshold)
        gc.unfreeze()


@contextlib.contextmanager
def _opencv_threads(n: int) -> Iterator[None]:
    """OpenCV's own thread pool set to ``n`` threads for the pass, then restored.

    The pass already runs a thread per stage; OpenCV splitting each small call (LK flow, resizes)
    over the cores as well cost ~6 % more process CPU on 2 cores, with the same results.
    """
    import cv2

    before = cv2.getNumThreads()
    cv2.setNumThreads(n)
    try:
        yield
    finally:
        cv2.setNumThreads(before)


def _check_options(
    detect_every: int,
    max_frames: int | None,
    max_width: int | None = None,
    lens: str = "none",
    ego_speed_kmh: float | None = None,
) -> None:
    if detect_every < 1:
        raise UserError(f"--detect-every must be >= 1 (got {detect_every})")
    if max_frames is not None and max_frames < 1:
        raise UserError(f"--max-frames must be >= 1 (got {max_frames})")
    if max_width is not None and max_width < MIN_MAX_WIDTH:
        raise UserError(f"--max-width must be at least {MIN_MAX_WIDTH} px, or 0 for full resolution (got {max_width})")
    if lens not in LENS_MODES:
        raise UserError(f"--lens must be one of {', '.join(LENS_MODES)} (got {lens!r})")
    if ego_speed_kmh is not None and not 1.0 <= ego_speed_kmh <= MAX_EGO_SPEED_KMH:
        raise UserError(f"--ego-speed must be 1-{MAX_EGO_SPEED_KMH:g} km/h, the ego moving (got {ego_speed_kmh:g})")


def _output_paths(
    src_path: Path, out: Path, annotate: bool, geometry: bool, report: bool, force: bool
) -> dict[str, Path]:
    """The files this run writes, by key; refuses before any work, so nothing already written is lost."""
    if not src_path.exists():
        raise UserError(f"{src_path}: no such video file or image folder")
    if out.exists() and not out.is_dir():
        raise UserError(f"{out}: exists and is not a directory")
    paths: dict[str, Path | None] = {
        "tracks_csv": out / "tracks.csv",
        "annotated_mp4": out / "annotated.mp4" if annotate else None,
        "scenario_raw": out / "scenario_raw.json" if geometry else None,
        "scenario": out / "scenario.json" if geometry else None,
        "report": out / "report.html" if geometry and report else None,
    }
    wanted = {key: path for key, path in paths.items() if path is not None}
    for path in wanted.values():
        check_writable(path, force)
    return wanted


@dataclass
class _Pass:
    """The one decoding pass, pipelined: decode | detect | track (flow, association) | geometry (ego-motion,
    lanes) | draw + encode, each in its own thread with bounded queues between
    (:mod:`deepcrashtest.pipeline.threads`)."""

    src_path: Path
    out: Path
    paths: dict[str, Path]
    det: Detector
    detect_every: int
    max_frames: int | None
    fps: float | None
    force: bool
    frame_range: tuple[int, int] | None
    seed: int
    watch_shots: bool = False
    """Look for shot cuts in this pass (:class:`~deepcrashtest.video.shots.ShotWatch`); a cut raises
    :class:`_Compilation` (at the first cut found, or after the last frame)."""
    max_width: int | None = DEFAULT_MAX_WIDTH
    """Frames wider than this (px) are processed scaled down to it (:func:`~deepcrashtest.video.source.open_video`)."""
    lens: str = "none"
    """``"auto"``: the lens's distortion read from the video when no calibration is given (:func:`run_extract`)."""
    ego_speed: float | None = None
    """The ego's speed the user knows (m/s), for an uncalibrated camera's focal length (:func:`run_extract`)."""
    overlay: bool = True
    """Read the dashcam's overlay: its speed where no speed and no calibration are given, and its clock
    (:func:`run_extract`)."""
    overlay_reader: OverlayReader | None = field(default=None, init=False)
    retime: bool = field(default=False, init=False)
    """Raise :class:`_Retime` where the picture's clock says the video is not real time: as soon as the clock is read
    (:data:`~deepcrashtest.perception.overlay.CLOCK_MAX_S` into the video), or after the last frame of a shorter one."""
    time_base: ClockTimeBase | None = field(default=None, init=False)
    """The frame rate this pass runs at was read off the picture's clock by a pass before it."""
    loaded: dict[str, Any] = field(default_factory=dict, init=False)
    """Models shared with a pass again (``text_reader``)."""
    motion: GlobalMotion = field(default_factory=GlobalMotion)
    """The camera's global image motion per frame (the ego's jolt, for crash detection)."""
    shot_watch: ShotWatch | None = field(default=None, init=False)
    imports: threading.Thread | None = field(default=None, init=False)
    """The background imports (:func:`_warm_imports`), joined after the last frame."""
    kept: SheetThumbs | None = field(default=None, init=False)
    """Thumbnails of the annotated frames for the report's contact sheet (when a report is written)."""

    def run(
        self,
        camera: Camera | CameraForVideo | None,
        dashboard_rows: int | None,
        geometry: bool,
        lanes: bool,
    ) -> tuple[list[tuple[object, ...]], GeometryResult | None, VideoMeta]:
        """Decode, track, (geometry,) draw; returns the track records, the geometry result and the metadata."""
        records: list[tuple[object, ...]] = []
        with open_video(self.src_path, self.fps, self.max_width) as source, contextlib.ExitStack() as stack:
            meta = source.meta
            _check_dashboard_rows(dashboard_rows, meta)
            dashboard_rows = None if dashboard_rows is None else round(dashboard_rows * meta.scale)  # the frames' rows
            ensure_output_dir(self.paths["tracks_csv"].parent)
            frames = _in_range(source, self.frame_range)
            if self.watch_shots:
                frames = _watched(frames, self._shot_watch(meta), self.max_frames)
            frames = stack.enter_context(closing(prefetch(frames, 8, "decode")))
            # the picture inside black bars (the detector's input, the camera, the jolt) from the pass's own first
            # frames: no second opening and decoding of the video before the pass
            head = list(itertools.islice(frames, SAMPLE_FRAMES))
            self.motion.area = picture_area([f.image for f in head]) if head else None
            frames = itertools.chain(head, frames)
            every = max(1, min(self.detect_every, int(meta.fps * MAX_DETECT_GAP_S + 1e-6)))
            det = in_picture(self.det, self.motion.area, meta.width, meta.height)  # the bars are no scene
            detected = detect_ahead(itertools.islice(frames, self.max_frames), det, every)
            detected = stack.enter_context(closing(prefetch(detected, 8, "detect")))
            tracked_boxes = track_detected(detected, meta.fps, every, picture=self.motion.area)
            tracking = stack.enter_context(closing(prefetch(tracked_boxes, 8, "track")))
            tracked = progress(tracking, "extract", total=self._total(meta))
            draw = self._drawing(meta, stack)
            if not geometry:
                for ft in tracked:
                    records.extend(frame_records(ft))
                    draw(ft, None)
                self._imported()
                return records, None, meta
            cam = _camera_for_frames(camera, meta, self.motion.area)
            return records, self._geometry(tracked, records, meta, cam, dashboard_rows, lanes, draw), meta

    def _imported(self) -> None:
        if self.imports is not None:
            self.imports.join()

    def _shot_watch(self, meta: VideoMeta) -> ShotWatch:
        self.shot_watch = ShotWatch(meta.fps)
        return self.shot_watch

    def _total(self, meta: VideoMeta) -> int | None:
        total = min(meta.frame_count, self.max_frames) if self.max_frames else meta.frame_count
        if self.frame_range is not None:
            total = min(total or self.frame_range[1] + 1, self.frame_range[1] + 1) - self.frame_range[0]
        return total or None

    def _drawing(self, meta: VideoMeta, stack: contextlib.ExitStack) -> Callable[[FrameTracks, LaneState | None], None]:
        """``draw(frame_tracks, lane_state)``: annotate and encode in a background thread (or nothing)."""
        path = self.paths.get("annotated_mp4")
        if path is None:
            return lambda _ft, _lanes: None
        writer = stack.enter_context(VideoWriter(path, meta.fps, meta.width, meta.height, force=self.force))
        drawer = Annotator(meta.fps)
        if "report" in self.paths:  # the report's contact sheet from these frames, not from decoding the video
            w, h = writer.width + writer.width % 2, writer.height + writer.height % 2  # as encoded
            self.kept = SheetThumbs(meta.fps, w, h, expected=self._total(meta))

        def encode(item: tuple[FrameTracks, LaneState | None]) -> None:
            img = drawer.draw(item[0])
            img = draw_lanes(img, item[1], copy=False) if item[1] is not None else img  # the drawer's own copy
            writer.write(img)
            if self.kept is not None:
                self.kept.add(img)

        worker: Worker[tuple[FrameTracks, LaneState | None]] = Worker(encode, 8, "encode")
        stack.callback(worker.close)  # drains before the writer closes (LIFO)
        return lambda ft, lanes: worker.submit((ft, lanes))

    def _geometry(
        self,
        tracked: Iterable[FrameTracks],
        records: list[tuple[object, ...]],
        meta: VideoMeta,
        cam: Camera,
        dashboard_rows: int | None,
        lanes: bool,
        draw: Callable[[FrameTracks, LaneState | None], None],
    ) -> GeometryResult:
        """Ego-motion, lanes and localisation over the tracked frames (:mod:`.geometry_pass`)."""
        pending: dict[int, FrameTracks] = {}
        overlay = self.overlay_reader = self._overlay_reader()
        use_speed = self.ego_speed is None and cam.intrinsics_source == "default"

        def pairs() -> Iterator[tuple[Any, TrackRows]]:
            for ft in tracked:
                rows = frame_records(ft, bridged=False)  # bridged boxes of earlier frames mask nothing here
                records.extend(rows + bridged_records(ft))
                pending[ft.frame.index] = ft
                yield ft.frame, rows
            self._imported()  # before the geometry's last steps import the self-calibration and world tracks

        def on_frame(frame: Any, _trk: TrackRows, lane_state: LaneState | None) -> None:
            self.motion.update(int(frame.index), frame.image)
            if overlay is not None and overlay.wants(float(frame.time)):
                overlay.offer(int(frame.index), float(frame.time), frame.image)
            elif overlay is not None:
                overlay.see(int(frame.index), float(frame.time), frame.image)
            draw(pending.pop(int(frame.index)), lane_state)
            if self.retime and float(frame.time) > CLOCK_MAX_S + SAMPLE_S:  # the clock is read: a long video that
                self.retime = False  # is not real time stops here, not after its last frame
                if (time_base := _clock_time_base(overlay, meta.fps)) is not None:
                    raise _Retime(time_base)

        return extract_geometry(
            pairs(),
            _video_source(meta),
            cam,
            dashboard_rows=dashboard_rows,
            lanes=lanes,
            name=self.src_path.stem,
            seed=self.seed,
            on_frame=on_frame,
            lens=self.lens == "auto",
            frame_times=meta.variable_frame_times,
            ego_speed=self.ego_speed,
            overlay_speed=None if overlay is None or not use_speed else lambda: _known_speed(overlay),
            measure_rate_hz=MAX_RATE_HZ * (1.0 if self.time_base is None else self.time_base.time_scale),
        )

    def _overlay_reader(self) -> OverlayReader | None:
        """The reader of the picture's overlay, where one is wanted and a text reader is installed."""
        if not self.overlay:
            return None
        from deepcrashtest.perception.text import make_text_reader

        if "text_reader" not in self.loaded:  # its models load on first use: once for a pass again
            self.loaded["text_reader"] = make_text_reader()
        reader = self.loaded["text_reader"]
        return None if reader is None else OverlayReader(reader)


def _clock_time_base(overlay: OverlayReader | None, fps: float) -> ClockTimeBase | None:
    """The frame rate the picture's clock gives a video stored at ``fps``, where it clearly is not ``fps``."""
    clock = overlay.clock() if overlay is not None else None
    real = clock.real_time_fps(fps) if clock is not None else None
    if clock is None or real is None:
        return None
    rate = clock.rate()
    assert rate is not None  # a real-time frame rate rests on it
    return ClockTimeBase(real, fps, rate, clock.sample)


def _with_overlay_clock(
    sc: Scenario, overlay: OverlayReader | None, fps: float, time_base: ClockTimeBase | None = None
) -> Scenario:
    """``sc`` with the rate of the picture's clock in its provenance (``overlay_clock``: clock seconds per video
    second, its 95 % interval, the ticks it rests on) and a warning where the video is clearly not real time (a
    slow-motion or sped-up video), or where the text reader failed; ``sc`` itself where no clock was read.
    ``time_base``: the frame rate ``fps`` was read off the clock by a pass before (``time_base`` in the provenance,
    and a warning)."""
    if time_base is not None:
        params = {**sc.provenance.parameters, "time_base": time_base.record()}
        prov = sc.provenance.model_copy(update={"parameters": params})
        sc = sc.evolve(provenance=prov, warnings=[*sc.warnings, time_base.warning()])
    if overlay is not None and overlay.failed is not None:
        return sc.evolve(
            warnings=[*sc.warnings, f"the picture's overlay was not read: the text reader failed ({overlay.failed})"]
        )
    clock = overlay.clock() if overlay is not None else None
    rate = clock.rate() if clock is not None else None
    if clock is None or rate is None:
        return sc
    params = {**sc.provenance.parameters}
    params["overlay_clock"] = {
        "rate": round(rate[0], 4),
        "interval_95": [round(rate[1], 4), round(rate[2], 4)],
        "ticks": len(clock.ticks_t),
        "sample": clock.sample,
    }
    sc = sc.evolve(provenance=sc.provenance.model_copy(update={"parameters": params}))
    slow = clock.slow_motion()
    if slow is None:
        return sc
    kind = "slow motion" if slow < 1.0 else "sped up"
    warning = (
        f"the picture's clock ({clock.sample!r}) runs {slow:.2f} s per second of video ({rate[1]:.2f}-{rate[2]:.2f}, "
        f"95 %): {kind}; the scenario's times and speeds follow the video's {fps:g} fps and are off by that factor "
        f"(--fps {clock.real_time_fps(fps) or fps / slow:.4g} plays it in real time)"
    )
    return sc.evolve(warnings=[*sc.warnings, warning])


def _known_speed(overlay: OverlayReader) -> KnownSpeed | None:
    """The speeds read off the picture's overlay as a known speed (None: no speed there)."""
    found = overlay.speed()
    if found is None:
        return None
    return KnownSpeed(found.times_s, found.kmh / 3.6, "overlay", found.describe())


def _check_dashboard_rows(rows: int | None, meta: VideoMeta) -> None:
    """Refuse ``--dashboard-rows`` that would hide the whole frame: a value meant for another resolution (as a
    principal point outside the frame is refused), not one to cut down quietly (the file's rows)."""
    width, height = meta.stored_size
    if rows is not None and rows >= height:
        raise UserError(
            f"--dashboard-rows {rows} hides the whole {width}x{height} frame of {meta.path} "
            f"(give fewer than {height} rows; a value for another resolution?)"
        )


def _camera_for_frames(
    camera: Camera | CameraForVideo | None, meta: VideoMeta, area: tuple[int, int, int, int] | None
) -> Camera:
    """The camera of the frames as processed: the user's (or the callable's, given the file's size and the
    picture area in the file's pixels) scaled to the frames when they are scaled (``meta.scaled_from``)."""
    cam = _given_camera(camera, meta, area)
    meta.warnings += _portrait_note(cam, meta, area)
    return cam


def _given_camera(
    camera: Camera | CameraForVideo | None, meta: VideoMeta, area: tuple[int, int, int, int] | None
) -> Camera:
    """The camera asked for (the user's, the callable's or the unknown-dashcam default) in the frames' pixels."""
    if camera is None:
        return default_camera(meta.width, meta.height, area=area)
    if meta.scaled_from is None:
        return camera(meta.width, meta.height, area=area) if callable(camera) else camera
    (width, height), s = meta.stored_size, meta.scale
    sy = meta.height / height
    if callable(camera):
        file_area = None
        if area is not None:
            x0, y0, x1, y1 = area
            file_area = (round(x0 / s), round(y0 / sy), round(x1 / s), round(y1 / sy))
        camera = camera(width, height, area=file_area)
    return scale_camera(camera, s, sy)


def _portrait_note(cam: Camera, meta: VideoMeta, area: tuple[int, int, int, int] | None) -> list[str]:
    """The note that the default camera took a portrait picture as cut from a landscape dashcam (none for a
    landscape picture, or a camera not the default): a phone filming upright has a shorter focal length, which
    only the user can give."""
    portrait = portrait_size(meta.width, meta.height, area)
    if cam.intrinsics_source != "default" or portrait is None:
        return []
    w, h = portrait
    return [
        f"portrait picture ({w}x{h}): the default camera takes it as cut from a 16:9 landscape dashcam "
        f"(focal length {cam.fx:.0f} px); give --hfov or --camera if it was filmed upright"
    ]


def _dashboard_note(asked: int | None, used: int, meta: VideoMeta) -> list[str]:
    """The warning for a ``--dashboard-rows`` the geometry cut to the bottom third of the frame (none if kept):
    ``used`` in the frames' rows, ``asked`` and the message in the file's (frames scaled: ``meta.scale``)."""
    if asked is None or used >= round(asked * meta.scale):
        return []
    height = meta.stored_size[1]
    return [
        f"--dashboard-rows {asked} cut to {round(used / meta.scale)} (a third of the {height}-row frame: the geometry "
        "needs the road below the horizon)"
    ]


def _summary(plan: _Pass, meta: VideoMeta, df: pd.DataFrame, elapsed: float) -> dict[str, Any]:
    """The run's summary (what ``--json`` prints) before stage 2."""
    n_frames = min(meta.decoded_frames, plan.max_frames) if plan.max_frames else meta.decoded_frames
    if plan.frame_range is not None:
        first, last = plan.frame_range
        n_frames = min(meta.decoded_frames - first, last - first + 1)
        n_frames = min(n_frames, plan.max_frames) if plan.max_frames else n_frames
    lengths = df.groupby("track_id").size() if len(df) else None
    video = plan.paths.get("annotated_mp4")
    return {
        "video": str(plan.src_path),
        "output": str(plan.out),
        "tracks_csv": str(plan.paths["tracks_csv"]),
        "annotated_mp4": str(video) if video is not None else None,
        "detector": plan.det.name,
        "detect_every": plan.detect_every,
        "fps_video": round(meta.fps, 3),
        "fps_video_range": [round(r, 3) for r in meta.rate_range] if meta.rate_range else None,
        "width": meta.width,
        "height": meta.height,
        "scaled_from": None if meta.scaled_from is None else list(meta.scaled_from),
        "frames": int(n_frames),
        "tracks": int(df["track_id"].nunique()) if len(df) else 0,
        "mean_track_length_frames": round(float(lengths.mean()), 2) if lengths is not None else 0.0,
        "fps_achieved": round(n_frames / elapsed, 2) if elapsed > 0 else None,
        "seconds": round(elapsed, 2),
        "scenario_raw": None,
        "scenario": None,
        "report": None,
        "warnings": list(meta.warnings) + _scaled_note(meta) + ([] if len(df) else ["no vehicles found in the video"]),
    }


def _scaled_note(meta: VideoMeta) -> list[str]:
    """The note that the frames were processed scaled (none when they were not)."""
    if meta.scaled_from is None:
        return []
    w, h = meta.scaled_from
    return [
        f"frames processed at {meta.width}x{meta.height} (the video is {w}x{h}; --max-width): tracks.csv, "
        "annotated.mp4 and the scenario's camera are in those pixels"
    ]


def _finish_scenario(
    geo: GeometryResult,
    paths: dict[str, Path],
    force: bool,
    seed: int,
    report: bool,
    warnings: list[str],
    stage2: Stage2Params | None = None,
    kept: SheetThumbs | None = None,
) -> dict[str, Any]:
    """Save the raw scenario, run stage 2 on it, save the processed one and the report (its contact sheet from
    ``kept``, the pass's thumbnails of the annotated frames)."""
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
            "height_m": round(geo.camera.height_m, 3),
        },
        "dashboard_rows": geo.dashboard_rows,
    }
    warnings.extend(raw.warnings)
    from deepcrashtest.pipeline.stage2 import processed_scenario

    try:
        processed = processed_scenario(raw, seed=seed, params=stage2)
    except UserError as exc:  # e.g. no usable track: the run fails as a whole and writes nothing
        raise UserError(
            f"stage 2 could not process the extracted tracks: {exc} (nothing written; --no-geometry writes the "
            "tracks and the annotated video alone)"
        ) from None
    processed.save(paths["scenario"], force=force)
    info["scenario"] = str(paths["scenario"])
    info["collision"] = processed.collision.model_dump() if processed.collision is not None else None
    info["classes"] = processed.class_counts()
    if report:
        from deepcrashtest.viz.report import build_report

        build_report(paths["scenario"], paths["report"], force=force, kept=kept)
        info["report"] = str(paths["report"])
    return info


def _watched(frames: Iterable[Frame], watch: ShotWatch, max_frames: int | None) -> Iterator[Frame]:
    """The frames, each shown to ``watch`` first (the first ``max_frames``); raises
    :class:`_Compilation` as soon as a cut is found."""
    for k, frame in enumerate(frames):
        if (max_frames is None or k < max_frames) and watch.feed(int(frame.index), frame.image):
            raise _Compilation([])
        yield frame


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
