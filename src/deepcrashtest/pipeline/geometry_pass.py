"""The geometry part of extract's one decoding pass: camera estimation + ego-motion + lanes +
localisation -> raw Scenario (orchestration: it chains perception's lane detector and the geometry
libraries; the stages themselves stay libraries).

:func:`extract_geometry` consumes ``(frame, tracks_at_that_frame)`` pairs, where ``frame`` has
``index`` (int), ``time`` (s) and ``image`` (BGR array, full resolution) - the ``Frame`` of
``deepcrashtest.video.source`` - and ``tracks_at_that_frame`` is the tracks table's rows of that
frame (columns of :data:`deepcrashtest.geometry.world_tracks.TRACK_COLUMNS`; may be empty), as a
DataFrame or as the list of row tuples (:func:`~deepcrashtest.perception.track.frame_records`: no
per-frame DataFrame to build; the whole table is built once at the end).

The first ``calib_seconds`` of frames are buffered to estimate what the stream needs before it starts: the
dashboard/bonnet rows (below a persistent edge with a still image beneath, unless given), and the horizon
(vanishing point of the lane lines, else the focus of expansion of the flow, else the camera's own pitch).
Then every buffered and later frame goes through the ego-motion estimator and the lane detector once (both
measure at most ``MAX_RATE_HZ`` frames a second: a 25 fps video at 12.5 fps, the frames between interpolated
or showing the last lanes); frames are never decoded twice. Lanes run in a second thread beside the ego-motion
estimator (both spend their time in OpenCV / NumPy, which release the GIL). When no calibration was given (the
camera's intrinsics are the unknown-dashcam default), the whole video's tracks then calibrate the camera
(:func:`~deepcrashtest.geometry.selfcalib.self_calibrate`: horizon, camera height, focal length, each with its
uncertainty and source) and the ego path is rescaled to the measured camera height.
"""

from __future__ import annotations

from collections.abc import Callable, Iterable, Iterator, Mapping, Sequence
from concurrent.futures import Future, ThreadPoolExecutor
from dataclasses import dataclass
from itertools import chain
from typing import TYPE_CHECKING, Any, Protocol, TypeAlias

import numpy as np

from deepcrashtest.errors import UserError
from deepcrashtest.geometry.camera import (
    detect_dashboard_rows,
    estimate_horizon_flow,
    vanishing_point_from_lines,
    with_horizon,
)
from deepcrashtest.geometry.egomotion import MAX_RATE_HZ, EgoMotion, EgoMotionEstimator, rescaled
from deepcrashtest.geometry.known_speed import KnownSpeed, with_known_speed
from deepcrashtest.geometry.lens import LensEstimate, estimate_lens, opencv_coefficients
from deepcrashtest.geometry.localize import Localizer
from deepcrashtest.perception.lanes import ClassicalLaneDetector, LaneDetector, LaneState, LaneTimelineResult
from deepcrashtest.perception.track import TRACK_COLUMNS, records_table
from deepcrashtest.scenario import Camera, Scenario, VideoSource

if TYPE_CHECKING:  # pandas and the self-calibration (filterpy -> scipy.stats) load in the background meanwhile
    import pandas as pd

    from deepcrashtest.geometry.selfcalib import SelfCalibration


class FrameLike(Protocol):
    index: int
    time: float
    image: np.ndarray


@dataclass
class GeometryResult:
    """Everything the geometry stage produced (the scenario plus per-frame details for overlays)."""

    scenario: Scenario
    camera: Camera
    ego: EgoMotion
    lanes: LaneTimelineResult | None
    lane_states: dict[int, LaneState]
    dashboard_rows: int
    horizon_source: str
    calibration: SelfCalibration | None = None
    #: the same geometry with the ego speeds cut at a crash: see :func:`cut_at_crash`
    speed_cut: SpeedCut | None = None


