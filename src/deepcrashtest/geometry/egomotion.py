"""Metric ego-motion (speed, yaw rate, path) from a monocular video, one frame at a time.

Method (frames are processed at most ``max_width`` px wide; the intrinsics follow):

1. Scene points: corners on the static scene (vehicle boxes, the dashboard/bonnet rows and
   burned-in overlays that stay still while the scene moves are masked out) are tracked with
   pyramidal Lucas-Kanade from frame to frame and reused; only gaps are refilled, with a separate
   low-threshold quota on the road in front. Each track starts from a prediction (its last flow,
   or the last frame's road homography), and is kept only if the backward track returns within
   ``fb_max_px``.
2. Keyframes: the motion is solved between the last keyframe and the current frame once the
   median parallax reaches ``min_parallax_px`` (every frame when driving; several frames when
   crawling). A parallax that stays below ``static_flow_px`` for ``static_window_s`` is a
   measurement too: the ego is stopped (speed 0), not a failure.
3. Rotation and translation direction from the essential matrix (``cv2.findEssentialMat`` with
   MAGSAC, ``cv2.recoverPose``).
4. Metric scale from the road: the plane-induced homography ``R + (|T|/h) t n^T`` with the known
   camera height ``h`` is fitted to the road points (robust Gauss-Newton over ``|T|/h`` and the
   plane's tilt ``n``, a prior keeping ``n`` near the slowly adapting road normal). Three
   parameters instead of a free 8-DOF homography: stable on a few dozen weak road corners.
5. Speeds go through a constant-acceleration Kalman filter (outliers gated); :meth:`result`
   returns the Rauch-Tung-Striebel smoothed speeds and the path integrated from them and the yaw
   (about the road normal).

Frames: the path is that of the camera, in the world frame of ``deepcrashtest.scenario`` (origin
at the camera's ground point at the first frame, x forward, y left, metres; yaw radians CCW).
``EgoState`` from :meth:`EgoMotionEstimator.update` is causal (filtered); :meth:`result` is smoothed.
A camera that does not move gives speed 0 and a warning; frames too dark or featureless to track
keep the predicted speed and are flagged ``valid=False``.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, field, replace
from typing import Any

import cv2
import numpy as np

from deepcrashtest.geometry.road_motion import MIN_ROAD_POINTS, PlaneFit, fit_plane_motion, ground_envelope_scale
from deepcrashtest.geometry.speed_filter import SpeedFilter
from deepcrashtest.perception.flow import top_up_corners, track_points
from deepcrashtest.scenario import Camera
from deepcrashtest.video.repeats import RepeatWatch

#: Fewer tracked static-scene corners than this and a frame pair is not trusted.
MIN_MATCHES = 40
#: Fewer speed readings than this (road-scale or "stopped" ones the filter took, not gated) over a clip whose camera
#: moves: its speed is barely measured, and :meth:`EgoMotionEstimator.result` says so. ccd_000487 (a pickup at
#: highway speed on a textureless rural road, 10 fps) took none and read 0 km/h with no warning.
MIN_SPEED_READINGS = 3
#: Frames closer than ~1 / this (s) to the last measured one are not measured but interpolated (a 25 or 30 fps
#: video is measured at 12.5 or 15 fps; 10 and 20 fps videos, KITTI and the crash clips, at every frame):
#: half the ego-motion CPU of a 25 fps clip. The estimator's motion per pair is then at most KITTI's
#: (10 fps, where its errors were measured); see README Performance for the check. Lower caps were measured and
#: rejected (README Performance, branch extractfps4): 10 Hz (25 fps every third frame) read the highway clip's
#: speed 1-3 % faster than every frame; 15 Hz (20 fps DAD clips every other frame) moved their speeds outside
#: the every-frame spread and lowered their fidelity IoU (processed 0.61 -> 0.60, replay 0.55 -> 0.51).
MAX_RATE_HZ = 20.0
#: Road points moving less than this share of the flow the pair's rotation alone gives them are fixed to the camera
#: and stay out of :func:`.road_motion.fit_joint_speed` (the ``fixed_flow_share`` value chosen on KITTI odometry,
#: README).
_JOINT_FIXED_SHARE = 0.1
#: Relative 1-sigma of a speed reading from the static points' ground envelope (:meth:`EgoMotionEstimator._envelope`),
#: used where the road gives fewer than ``MIN_SPEED_READINGS`` (:meth:`EgoMotionEstimator.result`). Its per-pair error
#: on KITTI odometry seq00 spans -10..+3 % (10-90 %) but on the crash clips' compressed 10 fps frames the readings
#: scatter far more (ccd_000014: 9-53 km/h, 0.44 in log); 0.15 let that scatter through as 20 m/s^2 of speed change
#: (the 20 clips with the envelope in every pair the road left: mean IoU 0.632 / 0.613 against 0.638 / 0.616 at 0.35).
ENVELOPE_REL_STD = 0.35
#: Grey-level standard deviation below which a frame is too dark or flat to track (0-255 scale).
DARK_CONTRAST = 6.0


@dataclass
class EgoState:
    """Ego state after one frame. Speeds m/s, yaw rate rad/s, positions metres (world frame)."""

    frame: int
    time: float
    speed: float
    yaw_rate: float
    x: float
    y: float
    yaw: float
    valid: bool
    matches: int = 0
    road_points: int = 0
    raw_speed: float | None = None


@dataclass
class EgoMotion:
    """The whole ego track: per-frame arrays (seconds, metres, radians, m/s) and warnings."""

    frame: np.ndarray
    t: np.ndarray
    x: np.ndarray
    y: np.ndarray
    yaw: np.ndarray
    speed: np.ndarray
    yaw_rate: np.ndarray
    valid: np.ndarray
    warnings: list[str] = field(default_factory=list)
    static: bool = False
    #: Per-frame camera pitch (radians, nose up positive) from an external pose source (e.g. stereo
    #: SLAM poses); None for image-based ego-motion, whose rotations are measured with the assumed
    #: focal length and so cannot calibrate it.
    pitch: np.ndarray | None = None
    #: Per-frame camera tilt from the image rotations between frames (radians): ``tilt[:, 0]`` pitch (nose up
    #: positive), ``tilt[:, 1]`` roll (clockwise as seen from behind positive), each integrated over the clip
    #: from 0 at the first frame (so it drifts slowly; the fast part is the camera's wobble). None: not measured.
    tilt: np.ndarray | None = None

    def __len__(self) -> int:
        return len(self.t)

    def path_length(self) -> float:
        """Metres travelled along the integrated path."""
        return float(np.sum(np.hypot(np.diff(self.x), np.diff(self.y)))) if len(self.x) > 1 else 0.0

    @classmethod
    def from_poses(cls, poses: np.ndarray, fps: float, frames: np.ndarray | None = None) -> EgoMotion:
        """The ego track of known camera poses: (N, 4, 4) ``T_cam0_camk`` (camera k in the first
        camera's frame, x right, y down, z forward, metres; e.g. KITTI/ORB-SLAM3 poses), frame k at
        ``k / fps`` seconds (or ``frames[k] / fps``). Positions are the camera's, in the world frame."""
        from deepcrashtest.geometry.frames import camera_forward_yaw, camera_points_to_world

        poses = np.asarray(poses, dtype=float)
        frame = np.arange(len(poses)) if frames is None else np.asarray(frames, dtype=int)
        t = frame / float(fps)
        xy = np.array([camera_points_to_world(T, np.zeros((1, 3)))[0, :2] for T in poses]).reshape(-1, 2)
        yaw = np.unwrap([camera_forward_yaw(T) for T in poses]) if len(poses) else np.zeros(0)
        grad = len(poses) > 1
        speed = np.hypot(np.gradient(xy[:, 0], t), np.gradient(xy[:, 1], t)) if grad else np.zeros(len(t))
        rate = np.gradient(yaw, t) if grad else np.zeros(len(t))
        pitch = np.array([math.asin(float(np.clip(-T[1, 2], -1.0, 1.0))) for T in poses])  # optical axis up
        return cls(frame, t, xy[:, 0], xy[:, 1], yaw, speed, rate, np.ones(len(t), bool), pitch=pitch)


def _down_vector(pitch_rad: float, roll_rad: float = 0.0) -> np.ndarray:
    """World 'down' expressed in the camera frame (x right, y down, z forward) for a pitched camera."""
    down = np.array([0.0, math.cos(pitch_rad), math.sin(pitch_rad)])
    c, s = math.cos(roll_rad), math.sin(roll_rad)
    rz = np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])
    return rz @ down