@dataclass(frozen=True)
class SpeedCut:
    """The geometry stage's last step kept so that it can run again with the ego speeds cut at a crash
    (:meth:`cut`): the pass's ego-motion estimator, its uncut ego-motion, the self-calibration's scale and what
    builds the raw scenario from them (the tracks, the video, the camera, the lanes, the localiser)."""

    estimator: EgoMotionEstimator
    indices: list[int]  #: the video's frame index of each frame the estimator measured
    ego: EgoMotion  #: uncut, as measured (before the self-calibration's scale)
    tracks: pd.DataFrame
    meta: VideoSource | Mapping[str, Any]
    camera: Camera
    lanes: LaneTimelineResult | None
    lane_states: dict[int, LaneState]
    localizer: Localizer | None
    dashboard_rows: int
    horizon_source: str
    calibration: SelfCalibration | None
    #: the self-calibration's (length, focal ratio) for :func:`rescaled`; (1, 1) without one
    scale: tuple[float, float]
    name: str
    seed: int
    #: the lens distortion read from the video's straight edges (no calibration given), if looked for
    lens: LensEstimate | None = None

    def cut(self, crash_time: float, min_change: float) -> GeometryResult | None:
        """The geometry with the ego speeds up to ``crash_time`` (s, video time) smoothed from the readings up
        to it only; None when no speed moves by more than ``min_change`` (m/s)."""
        ego = self._scaled(_ego_result(self.estimator, self.indices, crash_time))
        if np.max(np.abs(ego.speed - self._scaled(self.ego).speed), initial=0.0) <= min_change:
            return None
        return self.result(ego, crash_time)

    def result(self, ego: EgoMotion | None = None, cut_time: float | None = None) -> GeometryResult:
        """The geometry with the ego-motion ``ego`` (None: the uncut one, scaled), cut at ``cut_time`` (s)."""
        ego = self._scaled(self.ego) if ego is None else ego
        from deepcrashtest.geometry.world_tracks import raw_scenario_from_tracks  # SciPy's signal: imported late

        sc = raw_scenario_from_tracks(
            self.tracks, self.meta, self.camera, ego, self.lanes, self.localizer, name=self.name, seed=self.seed
        )
        params = {
            **sc.provenance.parameters,
            "dashboard_rows": self.dashboard_rows,
            "horizon_source": self.horizon_source,
        }
        if self.calibration is not None:
            params["self_calibration"] = self.calibration.summary()
        if self.lens is not None:
            params["lens_distortion"] = self.lens.summary()
        if cut_time is not None:
            params["ego_speed_cut_s"] = round(float(cut_time), 4)
        sc = sc.evolve(provenance=sc.provenance.model_copy(update={"parameters": params}))
        if self.calibration is not None and self.calibration.warnings:
            sc = sc.evolve(warnings=[*sc.warnings, *self.calibration.warnings])
        return GeometryResult(
            sc, self.camera, ego, self.lanes, self.lane_states, self.dashboard_rows, self.horizon_source,
            self.calibration, self,
        )  # fmt: skip

    def _scaled(self, ego: EgoMotion) -> EgoMotion:
        """``ego`` under the self-calibrated camera: speeds scale with focal length x height, rotations (seen as
        focal x angle) with the focal length; the known speed instead where the images' speed is off."""
        if self.calibration is None:
            return ego
        ego = rescaled(ego, *self.scale)
        known = self.calibration.known_speed
        return with_known_speed(ego, known) if self.calibration.replace_ego_speed and known is not None else ego