def _rotation_yaw(R_cam: np.ndarray, down: np.ndarray) -> float:
    """Yaw (rad, CCW seen from above = left turn positive) of a camera rotation about the road normal."""
    rvec, _ = cv2.Rodrigues(R_cam)
    return float(-(rvec.ravel() @ down))


def _epipolar_px(E: np.ndarray, p0: np.ndarray, p1: np.ndarray, K: np.ndarray) -> np.ndarray:
    """Distance (pixels) of each ``p1`` from the epipolar line of its ``p0`` under ``E``."""
    Ki = np.linalg.inv(K)
    h0 = np.column_stack([p0, np.ones(len(p0))]) @ Ki.T
    h1 = np.column_stack([p1, np.ones(len(p1))]) @ Ki.T
    lines = h0 @ E.T
    return np.abs(np.sum(h1 * lines, axis=1)) / np.maximum(np.hypot(lines[:, 0], lines[:, 1]), 1e-12) * K[0, 0]


class EgoMotionEstimator:
    """Streaming monocular ego-motion: call :meth:`update` once per frame, then :meth:`result`.

    ``camera`` gives intrinsics (pixels of the full frame), height (m) and pitch/roll (rad).
    ``mask_bottom_rows``: rows at the bottom of the frame to ignore (dashboard/bonnet), full-frame px.
    ``max_width``: frames wider than this are downscaled first (speed; the intrinsics follow).
    ``static_flow_px`` / ``min_parallax_px``: median parallax (full-frame px) below which the ego
    counts as stopped (held ``static_window_s``) / above which a keyframe pair is solved.
    ``smooth_window``: kept for compatibility (the Kalman filter replaced the running median).
    ``accel_tau_s``: correlation time (s) of the ego's acceleration in the speed filter (0: constant
    acceleration).
    ``max_rate_hz``: frames closer than ~1 / this to the last measured one are not measured; their
    state is interpolated (or extrapolated at the end) in :meth:`result` (None: every frame).
    ``still_mask``: full-frame bool mask (True: not scene) of burned-in overlays found beforehand
    (:func:`deepcrashtest.geometry.camera.static_overlay_mask`): no road corner is seeded there and no point
    there enters the road-scale fit. The scene's corners may still sit on it (as before the mask): masking
    them too left the essential matrix of blurred 10 fps clips without still points and its rotations
    noisy (ccd_000080: pitch swinging +-0.1 rad between frames, the camera attitude from them dropped the
    fidelity IoU 0.72 / 0.64 -> 0.43 / 0.22). ``extract`` does not pass it (it changed dad_000487's ego
    speed and lost that clip's crash; README, ego speed on real dashcam clips).
    ``road_flow_share``: in a pair whose scene moves, a road point moving less than this share of the
    scene's parallax is not road (see :meth:`_solve`); 0 (default): only the 0.1 work-px floor. Measured, not
    made the default: at 0.05 (half the 0.5th percentile of the share on KITTI odometry seq00 / seq06 road
    points, 0.081 / 0.086, so it drops none of them; on ccd_000014 45 % of the road-region points move less
    than 0.1 of it) KITTI moved within its noise (seq00 2.16 -> 2.05 %, 0.349 -> 0.055 deg/100 m; seq06 0.81
    -> 0.81 %, 0.572 -> 0.583) but the fidelity guard rail did not hold (dad_000487's ego 2 % slower at the
    end, two bystanders then touch 1.5 s before its crash; ccd_000053 IoU 0.73 -> 0.66) and ccd_000014's
    extract speed stayed at 28-30 km/h (README, ego speed on real dashcam clips).
    ``max_travel_dev_deg``: a pair whose camera motion points further than this from the direction of travel
    gives no road scale (:meth:`_off_travel`); 180 (default): off. Measured, not made the default: at 30
    (about 3x the largest deviation on KITTI odometry seq00 / seq06, 10.9 / 0.8 deg over 159 / 50 pairs,
    seq00's turns included, so KITTI is unchanged) the fidelity clips kept 18 / 18 crashes, ccd_000053's IoU
    rose 0.73 -> 0.79 (its 3-10 km/h readings at frames 36-40 were sideways pairs) but ccd_000132's fell 0.69
    -> 0.61 (its one late reading, 1 km/h, was one; the speed stays at its first, 9 km/h) and the processed
    IoU mean 0.6476 -> 0.6470.
    ``speed_hold_accel``: the speed filter's ``hold_accel`` (m/s^2, see ``SpeedFilter``; 0, the default: off).
    1 was chosen on KITTI odometry seq00 with every 5th / 10th reading kept (``bench/road_scale_scatter.py
    --keep 5 --keep 10``): output median speed error 4.7 / 9.4 % -> 4.1 / 4.4 % (0.5: 4.8 / 5.3 %), gated
    readings 6 / 5 -> 0; seq06 (10 / 5 readings) 0.76 / 0.31 -> 0.77 / 0.61 %; with a reading every frame the
    filter never holds (KITTI as before). Not the default: on the fidelity clips ccd_000053's IoU fell 0.73 ->
    0.53 (its readings of 10 / 9 km/h at frames 36-37, after its crash at frame 33, are now fused and the
    smoother carries the slowing back before the crash). Still not the default with extract's cut at the crash
    (:meth:`result`'s ``cut_time``; 20 fidelity clips held): a phone-filmed copy of ccd_000053 then fused a late
    reading, ramped 5 -> 13.7 m/s before its crash and its replay missed the crash (README).
    ``fixed_flow_share``: a road point that moves less than this share of the flow the pair's rotation alone gives
    it (where that flow is >= ``_FIXED_MIN_ROT_PX``) is fixed to the camera, not road, and leaves the road-plane fit
    (:meth:`_camera_fixed`); 0 (default): off. Measured, not made the default: at 0.1 (a third of the 0.5th
    percentile of the ratio on KITTI odometry road points, seq06 / seq00 0.27 / 0.34; ccd_000014: 57 % of its
    road-region points under 0.1, the dashboard and its reflection at the bottom left of a camera that shakes by
    5-20 px a frame) KITTI odometry is unchanged (seq00 2.16 % / 0.349 deg/100 m, seq06 0.81 % / 0.572) and on
    ccd_000014 at the camera its overlay implies (2,400 px, 0.92 m) the road-scale readings go from median 19.6
    km/h (6 readings, 10-90 % 5.7-49.4) to 57.2 (4 readings, 38-62) against the overlay's 57-59, ego speed -13 %
    -> +2 % (``bench/ego_speed_overlays.py --fx 2400 --height 0.92``); but in a fresh fidelity extract of the
    20 clips ccd_000755's crash came 0.26 s late (its ego 3 % faster; processed IoU 0.61 -> 0.41), ccd_000053
    0.82 -> 0.77 (its flagged points are codec-block corners on a blank road, the ego 10 % faster), means
    0.652 / 0.625 -> 0.642 / 0.615 (dad_000493 0.35 -> 0.41). Extract's ccd_000014 reads 34 -> 28 km/h (main
    34 -> 30): at the default camera it keeps one reading (21 km/h x 1.55), and the readings do not follow the
    assumed focal length (README, ego speed on real dashcam clips).
    ``road_shift_prior_px``: the road-plane fit also fits one image shift of the road points (a Gaussian prior of
    this 1-sigma, work px; :func:`fit_plane_motion`): the rotation error of the road's rows (rolling shutter, a
    shaking mount) then no longer reads as speed, and a reading whose road rows span too little depth to tell the
    two apart gets the large variance it has; 0 (default): off. ``max_scale_rel_std``: a road-scale reading whose
    1-sigma is over this share of it does not reach the speed filter (ill-conditioned; its fit still warps the
    next frame's road tracking); inf (default): off. Neither is the default
    (README / docs/notes/egospeed11.md: KITTI unchanged, ccd_000014 no nearer its overlay).
    ``keep_pairs``: every solved keyframe pair is kept in ``pairs`` (its road points, rotation, translation, time
    span) for :func:`.road_motion.fit_joint_speed` (one speed over many pairs; a diagnosis, not used by ``extract``)."""

    def __init__(
        self,
        camera: Camera,
        mask_bottom_rows: int = 0,
        max_width: int = 960,
        horizon_v: float | None = None,
        static_flow_px: float = 0.5,
        smooth_window: int = 5,
        road_half_width_m: float = 1.5,
        scale_method: str = "homography",
        seed: int = 0,
        min_parallax_px: float = 3.0,
        static_window_s: float = 0.25,
        max_keyframe_s: float = 1.0,
        corners: int = 200,
        road_corners: int = 200,
        fb_max_px: float = 0.5,
        ransac_px: float = 0.5,
        jerk: float = 1.0,
        lk_win: int = 11,
        speed_noise_rel: float = 0.05,
        max_road_m: float = 30.0,
        coarse_corners: bool = True,
        accel_tau_s: float = 1.5,
        max_rate_hz: float | None = MAX_RATE_HZ,
        still_mask: np.ndarray | None = None,
        road_flow_share: float = 0.0,
        max_travel_dev_deg: float = 180.0,
        speed_hold_accel: float = 0.0,
        fixed_flow_share: float = 0.0,
        keep_pairs: bool = False,
        road_shift_prior_px: float = 0.0,
        max_scale_rel_std: float = math.inf,
    ) -> None:
        if scale_method != "homography":
            raise ValueError(f"scale_method must be 'homography' (got {scale_method!r})")
        self.camera = camera
        self.road_half_width_m = road_half_width_m
        self.scale_method = scale_method
        self.mask_bottom_rows = int(mask_bottom_rows)
        self.max_width = int(max_width)
        self.horizon_v = horizon_v
        self.static_flow_px = static_flow_px
        self.min_parallax_px = min_parallax_px
        self.static_window_s = static_window_s
        self.max_keyframe_s = max_keyframe_s
        self.corners = corners
        self.road_corners = road_corners
        self.fb_max_px = fb_max_px
        self.ransac_px = ransac_px
        self.seed = seed
        self.lk_win = lk_win
        self.speed_noise_rel = speed_noise_rel
        self.max_road_m = max_road_m
        self.coarse_corners = coarse_corners
        self.road_flow_share = road_flow_share
        self.max_travel_dev_deg = max_travel_dev_deg
        self.fixed_flow_share = fixed_flow_share
        self._scale_f = 1.0
        self._K: np.ndarray | None = None
        self._down = _down_vector(camera.pitch_rad, camera.roll_rad)
        self._normal = self._down.copy()
        self._travel: np.ndarray | None = None  # direction of travel, camera frame (running mean)
        self._travels = 0
        self._pitch_from_motion = horizon_v is None and camera.pitch_source not in ("user", "kitti_calib")
        self._new_filter = lambda: SpeedFilter(jerk=jerk, accel_tau_s=accel_tau_s, hold_accel=speed_hold_accel)
        self._filter = self._new_filter()
        #: per filter step: (dt s, road reading m/s or None, its variance, ground-envelope reading or None, variance)
        self._readings: list[tuple[float, float | None, float, float | None, float]] = []
        self._ground: PlaneFit | None = None  # the last solved pair's ground-envelope scale, where the road gave none
        self._states: list[EgoState] = []
        self._dt: list[float] = []
        self._dyaw: list[float] = []
        self._dtilt: list[tuple[float, float]] = []  # (pitch, roll) change of each measured frame, rad
        self._x = self._y = self._yaw = 0.0
        self._last_time: float | None = None
        self._frame = 0
        self._invalid = 0
        self._unsolved = 0  # invalid pairs with features enough whose camera motion could not be solved
        self._static = 0
        self._pairs = 0
        self._unscaled = 0
        self._pyr: np.ndarray | None = None
        self._p = np.zeros((0, 2), np.float32)  # points in the last frame (work px)
        self._p_kf = np.zeros((0, 2), np.float32)  # the same points at the keyframe (NaN: added later)
        self._v = np.zeros((0, 2), np.float32)  # their last flow (NaN: new)
        self._kf_time = 0.0
        self._kf_frames = 0
        self._frame_motion: tuple[np.ndarray, np.ndarray, float, np.ndarray] | None = None
        self._overlay: np.ndarray | None = None  # votes per 16-px cell for still overlay points
        self._dist = np.asarray(camera.distortion, dtype=float)
        self.max_rate_hz = max_rate_hz
        self._all: list[tuple[int, float]] = []  # (frame, time) of every update, measured or not
        self._repeats = RepeatWatch()
        self.still_mask = still_mask
        self._still: np.ndarray | None = None  # still_mask at the work resolution
        self.keep_pairs = keep_pairs
        self.road_shift_prior_px = road_shift_prior_px
        self.max_scale_rel_std = max_scale_rel_std
        self.pairs: list[dict[str, Any]] = []  # with keep_pairs: every solved keyframe pair (fit_joint_speed)
        self._now = 0.0

    # ------------------------------------------------------------------ helpers
    def _prepare(self, grey: np.ndarray) -> np.ndarray:
        """The grey frame at the work resolution (``max_width``; the intrinsics follow on the first call)."""
        h, w = grey.shape[:2]
        if self._K is None:
            self._scale_f = min(1.0, self.max_width / float(w))
            K = self.camera.matrix().copy()
            K[:2] *= self._scale_f
            self._K = K
        if self._scale_f < 1.0:
            grey = cv2.resize(grey, None, fx=self._scale_f, fy=self._scale_f, interpolation=cv2.INTER_AREA)
        return grey

    def _static_mask(self, shape: tuple[int, int], boxes: np.ndarray) -> np.ndarray:
        h, w = shape
        mask = np.full((h, w), 255, np.uint8)
        s = self._scale_f
        if self.mask_bottom_rows > 0:
            mask[max(0, h - int(math.ceil(self.mask_bottom_rows * s))) :] = 0
        for x1, y1, x2, y2 in np.asarray(boxes, dtype=float).reshape(-1, 4):
            pad = 0.1 * (x2 - x1)
            mask[
                max(0, int((y1 - pad) * s)) : max(0, int((y2 + pad) * s)),
                max(0, int((x1 - pad) * s)) : max(0, int((x2 + pad) * s)),
            ] = 0
        if self.still_mask is not None and (self._still is None or self._still.shape != (h, w)):
            small = cv2.resize(self.still_mask.astype(np.uint8), (w, h), interpolation=cv2.INTER_NEAREST)
            self._still = small > 0
        if self._overlay is not None:
            cells = (self._overlay[0] >= 3) & (self._overlay[0] >= 3 * self._overlay[1])
            still = cv2.resize(cells.astype(np.uint8), (w, h), interpolation=cv2.INTER_NEAREST)
            mask[still > 0] = 0
        return mask

    def _undistort(self, p: np.ndarray) -> np.ndarray:
        """Work-px points without the lens distortion (the camera's, if it has one): the essential
        matrix and the road homography hold for a pinhole only. Tracking stays on the raw frames."""
        if not self._dist.size or not len(p):
            return p
        assert self._K is not None
        pts = p.reshape(-1, 1, 2).astype(np.float64)
        return cv2.undistortPoints(pts, self._K, self._dist, P=self._K).reshape(-1, 2).astype(np.float32)

    def _horizon_row(self) -> float:
        assert self._K is not None
        if self.horizon_v is not None:
            return self.horizon_v * self._scale_f
        if self._pitch_from_motion and self._travel is not None and self._travel[2] > 0.5:
            return float(self._K[1, 2] + self._K[1, 1] * self._travel[1] / self._travel[2])
        return float(self._K[1, 2] - self._K[1, 1] * math.tan(self.camera.pitch_rad))

    def _road_region(self, u: np.ndarray, v: np.ndarray, h: int, width_factor: float = 1.0) -> np.ndarray:
        """Points on the road ahead: below the horizon, within ``road_half_width_m``, nearer than 30 m."""
        assert self._K is not None
        K = self._K
        hv = self._horizon_row()
        below = np.maximum(v - hv, 1e-6)
        u_travel = K[0, 2]  # the column the road ahead runs to: the direction of travel when known
        if self._travel is not None and self._travel[2] > 0.5:
            u_travel = K[0, 2] + K[0, 0] * self._travel[0] / self._travel[2]
        lateral = np.abs(u - u_travel) / K[0, 0] * K[1, 1] * self.camera.height_m / below
        ahead = K[1, 1] * self.camera.height_m / below
        return (v > hv + 0.04 * h) & (lateral < width_factor * self.road_half_width_m) & (ahead < self.max_road_m)

    def _road_mask(self, mask: np.ndarray) -> np.ndarray:
        h, w = mask.shape
        vv, uu = np.mgrid[0:h:4, 0:w:4]
        coarse = self._road_region(uu.astype(float), vv.astype(float), h).astype(np.uint8)
        road = cv2.resize(coarse, (w, h), interpolation=cv2.INTER_NEAREST) * 255
        if self._still is not None:
            road[self._still] = 0
        return cv2.bitwise_and(road, mask)

    def _off_overlay(self, p: np.ndarray) -> np.ndarray:
        """Whether each work-px point (N, 2) lies off the burned-in overlay (``still_mask``)."""
        if self._still is None or not len(p):
            return np.ones(len(p), bool)
        h, w = self._still.shape
        ix, iy = np.clip(p[:, 0].astype(int), 0, w - 1), np.clip(p[:, 1].astype(int), 0, h - 1)
        return ~self._still[iy, ix]

    def _track(self, prev: np.ndarray, cur: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Track the last frame's points into ``cur`` (work px): (positions, good mask).

        Scene points start from their last flow (LK on the raw pair). Road points are tracked on
        the previous frame warped by the last frame's road homography: the near road then neither
        moves far nor stretches, which otherwise biases translation-only LK towards too little
        flow (measured on KITTI seq06/seq00: -8 % speed with 15-px windows at 640 px).
        """
        h = prev.shape[0]
        p = self._p
        guess = np.where(np.isfinite(self._v), p + self._v, p)
        p1, good = track_points(prev, cur, p, guess, win=self.lk_win, fb_max_px=self.fb_max_px)
        road = self._road_region(p[:, 0], p[:, 1], h)
        if self._frame_motion is None or self._K is None or not road.any():
            return p1, good
        R, t, sigma, n = self._frame_motion
        K = self._K
        H = K @ (R + sigma * np.outer(t, n)) @ np.linalg.inv(K)
        q = cv2.perspectiveTransform(p[road].reshape(-1, 1, 2).astype(np.float64), H).reshape(-1, 2).astype(np.float32)
        # Only the box around the road points is warped (the road is a fraction of the frame); LK reads
        # nothing beyond the margin, so the tracks are the same as on a wholly warped frame.
        x0, y0, x1, y1 = _crop_box(q, prev.shape[1], h, margin=_ROAD_CROP_MARGIN_PX, align=4)
        shift = np.array([[1.0, 0.0, -x0], [0.0, 1.0, -y0], [0.0, 0.0, 1.0]])
        warped = np.zeros_like(prev)
        warped[y0:y1, x0:x1] = cv2.warpPerspective(prev, shift @ H, (x1 - x0, y1 - y0), flags=cv2.INTER_LINEAR)
        q1, ok = track_points(warped, cur, q, None, win=self.lk_win, fb_max_px=self.fb_max_px, levels=2)
        p1[road], good[road] = q1, ok
        return p1, good

    def _vote_overlay(self, p0: np.ndarray, p1: np.ndarray, shape: tuple[int, int]) -> None:
        """Count, per 16-px cell, points that stay still (< 0.3 px) and points that move (> 1 px) while
        the scene's parallax is large; cells mostly still are burned-in overlays,
        dashboard parts or lens vignetting and leave future masks (see :meth:`_static_mask`)."""
        h, w = shape
        if self._overlay is None:
            self._overlay = np.zeros((2, (h + 15) // 16, (w + 15) // 16), np.int32)
        d = np.linalg.norm(p1 - p0, axis=1)
        still = d < 0.3
        moving = d > 1.0
        iy = np.clip(p1[:, 1].astype(int) // 16, 0, self._overlay.shape[1] - 1)
        ix = np.clip(p1[:, 0].astype(int) // 16, 0, self._overlay.shape[2] - 1)
        np.add.at(self._overlay[0], (iy[still], ix[still]), 1)
        np.add.at(self._overlay[1], (iy[moving], ix[moving]), 1)

    def _learn_travel(self, R: np.ndarray, t: np.ndarray, dyaw: float) -> None:
        """Running mean of the direction of travel (camera frame): the camera centre's motion turned
        back by half the yaw (a car moves along the arc of its turn). Travel is parallel to the
        road, so unless the pitch was calibrated it sets the horizon and the road normal's pitch:
        a wrong default or a mis-detected vanishing point then no longer hides the road."""
        c = -R.T @ t
        back, _ = cv2.Rodrigues(self._normal * (0.5 * dyaw))
        c = back @ c
        if c[2] <= 0.5:
            return
        self._travels += 1
        rate = max(0.05, 1.0 / self._travels)
        self._travel = c if self._travel is None else _tilted_towards(self._travel, c, rate)
        if self._pitch_from_motion:
            tr = self._travel
            self._down = _down_vector(math.atan2(-tr[1], tr[2]), self.camera.roll_rad)
            n = self._normal - (self._normal @ tr) * tr
            self._normal = n / np.linalg.norm(n)

    def _off_travel(self, R: np.ndarray, t: np.ndarray) -> bool:
        """Whether the camera's motion of a pair (``X1 = R X0 + |T| t``) points more than ``max_travel_dev_deg``
        away from the direction of travel learned so far (the optical axis before any). A car moves along its
        heading; on 10 fps dashcam clips a third of the essential matrices put the camera moving sideways
        (75-113 deg off; ccd_000014) and their road planes gave readings of 2-20 km/h at 58."""
        if self.max_travel_dev_deg >= 180.0:
            return False
        c = -R.T @ t
        ref = self._travel if self._travel is not None else np.array([0.0, 0.0, 1.0])
        cos = float(c @ ref) / max(float(np.linalg.norm(c) * np.linalg.norm(ref)), 1e-12)
        return cos < math.cos(math.radians(self.max_travel_dev_deg))

    def _camera_fixed(self, p0: np.ndarray, p1: np.ndarray, R: np.ndarray, share: float | None = None) -> np.ndarray:
        """Whether each work-px point pair (``p0`` -> ``p1``, N x 2) stays put in the image while the camera's
        rotation ``R`` (``X1 = R X0 + |T| t``) moves every scene point by at least ``_FIXED_MIN_ROT_PX``: a point
        fixed to the camera (dashboard, its reflection in the windscreen, burned-in text), not scene. A scene
        point at any depth moves by the rotation's flow plus a translation flow along its epipolar line; staying
        put takes the two to cancel, which the road's translation flow (radial from the direction of travel) does
        not do for a whole patch. Still means moving less than ``share`` (default ``fixed_flow_share``) of the
        rotation's own flow."""
        share = self.fixed_flow_share if share is None else share
        if share <= 0.0 or not len(p0):
            return np.zeros(len(p0), bool)
        assert self._K is not None
        K = self._K
        x0 = np.column_stack([p0, np.ones(len(p0))]) @ np.linalg.inv(K).T
        a = x0 @ (K @ R).T
        rot = np.linalg.norm(a[:, :2] / a[:, 2:3] - p0, axis=1)  # the flow of a point at infinite depth
        still = np.linalg.norm(p1 - p0, axis=1)
        return (rot >= _FIXED_MIN_ROT_PX) & (still < share * rot)

    def _solve(
        self, p0: np.ndarray, p1: np.ndarray, h: int, moving: bool = False, parallax: float = 0.0
    ) -> tuple[float, float, int, np.ndarray, np.ndarray, PlaneFit | None] | None:
        """Keyframe pair -> (metres or NaN, yaw change rad, road inliers, R, t, plane fit) or None.

        ``moving``: the scene's parallax (``parallax``, work px, :func:`scene_parallax`) is well above the
        stopped threshold; road points that move less than 0.1 work px (or ``road_flow_share`` of it, when
        set) are then burned-in text, bonnet, dashboard reflections or a road user moving with the ego, not
        road, and leave the scale fit (on ccd_000755 they decided the fit, which then swung with a few rows
        of dashboard mask; on ccd_000014 points under 0.1 of the parallax were most of two of its three fits)."""
        assert self._K is not None
        K = self._K
        scene = ~self._road_region(p0[:, 0], p0[:, 1], h)
        if scene.sum() < MIN_MATCHES:
            scene[:] = True
        E, inl = cv2.findEssentialMat(
            p0[scene], p1[scene], K, method=cv2.USAC_ACCURATE, prob=0.999, threshold=self.ransac_px
        )
        if E is None or E.shape != (3, 3):
            return None
        inl_all = (_epipolar_px(E, p0, p1, K) < 2.0 * self.ransac_px).astype(np.uint8).reshape(-1, 1)
        inl_all[scene] = inl.reshape(-1, 1)
        inl = inl_all
        _, R, t, inl2 = cv2.recoverPose(E, p0, p1, K, mask=inl.copy())
        ok = inl2.ravel() > 0
        if ok.sum() < MIN_MATCHES:
            return None
        t = t.ravel()
        dyaw = _rotation_yaw(R.T, self._normal)
        aside = self._off_travel(R, t)
        self._learn_travel(R, t, dyaw)
        if self.keep_pairs:
            self._keep_pair(p0, p1, h, R, t, moving, parallax)
        if aside:  # a car does not move sideways: a degenerate essential matrix, its road scale is none
            return float("nan"), dyaw, 0, R, t, None
        if moving:
            ok = ok & (np.linalg.norm(p1 - p0, axis=1) >= max(0.1, self.road_flow_share * parallax))
        ok_road = ok & self._off_overlay(p0) & ~self._camera_fixed(p0, p1, R)
        road = ok_road & self._road_region(p0[:, 0], p0[:, 1], h)
        if road.sum() < 2 * MIN_ROAD_POINTS:  # a narrow or textureless lane: take the shoulders too
            road = ok_road & self._road_region(p0[:, 0], p0[:, 1], h, width_factor=3.0)
        fit = None
        if road.sum() >= MIN_ROAD_POINTS:
            x0 = cv2.undistortPoints(p0[road].reshape(-1, 1, 2).astype(np.float64), K, None).reshape(-1, 2)
            x0h = np.column_stack([x0, np.ones(len(x0))])
            fit = fit_plane_motion(
                x0h, p1[road].astype(np.float64), K, R, t, self._normal, shift_prior_px=self.road_shift_prior_px
            )
            if fit is not None and fit.normal @ self._down < math.cos(math.radians(15)):
                fit = None
        if fit is None:  # the road gives no scale: the ground under whatever stands beside it, kept aside
            self._ground = self._envelope(p0, p1, ok_road, R, t)
            return float("nan"), dyaw, int(road.sum()), R, t, None
        return fit.sigma * self.camera.height_m, dyaw, fit.inliers, R, t, fit

    def _speed_reading(self, fit: PlaneFit, span: float) -> tuple[float, float]:
        """A keyframe pair's speed (m/s) and its variance from its scale ``fit`` (road plane or ground envelope) over
        ``span`` (s): the fit's own sigma and ``speed_noise_rel`` of the speed."""
        raw = fit.sigma * self.camera.height_m / max(span, 1e-3)
        return raw, (fit.sigma_std * self.camera.height_m / max(span, 1e-3)) ** 2 + (self.speed_noise_rel * raw) ** 2

    def _envelope(
        self, p0: np.ndarray, p1: np.ndarray, ok: np.ndarray, R: np.ndarray, t: np.ndarray
    ) -> PlaneFit | None:
        """The pair's scale from the ground envelope of its static points under the horizon
        (:func:`.road_motion.ground_envelope_scale`; ``ok``: the points that moved with the scene, off the overlays)
        as a :class:`PlaneFit` of the road's current normal, 1-sigma ``ENVELOPE_REL_STD``; None where it gives none.
        The ground's normal is the road's, made square to the camera's direction of travel (the learnt one, else the
        pair's): a car travels level with its road, and the envelope is read along the normal over many depths, so a
        camera pitch 1 deg off moved it 10 % (KITTI odometry seq00: -2 / -1 / +1 / +2 deg: +18 / +8 / -12 / -21 %;
        squared to the travel: -1.9 % each)."""
        assert self._K is not None
        use = ok & (p0[:, 1] > self._horizon_row() + 2.0)
        if use.sum() < 2:
            return None
        x0, x1 = (
            cv2.undistortPoints(p[use].reshape(-1, 1, 2).astype(np.float64), self._K, None).reshape(-1, 2)
            for p in (p0, p1)
        )
        travel = self._travel if self._travel is not None else np.asarray(t, dtype=float).ravel()
        travel = travel / np.linalg.norm(travel)
        down = self._normal - (self._normal @ travel) * travel  # the car travels along the road: level with it
        found = ground_envelope_scale(x0, x1, R, t, down / np.linalg.norm(down), 1.0)
        if found is None:
            return None
        scale, n = found
        return PlaneFit(scale, ENVELOPE_REL_STD * scale, self._normal.copy(), n)

    def _keep_pair(
        self, p0: np.ndarray, p1: np.ndarray, h: int, R: np.ndarray, t: np.ndarray, moving: bool, parallax: float
    ) -> None:
        """Record a solved keyframe pair for :func:`.road_motion.fit_joint_speed` (``keep_pairs``): its work-px points,
        the road candidates among them (road region, moving, off the overlay, not fixed to the camera at
        ``_JOINT_FIXED_SHARE``; no epipolar gate), rotation, translation direction, road normal, travel, span."""
        assert self._K is not None
        ok = self._road_region(p0[:, 0], p0[:, 1], h) & self._off_overlay(p0)
        if moving:
            ok &= np.linalg.norm(p1 - p0, axis=1) >= max(0.1, self.road_flow_share * parallax)
        ok &= ~self._camera_fixed(p0, p1, R, max(self.fixed_flow_share, _JOINT_FIXED_SHARE))
        travel = None if self._travel is None else self._travel.copy()
        self.pairs.append(
            {"t0": self._kf_time, "t1": self._now, "p0": p0.copy(), "p1": p1.copy(), "road": ok, "R": R.copy(),
             "t": t.copy(), "K": self._K.copy(), "normal": self._normal.copy(), "travel": travel}
        )  # fmt: skip

    # ------------------------------------------------------------------ API
    def update(
        self, frame_bgr: np.ndarray, time: float, vehicle_boxes: Sequence[Sequence[float]] | np.ndarray | None = None
    ) -> EgoState:
        """Add one frame (BGR or grey, full resolution) at ``time`` seconds; returns the ego state."""
        grey = frame_bgr if frame_bgr.ndim == 2 else cv2.cvtColor(frame_bgr, cv2.COLOR_BGR2GRAY)  # once for both
        if self._repeat(grey, float(time)) or self._skip(float(time)):
            return self._skipped(float(time))
        self._all.append((self._frame, float(time)))
        self._now = float(time)
        cur = self._prepare(grey)
        h = cur.shape[0]
        boxes = np.zeros((0, 4)) if vehicle_boxes is None else np.asarray(vehicle_boxes, dtype=float).reshape(-1, 4)
        idx = self._frame
        self._frame += 1
        dark = float(cv2.meanStdDev(cur)[1][0, 0]) < DARK_CONTRAST  # (np.std: a float64 copy of the frame)
        pyr = None if dark else cur
        mask = self._static_mask(cur.shape, boxes)
        if self._last_time is None:
            self._last_time = self._kf_time = float(time)
            self._pyr = pyr
            self._refill(cur, mask, keyframe=True)
            self._dt.append(0.0)
            self._dyaw.append(0.0)
            self._dtilt.append((0.0, 0.0))
            state = EgoState(idx, float(time), 0.0, 0.0, 0.0, 0.0, 0.0, True)
            self._states.append(state)
            return state
        dt = max(float(time) - self._last_time, 1e-3)
        self._pairs += 1
        self._kf_frames += 1
        raw: float | None = None
        var = 0.0
        ground_raw: float | None = None
        ground_var = 0.0
        dyaw = 0.0
        dtilt = (0.0, 0.0)
        n_road = 0
        valid = True
        if pyr is None or self._pyr is None or not len(self._p):
            p1 = np.zeros((0, 2), np.float32)
            good = np.zeros(0, bool)
        else:
            p1, good = self._track(self._pyr, pyr)
            ix, iy = np.clip(p1[:, 0].astype(int), 0, cur.shape[1] - 1), np.clip(p1[:, 1].astype(int), 0, h - 1)
            good &= mask[iy, ix] > 0
        self._v = (p1 - self._p)[good] if len(good) else np.zeros((0, 2), np.float32)
        self._p, self._p_kf = p1[good], self._p_kf[good] if len(good) else self._p_kf[:0]
        has_kf = np.all(np.isfinite(self._p_kf), axis=1)
        keyframe = False
        if has_kf.sum() < MIN_MATCHES:
            valid = False
            self._invalid += 1
            keyframe = True
        else:
            q0, q1 = self._p_kf[has_kf], self._p[has_kf]
            parallax = scene_parallax(q0, q1, cur.shape) / self._scale_f  # full-frame px, per cell
            baseline = float(np.median(np.linalg.norm(q1 - q0, axis=1))) / self._scale_f  # per point
            span = float(time) - self._kf_time
            if parallax < self.static_flow_px and span >= self.static_window_s:
                raw, var, keyframe = 0.0, 0.05**2, True  # a positive measurement: the ego is stopped
                self._static += self._kf_frames
                self._frame_motion = None
            elif baseline >= self.min_parallax_px or span >= self.max_keyframe_s:
                keyframe = True
                moving = parallax >= 5.0 * self.static_flow_px
                self._ground = None
                res = self._solve(self._undistort(q0), self._undistort(q1), h, moving, parallax * self._scale_f)
                if res is None:
                    valid = False
                    self._invalid += 1
                    self._unsolved += 1
                else:
                    metres, dyaw, n_road, R, t, fit = res
                    rot = cv2.Rodrigues(R.T)[0].ravel()  # the camera's turn: about x = pitch up, about z = roll
                    dtilt = (float(rot[0]), float(rot[2]))
                    k = max(1, self._kf_frames)
                    if parallax >= 5.0 * self.static_flow_px:
                        self._vote_overlay(q0, q1, cur.shape)
                    if fit is not None and np.isfinite(metres):
                        raw, var = self._speed_reading(fit, span)
                        if fit.sigma_std > self.max_scale_rel_std * fit.sigma:
                            raw = None  # ill-conditioned: no reading (the fit still carries the road tracking)
                        self._normal = _tilted_towards(self._normal, fit.normal, 0.1)
                        rv, _ = cv2.Rodrigues(R)
                        Rk, _ = cv2.Rodrigues(rv / k)
                        self._frame_motion = (Rk, t, fit.sigma / k, fit.normal)
                    else:
                        self._unscaled += 1
                        if self._ground is not None:
                            ground_raw, ground_var = self._speed_reading(self._ground, span)
        self._readings.append((dt, raw, var, ground_raw, ground_var))
        speed = self._filter.step(dt, raw, var)
        self._dt.append(dt)
        self._dyaw.append(dyaw)
        self._dtilt.append(dtilt)
        ds = speed * dt
        mid = self._yaw + 0.5 * dyaw
        self._x += ds * math.cos(mid)
        self._y += ds * math.sin(mid)
        self._yaw += dyaw
        state = EgoState(
            idx, float(time), speed, dyaw / dt, self._x, self._y, self._yaw, valid, len(self._p), n_road, raw
        )
        self._states.append(state)
        self._pyr = pyr
        self._last_time = float(time)
        if pyr is None:
            self._p = self._p_kf = self._v = np.zeros((0, 2), np.float32)
        self._refill(cur, mask, keyframe)
        return state

    def _refill(self, cur: np.ndarray, mask: np.ndarray, keyframe: bool) -> None:
        """Top up the scene and road corners; on a keyframe every point's keyframe position is now."""
        if keyframe:
            self._p_kf = self._p.copy()
            self._kf_time = float(self._last_time or 0.0)
            self._kf_frames = 0
        if self._pyr is None:
            return
        road = self._road_mask(mask)
        in_road = self._road_region(self._p[:, 0], self._p[:, 1], cur.shape[0]) if len(self._p) else np.zeros(0, bool)
        new_road = top_up_corners(cur, road, self._p[in_road], self.road_corners, quality=0.001, min_distance=5)
        pts = np.concatenate([self._p, new_road])
        new = top_up_corners(
            cur, mask, pts, self.corners + self.road_corners, quality=0.01, min_distance=8, coarse=self.coarse_corners
        )
        added = np.concatenate([new_road, new])
        if not len(added):
            return
        nan = np.full_like(added, np.nan)
        self._p = np.concatenate([self._p, added]).astype(np.float32)
        self._p_kf = np.concatenate([self._p_kf, added if keyframe else nan]).astype(np.float32)
        self._v = np.concatenate([self._v, nan]).astype(np.float32)

    def _repeat(self, grey: np.ndarray, time: float) -> bool:
        """Whether the frame shows the last new picture again (:class:`~deepcrashtest.video.repeats.RepeatWatch`) and
        the last measured frame is less than ``static_window_s`` ago: a repeat is not measured, so the next new picture
        is measured over the time it took (a clip re-encoded at a higher frame rate: 10 -> 30 fps repeats a picture for
        0.07 s, 5 -> 30 fps for 0.17 s); a picture held longer is measured (a parked camera's identical frames read
        stopped, as a frozen stretch did before)."""
        repeat = self._repeats.repeats(grey)
        return repeat and self._last_time is not None and time - self._last_time < self.static_window_s

    def _skip(self, time: float) -> bool:
        """Whether the frame at ``time`` comes too soon after the last measured one (``max_rate_hz``)."""
        if self.max_rate_hz is None or self._last_time is None:
            return False
        return time - self._last_time < 0.9 / self.max_rate_hz

    def _skipped(self, time: float) -> EgoState:
        """A frame that is not measured: the last state carried forward at its speed and yaw rate."""
        last = self._states[-1]
        self._all.append((self._frame, time))
        self._frame += 1
        dt = time - last.time
        yaw = last.yaw + last.yaw_rate * dt
        mid = 0.5 * (last.yaw + yaw)
        x, y = last.x + last.speed * dt * math.cos(mid), last.y + last.speed * dt * math.sin(mid)
        return EgoState(self._frame - 1, time, last.speed, last.yaw_rate, x, y, yaw, last.valid)

    def result(self, cut_time: float | None = None) -> EgoMotion:
        """All frames so far as arrays (smoothed speeds, path integrated from them), with warnings
        about static, dark or featureless input. ``cut_time`` (s, the frames' time): the speeds up to
        this time are smoothed from the readings up to it only (e.g. a crash's time: what the crash
        does to the speed afterwards is not carried back before it). Only when two readings or more
        were taken up to the cut: a lone first reading is the filter's start, not a confirmed speed (a
        later reading that disagrees can overturn it), and the readings after the cut are then the
        nearest evidence of the speed before it (ccd_000132: one reading at frame 1, the next 0.9 s
        after its crash; cut anyway, its fidelity IoU fell 0.69 -> 0.59; ccd_000053, three readings
        before its crash: 0.73 -> 0.82. Chosen on these two fidelity clips)."""
        s = self._states
        warnings: list[str] = []
        decided = self._pairs - self._kf_frames  # frames after the last keyframe are still open
        static = self._pairs > 0 and self._static >= 0.9 * max(1, decided)
        if static:
            warnings.append("ego-motion: the camera does not move (static camera?); ego speed set to 0")
        if self._pairs and self._invalid > 0.2 * self._pairs:
            few, unsolved = self._invalid - self._unsolved, self._unsolved
            why = []
            if few:
                why.append(f"{few} had too few trackable static-scene features (dark, blurred or featureless frames)")
            if unsolved:
                why.append(
                    f"{unsolved} gave no consistent camera motion (the tracked points' motion fits no single turn and "
                    "translation: road users or swaying foliage filling the scene, or too little motion to tell)"
                )
            warnings.append(
                f"ego-motion: {self._invalid} of {self._pairs} frame pairs were not measured: {'; '.join(why)}; "
                "speed held over those frames"
            )
        filt = self._filter
        taken = road_taken = filt.taken()
        if self._pairs and not static and taken < MIN_SPEED_READINGS and any(r[3] is not None for r in self._readings):
            filt = self._new_filter()  # too few road readings: the ground envelope's fill the pairs the road left
            for dt_k, raw_k, var_k, ground_k, ground_var_k in self._readings:
                use_ground = raw_k is None and ground_k is not None
                filt.step(dt_k, ground_k if use_ground else raw_k, ground_var_k if use_ground else var_k)
            taken = filt.taken()
            warnings.append(
                f"ego-motion: the road gave {road_taken} speed reading(s) in {self._pairs} frame pairs; the speed "
                f"rests on {taken - road_taken} more from the ground under the scene's standing points (kerbs, walls, "
                "parked cars), less certain than the road's: check it against the video or give the camera "
                "(--camera, --chessboard)"
            )
        if self._pairs and not static and taken < MIN_SPEED_READINGS:
            warnings.append(
                f"ego-motion: the ego's speed rests on {taken} reading(s) in {self._pairs} frame pairs (the road gave "
                "no metric scale: textureless, blurred or hidden): barely measured; it is held between readings "
                "and 0 before the first, so check it against the video or give the camera (--camera, --chessboard)"
            )
        elif self._pairs and self._unscaled > 0.5 * self._pairs and filt is self._filter:
            warnings.append(
                f"ego-motion: the road gave no metric scale in {self._unscaled} of {self._pairs} frame pairs "
                "(road hidden, textureless or dashboard not masked); speeds there are held"
            )
        cut = None
        if cut_time is not None and s:  # state k + 1 is filter step k
            cut = int(np.searchsorted([e.time for e in s], cut_time, side="right")) - 2
            cut = cut if filt.confirmed(cut) else None
        speed = np.r_[0.0, filt.smoothed(cut)] if s else np.zeros(0)
        dt = np.asarray(self._dt)
        dyaw = np.asarray(self._dyaw)
        yaw = np.cumsum(dyaw)
        mid = yaw - 0.5 * dyaw
        ds = speed * dt
        x = np.cumsum(ds * np.cos(mid))
        y = np.cumsum(ds * np.sin(mid))
        measured = EgoMotion(
            frame=np.array([e.frame for e in s], dtype=int),
            t=np.array([e.time for e in s]),
            x=x,
            y=y,
            yaw=yaw,
            speed=speed,
            yaw_rate=dyaw / np.maximum(dt, 1e-3),
            valid=np.array([e.valid for e in s], dtype=bool),
            warnings=warnings,
            static=bool(static),
            tilt=np.cumsum(np.asarray(self._dtilt, dtype=float).reshape(-1, 2), axis=0),
        )
        return _every_frame(measured, self._all) if len(self._all) > len(s) else measured


def rescaled(ego: EgoMotion, length: float = 1.0, focal_ratio: float = 1.0) -> EgoMotion:
    """Image ego-motion measured with an assumed camera, under a calibrated one.

    ``length``: the metric scale factor (the road plane's scale goes with focal length x camera height:
    calibrated over assumed); speeds and path lengths are multiplied by it. ``focal_ratio``: the assumed
    over the calibrated focal length (px / px). A rotation is seen as an image shift of about focal x
    angle, so the yaw (and the camera's pitch, ``tilt[:, 0]``; roll about the optical axis does not
    depend on it) measured with the assumed focal length is multiplied by this ratio, and the path is
    integrated again along the corrected headings (each step keeps its length, its heading the middle
    of the frame pair's yaw). Measured on KITTI odometry seq00 frames 0-159 (a -85.8 deg turn) with
    the focal length assumed at 0.5x / 2x the calibrated one (height scaled so that focal x height is
    right): heading -154.6 / -51.8 deg, -77.3 / -103.6 deg after this rescaling (``focal_ratio`` 2 / 0.5;
    the essential matrix of a wrongly assumed focal length is not an exact rescaling of the rotation).
    ``focal_ratio == 1``: positions and speeds are only multiplied by ``length``."""
    if focal_ratio == 1.0 or len(ego.t) < 2:
        return replace(ego, x=ego.x * length, y=ego.y * length, speed=ego.speed * length)
    dyaw = np.diff(ego.yaw) * focal_ratio
    yaw = ego.yaw[0] + np.r_[0.0, np.cumsum(dyaw)]
    step = np.hypot(np.diff(ego.x), np.diff(ego.y)) * length
    x, y = path_along(ego.x[0] * length, ego.y[0] * length, step, yaw[:-1] + 0.5 * dyaw)
    tilt = None if ego.tilt is None else ego.tilt * np.array([focal_ratio, 1.0])
    return replace(ego, x=x, y=y, yaw=yaw, speed=ego.speed * length, yaw_rate=ego.yaw_rate * focal_ratio, tilt=tilt)


def path_along(x0: float, y0: float, step: np.ndarray, heading: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """World x, y (m) of a path from (``x0``, ``y0``) whose k-th step is ``step[k]`` metres long at ``heading[k]``
    (rad, world frame): one more point than steps."""
    x = x0 + np.r_[0.0, np.cumsum(step * np.cos(heading))]
    y = y0 + np.r_[0.0, np.cumsum(step * np.sin(heading))]
    return x, y


def _every_frame(m: EgoMotion, every: list[tuple[int, float]]) -> EgoMotion:
    """The measured frames' track ``m`` at every (frame, time) of ``every``: positions, yaw and speed
    interpolated linearly in time (after the last measured frame: extrapolated at its speed and yaw
    rate); a frame's yaw rate and validity are those of the measured pair it lies in."""
    frame = np.array([f for f, _ in every], dtype=int)
    t = np.array([tt for _, tt in every])
    k = np.minimum(np.searchsorted(m.t, t, side="left"), len(m.t) - 1)  # the measured frame at or after
    after = np.maximum(t - m.t[-1], 0.0)
    yaw = np.interp(t, m.t, m.yaw) + m.yaw_rate[-1] * after
    mid = m.yaw[-1] + 0.5 * m.yaw_rate[-1] * after
    x = np.interp(t, m.t, m.x) + m.speed[-1] * after * np.cos(mid)
    y = np.interp(t, m.t, m.y) + m.speed[-1] * after * np.sin(mid)
    speed = np.interp(t, m.t, m.speed)
    tilt = None if m.tilt is None else np.column_stack([np.interp(t, m.t, m.tilt[:, j]) for j in range(2)])
    return EgoMotion(frame, t, x, y, yaw, speed, m.yaw_rate[k], m.valid[k], m.warnings, m.static, tilt=tilt)


def scene_parallax(p0: np.ndarray, p1: np.ndarray, shape: tuple[int, int], grid: tuple[int, int] = (4, 6)) -> float:
    """Median displacement (px) of tracked points, one vote per image cell (``grid`` rows x columns)
    holding at least 3 points: a median over the points alone is decided by wherever the corners
    crowd. On dashcam clips the crowd is a burned-in date/speed overlay, whose sharp glyphs keep
    their corners while the moving scene's corners are lost to blur and the forward-backward check:
    ccd_000080 and ccd_000882 (10 fps, driving at ~50 km/h) had a median point parallax of 0 px
    and read "stopped". Falls back to the median over points when fewer than 3 cells vote."""
    d = np.linalg.norm(p1 - p0, axis=1)
    if not len(d):
        return 0.0
    h, w = shape[:2]
    rows, cols = grid
    iy = np.clip((p1[:, 1] * rows / h).astype(int), 0, rows - 1)
    ix = np.clip((p1[:, 0] * cols / w).astype(int), 0, cols - 1)
    cell = iy * cols + ix
    votes = _group_medians(cell, d, min_count=3)
    return float(np.median(votes)) if len(votes) >= 3 else float(np.median(d))


def _group_medians(group: np.ndarray, values: np.ndarray, min_count: int) -> list[float]:
    """``np.median`` of ``values`` per group label (ascending labels) holding at least ``min_count``
    values, from one sort instead of a mask and a median per group (the same numbers)."""
    order = np.lexsort((values, group))
    g, v = group[order], values[order]
    starts = np.flatnonzero(np.r_[True, g[1:] != g[:-1]])
    counts = np.diff(np.r_[starts, len(g)])
    keep = counts >= min_count
    starts, counts = starts[keep], counts[keep]
    lo, hi = v[starts + (counts - 1) // 2], v[starts + counts // 2]
    return [float(x) for x in np.where(counts % 2 == 1, lo, (lo + hi) / v.dtype.type(2))]


#: Rotation flow (work px) from which :meth:`EgoMotionEstimator._camera_fixed` tells a still point from scene
#: (6x the 0.5 px forward-backward tracking tolerance). Chosen on KITTI odometry seq00: at 2 px two of its 13,005
#: road points with that much rotation flow (2.4 px, moving 0.21-0.24 px) counted as fixed and moved its yaw drift
#: 0.349 -> 0.475 deg/100 m; from 3 px none does. ccd_000014's dashboard points see 5-15 px.
_FIXED_MIN_ROT_PX = 3.0

#: Margin (px) around the road points of the region :meth:`EgoMotionEstimator._track` warps: an 11-px LK
#: window at pyramid level 2 reaches 4 x 6 = 24 px, plus the Scharr kernel and the pyramid's border rows.
_ROAD_CROP_MARGIN_PX = 48


def _crop_box(pts: np.ndarray, w: int, h: int, margin: int, align: int) -> tuple[int, int, int, int]:
    """(x0, y0, x1, y1) px: the box around ``pts`` (N, 2) widened by ``margin``, its top-left corner on a
    multiple of ``align``, clipped to a ``w`` x ``h`` image."""
    x0 = min(max(0, int(np.floor((float(pts[:, 0].min()) - margin) / align)) * align), (w - align) // align * align)
    y0 = min(max(0, int(np.floor((float(pts[:, 1].min()) - margin) / align)) * align), (h - align) // align * align)
    x1 = int(np.ceil(float(pts[:, 0].max()) + margin))
    y1 = int(np.ceil(float(pts[:, 1].max()) + margin))
    # points all beyond an edge (the road warped off the frame) still give a box inside the image
    return x0, y0, min(w, max(x1, x0 + align)), min(h, max(y1, y0 + align))


def _tilted_towards(n_ref: np.ndarray, n_new: np.ndarray, rate: float) -> np.ndarray:
    """Move the reference road normal a fraction ``rate`` towards a new estimate (unit vector)."""
    n = (1.0 - rate) * n_ref + rate * n_new
    return n / np.linalg.norm(n)