def estimate_camera(
    images: list[np.ndarray],
    camera: Camera,
    dashboard_rows: int | None = None,
    boxes: list[np.ndarray] | None = None,
) -> tuple[Camera, int, str]:
    """Dashboard rows and horizon from a few frames (``boxes``: each frame's road users, (N, 4) px, whose edges are
    not the bonnet's). Returns (camera with pitch, rows, pitch source)."""
    h, w = images[0].shape[:2]
    step = max(1, len(images) // 9)
    spread = images[::step]  # pairs ~0.2 s apart: enough road motion to see
    spread_boxes = boxes[::step] if boxes is not None else None
    rows = detect_dashboard_rows(spread, boxes=spread_boxes) if dashboard_rows is None else int(dashboard_rows)
    rows = min(rows, h // 3)
    if camera.pitch_source in ("user", "kitti_calib"):
        return camera, rows, camera.pitch_source
    probe = ClassicalLaneDetector(camera, mask_bottom_rows=rows)
    segs = []
    for img in images[:: max(1, len(images) // 10)]:
        for ln in probe.detect(img):
            segs.append([float(ln.u_at(ln.v_top)), ln.v_top, float(ln.u_at(ln.v_bottom)), ln.v_bottom])
    vp = vanishing_point_from_lines(np.array(segs), w, h) if len(segs) >= 2 else None
    if vp is not None and 0.2 * h < vp[1] < 0.8 * h:
        return with_horizon(camera, vp[1], "vanishing_point"), rows, "vanishing_point"
    foe = estimate_horizon_flow(images)
    if foe is not None and 0.2 * h < foe < 0.8 * h:
        return with_horizon(camera, foe, "flow_foe"), rows, "flow_foe"
    return camera, rows, camera.pitch_source


#: One frame's tracks: a tracks-table DataFrame or its rows as tuples (columns of ``TRACK_COLUMNS``).
TrackRows: TypeAlias = "pd.DataFrame | list[tuple[object, ...]]"


def extract_geometry(
    frames: Iterable[tuple[FrameLike, TrackRows]],
    meta: VideoSource | Mapping[str, Any],
    camera: Camera,
    dashboard_rows: int | None = None,
    calib_seconds: float = 2.0,
    lanes: bool = True,
    lane_detector: LaneDetector | None = None,
    localizer: Localizer | None = None,
    max_width: int = 960,
    name: str = "scenario",
    seed: int = 0,
    on_frame: Callable[[FrameLike, TrackRows, LaneState | None], None] | None = None,
    lens: bool = False,
    frame_times: Callable[[], Sequence[float] | None] | None = None,
    ego_speed: float | None = None,
    overlay_speed: Callable[[], KnownSpeed | None] | None = None,
    measure_rate_hz: float = MAX_RATE_HZ,
) -> GeometryResult:
    """Run the geometry stage over one pass of frames (see the module docstring).

    ``on_frame(frame, tracks, lane_state)`` is called once per frame, in order, after the frame went
    through ego-motion and lanes (annotation draws the lanes in the same pass). ``lens``: without a calibration,
    read the lens's radial distortion from the first frames' straight edges (:mod:`deepcrashtest.geometry.lens`).
    ``frame_times``: asked after the last frame, every frame's time (s, by index) where the video's frame rate
    varies (:meth:`deepcrashtest.video.source.VideoMeta.variable_frame_times`), else None: the raw Scenario's
    ``source.frame_times``, which the monocular filter steps by. ``ego_speed``: the ego's speed (m/s) the user knows
    (a GPS overlay or log), from which an uncalibrated camera's focal length is read
    (:func:`deepcrashtest.geometry.known_speed.focal_from_ego_speed`). ``overlay_speed``: asked after the last frame
    where no ``ego_speed`` is given, the ego's speed read off the picture (None: none there), used alike.
    ``measure_rate_hz``: ego-motion and lanes measure at most this many frames a second of the frames' times (a video
    re-timed by its clock keeps the stored frames' cadence: ``MAX_RATE_HZ`` x its frame rate / the file's).
    """
    buffer, rest = _calibration_frames(frames, calib_seconds)
    cam, rows, horizon_source = estimate_camera(
        [f.image for f, _ in buffer], camera, dashboard_rows, [_boxes(t) for _, t in buffer]
    )
    size = (int(buffer[0][0].image.shape[1]), int(buffer[0][0].image.shape[0]))  # width, height (px)
    lens_est = None
    if lens and cam.intrinsics_source == "default" and not cam.distortion:  # the lens from straight edges
        lens_est = estimate_lens([f.image for f, _ in buffer], size[1] - rows if rows else None, seed=seed)
        if lens_est.used:
            cam = cam.model_copy(update={"distortion": opencv_coefficients(lens_est.lam, size, cam.fx)})
    ego_est = EgoMotionEstimator(
        cam, mask_bottom_rows=rows, max_width=max_width, seed=seed, max_rate_hz=measure_rate_hz
    )
    lane_det: LaneDetector | None = lane_detector or (
        ClassicalLaneDetector(cam, mask_bottom_rows=rows, seed=seed) if lanes else None
    )
    lane_states: dict[int, LaneState] = {}
    indices: list[int] = []
    all_tracks: list[pd.DataFrame] = []
    all_rows: list[tuple[object, ...]] = []
    lane_rate = _RateGate(measure_rate_hz)  # lanes on as many frames a second as ego-motion measures
    last_lanes: LaneState | None = None

    with ThreadPoolExecutor(1, thread_name_prefix="lanes") as pool:
        for frame, trk in chain(_drain(buffer), rest):
            boxes = _boxes(trk)
            indices.append(int(frame.index))
            lanes_job: Future[LaneState] | None = None
            if lane_det is not None and lane_rate.take(float(frame.time)):
                lanes_job = pool.submit(lane_det.update, frame.image, float(frame.time), boxes)
            ego_est.update(frame.image, float(frame.time), boxes)
            if lanes_job is not None:
                last_lanes = lanes_job.result()
            if last_lanes is not None:  # a frame between two lane updates shows the last lanes
                lane_states[int(frame.index)] = last_lanes
            if isinstance(trk, list):
                all_rows.extend(trk)
            elif len(trk):
                all_tracks.append(trk)
            if on_frame is not None:
                on_frame(frame, trk, lane_states.get(int(frame.index)))
    ego = _ego_result(ego_est, indices)
    lane_tl = lane_det.timeline() if lane_det is not None else None
    if all_rows:
        all_tracks.append(records_table(all_rows))
    import pandas as pd

    tracks = pd.concat(all_tracks, ignore_index=True) if all_tracks else pd.DataFrame(columns=list(TRACK_COLUMNS))
    calibration = None
    scale = (1.0, 1.0)
    if cam.intrinsics_source == "default" and len(tracks):  # no calibration given: the video calibrates it
        from deepcrashtest.geometry.selfcalib import self_calibrate

        known = KnownSpeed.constant(ego_speed) if ego_speed is not None else None
        if known is None and overlay_speed is not None:
            known = overlay_speed()
        calibration = self_calibrate(tracks, cam, size, ego, ego_scaled_by_height=True, known_speed=known)
        scale = (calibration.ego_scale, cam.fy / calibration.camera.fy)
        cam = calibration.camera
        horizon_source = cam.pitch_source

    times = frame_times() if frame_times is not None else None
    if times is not None:
        meta = _with_frame_times(meta, times)
    cut = SpeedCut(
        estimator=ego_est, indices=indices, ego=ego, tracks=tracks, meta=meta, camera=cam, lanes=lane_tl,
        lane_states=lane_states, localizer=localizer, dashboard_rows=rows, horizon_source=horizon_source,
        calibration=calibration, scale=scale, name=name, seed=seed, lens=lens_est,
    )  # fmt: skip
    return cut.result()


def _with_frame_times(meta: VideoSource | Mapping[str, Any], times: Sequence[float]) -> VideoSource | Mapping[str, Any]:
    """The video's description with every frame's time (s, by index): ``VideoSource.frame_times``."""
    if isinstance(meta, VideoSource):
        return meta.model_copy(update={"frame_times": list(times)})
    return {**meta, "frame_times": list(times)}


def _ego_result(est: EgoMotionEstimator, indices: list[int], cut_time: float | None = None) -> EgoMotion:
    """The estimator's ego-motion (speeds smoothed apart before and after ``cut_time``, s) at the video's
    frame indices (the estimator counts 0..n-1)."""
    ego = est.result(cut_time)
    ego.frame = np.array(indices, dtype=int)
    return ego


def cut_at_crash(geo: GeometryResult, crash_time: float, min_change: float = 0.05) -> GeometryResult:
    """``geo`` again with the ego speeds up to ``crash_time`` (s, video time) smoothed from the readings up
    to it only (:meth:`EgoMotionEstimator.result`'s ``cut_time``): the speed smoother otherwise carries the
    crash's slowing, read after it, back before it (ccd_000053). Unchanged (``geo`` itself) when no speed
    moves by more than ``min_change`` (m/s) or ``geo`` cannot be rebuilt."""
    cut = None if geo.speed_cut is None else geo.speed_cut.cut(crash_time, min_change)
    return geo if cut is None else cut


class _RateGate:
    """``take(time)``: True for the first frame and for each frame at least ~1 / ``max_hz`` s after the
    last taken one (the rule of ``EgoMotionEstimator(max_rate_hz)``: a 25 fps video at 12.5 fps, 10
    and 20 fps videos at every frame)."""

    def __init__(self, max_hz: float | None) -> None:
        self.min_gap_s = 0.9 / max_hz if max_hz else 0.0
        self.last: float | None = None

    def take(self, time: float) -> bool:
        if self.last is not None and time - self.last < self.min_gap_s:
            return False
        self.last = time
        return True


def _boxes(trk: TrackRows) -> np.ndarray:
    """(N, 4) x1, y1, x2, y2 px of one frame's tracks."""
    if isinstance(trk, list):
        return np.array([r[4:8] for r in trk], dtype=float).reshape(-1, 4)
    return trk[["x1", "y1", "x2", "y2"]].to_numpy(float) if len(trk) else np.zeros((0, 4))


def _drain(buffer: list[tuple[FrameLike, TrackRows]]) -> Iterator[tuple[FrameLike, TrackRows]]:
    """The buffered pairs in order, each let go as it is taken (2 s of full frames are ~150 MB)."""
    buffer.reverse()
    while buffer:
        yield buffer.pop()


def _calibration_frames(
    frames: Iterable[tuple[FrameLike, TrackRows]], calib_seconds: float
) -> tuple[list[tuple[FrameLike, TrackRows]], Iterable[tuple[FrameLike, TrackRows]]]:
    """The first ``calib_seconds`` of (frame, tracks) pairs (at least 3 frames) and the rest."""
    buffer: list[tuple[FrameLike, TrackRows]] = []
    it = iter(frames)
    for item in it:
        buffer.append(item)
        if item[0].time - buffer[0][0].time >= calib_seconds and len(buffer) >= 3:
            break
    if len(buffer) < 2:
        raise UserError(
            "the video has fewer than 2 frames: a scenario needs the motion between frames "
            "(--no-geometry writes the tracks alone)"
        )
    return buffer, it
