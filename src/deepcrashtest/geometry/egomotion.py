"""Metric ego-motion (speed, yaw rate, path) from a monocular video, one frame at a time.

Method, per consecutive frame pair:

1. Corners on the static scene (vehicle boxes, the dashboard/bonnet rows and the sky are masked
   out) tracked with pyramidal Lucas-Kanade, kept only where the backward track returns
   within 1 px.
2. Rotation and translation direction from the essential matrix (RANSAC, ``cv2.findEssentialMat``
   + ``cv2.recoverPose``).
3. Metric scale from the road: corners in the road region in front of the car are triangulated
   with the unit-length translation, a plane is fitted to them (RANSAC, normal within 12 deg of
   the calibrated down vector) and its distance to the camera is set equal to the camera height.
4. Speeds are filtered with a robust running median; the yaw (about the road normal) and the
   forward/leftward displacement are integrated into a planar path.

Frames: the path is that of the camera, in the world frame of ``deepcrashtest.scenario`` (origin
at the camera's ground point at the first frame, x forward, y left, metres; yaw radians CCW).
A camera that does not move (median flow below ``static_flow_px``) gives speed 0 and a warning;
frames with too few corners (darkness, blur, featureless road) keep the last speed and are
flagged ``valid=False``.
"""

from __future__ import annotations

import math
from collections import deque
from collections.abc import Sequence
from dataclasses import dataclass, field

import cv2
import numpy as np

from deepcrashtest.scenario import Camera

#: Fewer tracked static-scene corners than this and a frame pair is not trusted.
MIN_MATCHES = 40
#: Fewer road points than this and the pair's scale is not measured (the filtered speed is kept).
MIN_ROAD_POINTS = 12
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
        return cls(frame, t, xy[:, 0], xy[:, 1], yaw, speed, rate, np.ones(len(t), bool))


def _down_vector(pitch_rad: float, roll_rad: float = 0.0) -> np.ndarray:
    """World 'down' expressed in the camera frame (x right, y down, z forward) for a pitched camera."""
    down = np.array([0.0, math.cos(pitch_rad), math.sin(pitch_rad)])
    c, s = math.cos(roll_rad), math.sin(roll_rad)
    rz = np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])
    return rz @ down


def fit_road_plane(
    points: np.ndarray, down: np.ndarray, max_tilt_deg: float = 12.0, iters: int = 150, seed: int = 0
) -> tuple[np.ndarray, float, np.ndarray] | None:
    """RANSAC plane ``n . X = d`` through (N, 3) camera-frame points with ``n`` near ``down``.

    Returns (unit normal pointing down, distance d > 0 in the points' units, inlier mask) or None.
    """
    pts = np.asarray(points, dtype=float)
    if len(pts) < 3:
        return None
    rng = np.random.default_rng(seed)
    cos_max = math.cos(math.radians(max_tilt_deg))
    heights = pts @ down
    scale = float(np.median(np.abs(heights)))
    if not np.isfinite(scale) or scale <= 0:
        return None
    tol = 0.03 * scale
    best: tuple[int, np.ndarray, float] | None = None
    for _ in range(iters):
        a, b, c = pts[rng.choice(len(pts), 3, replace=False)]
        n = np.cross(b - a, c - a)
        norm = np.linalg.norm(n)
        if norm < 1e-12:
            continue
        n /= norm
        if n @ down < 0:
            n = -n
        if n @ down < cos_max:
            continue
        d = float(n @ a)
        if d <= 0:
            continue
        inl = np.abs(pts @ n - d) < tol
        cnt = int(inl.sum())
        if best is None or cnt > best[0]:
            best = (cnt, n, d)
    if best is None or best[0] < 3:
        return None
    _, n, d = best
    inl = np.abs(pts @ n - d) < tol
    # least-squares refinement on the inliers
    sel = pts[inl]
    centroid = sel.mean(axis=0)
    _, _, vt = np.linalg.svd(sel - centroid)
    n2 = vt[2] if vt[2] @ down > 0 else -vt[2]
    if n2 @ down >= cos_max:
        n, d = n2, float(n2 @ centroid)
        inl = np.abs(pts @ n - d) < tol
    return n, d, inl


def _rotation_yaw(R_cam: np.ndarray, down: np.ndarray) -> float:
    """Yaw (rad, CCW seen from above = left turn positive) of a camera rotation about the road normal."""
    rvec, _ = cv2.Rodrigues(R_cam)
    return float(-(rvec.ravel() @ down))


class EgoMotionEstimator:
    """Streaming monocular ego-motion: call :meth:`update` once per frame, then :meth:`result`.

    ``camera`` gives intrinsics (pixels of the full frame), height (m) and pitch/roll (rad).
    ``mask_bottom_rows``: rows at the bottom of the frame to ignore (dashboard/bonnet), full-frame px.
    ``max_width``: frames wider than this are downscaled first (speed; the intrinsics follow).
    """

    def __init__(
        self,
        camera: Camera,
        mask_bottom_rows: int = 0,
        max_width: int = 1280,
        horizon_v: float | None = None,
        static_flow_px: float = 0.25,
        smooth_window: int = 5,
        road_half_width_m: float = 3.0,
        scale_method: str = "homography",
        seed: int = 0,
    ) -> None:
        self.camera = camera
        self.road_half_width_m = road_half_width_m
        self.scale_method = scale_method
        self.mask_bottom_rows = int(mask_bottom_rows)
        self.max_width = int(max_width)
        self.horizon_v = horizon_v
        self.static_flow_px = static_flow_px
        self.seed = seed
        self._prev: np.ndarray | None = None
        self._scale_f = 1.0
        self._K: np.ndarray | None = None
        self._down = _down_vector(camera.pitch_rad, camera.roll_rad)
        self._speeds: deque[float] = deque(maxlen=max(1, smooth_window))
        self._states: list[EgoState] = []
        self._x = self._y = self._yaw = 0.0
        self._last_speed = 0.0
        self._last_time: float | None = None
        self._frame = 0
        self._invalid = 0
        self._static = 0
        self._pairs = 0
        self._unscaled = 0

    # ------------------------------------------------------------------ helpers
    def _prepare(self, frame: np.ndarray) -> np.ndarray:
        grey = frame if frame.ndim == 2 else cv2.cvtColor(frame, cv2.COLOR_BGR2GRAY)
        h, w = grey.shape[:2]
        if self._K is None:
            self._scale_f = min(1.0, self.max_width / float(w))
            K = self.camera.matrix().copy()
            K[:2] *= self._scale_f
            self._K = K
            self._size = (w, h)
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
        return mask

    def _horizon_row(self) -> float:
        assert self._K is not None
        if self.horizon_v is not None:
            return self.horizon_v * self._scale_f
        return float(self._K[1, 2] - self._K[1, 1] * math.tan(self.camera.pitch_rad))

    def _track(self, prev: np.ndarray, cur: np.ndarray, mask: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        h, w = prev.shape
        pts = cv2.goodFeaturesToTrack(prev, maxCorners=1500, qualityLevel=0.005, minDistance=7, mask=mask)
        road = mask.copy()
        road[: int(min(h - 1, max(0, self._horizon_row() + 0.04 * h)))] = 0
        pts_road = cv2.goodFeaturesToTrack(prev, maxCorners=1200, qualityLevel=0.0001, minDistance=5, mask=road)
        all_pts = [p for p in (pts, pts_road) if p is not None]
        if not all_pts:
            return np.zeros((0, 2), np.float32), np.zeros((0, 2), np.float32)
        p0 = np.concatenate(all_pts).astype(np.float32)
        lk = {"winSize": (21, 21), "maxLevel": 3}
        p1, st, _ = cv2.calcOpticalFlowPyrLK(prev, cur, p0, None, **lk)  # type: ignore[call-overload]
        p0r, st2, _ = cv2.calcOpticalFlowPyrLK(cur, prev, p1, None, **lk)  # type: ignore[call-overload]
        good = (st.ravel() == 1) & (st2.ravel() == 1) & (np.linalg.norm(p0 - p0r, axis=-1).ravel() < 1.0)
        return p0.reshape(-1, 2)[good], p1.reshape(-1, 2)[good]

    def _pair_motion(self, p0: np.ndarray, p1: np.ndarray, shape: tuple[int, int]) -> tuple[float, float, int] | None:
        """(metres travelled between the frames, yaw change rad, road points) or None when unmeasurable."""
        assert self._K is not None
        K = self._K
        E, inl = cv2.findEssentialMat(p0, p1, K, method=cv2.USAC_MAGSAC, prob=0.999, threshold=0.7)
        if E is None or E.shape != (3, 3):
            return None
        _, R, t, inl2 = cv2.recoverPose(E, p0, p1, K, mask=inl.copy())
        ok = inl2.ravel() > 0
        if ok.sum() < MIN_MATCHES:
            return None
        dyaw = _rotation_yaw(R.T, self._down)
        # road points: in the road region below the horizon, central part of the image
        h, w = shape
        hv = self._horizon_row()
        u, v = p0[:, 0], p0[:, 1]
        below = np.maximum(v - hv, 1e-6)
        lateral = np.abs(u - K[0, 2]) / K[0, 0] * K[1, 1] * self.camera.height_m / below  # metres, level road
        ahead = K[1, 1] * self.camera.height_m / below
        road = ok & (v > hv + 0.04 * h) & (lateral < self.road_half_width_m) & (ahead < 30.0)
        if road.sum() < MIN_ROAD_POINTS:
            return float("nan"), dyaw, int(road.sum())
        if self.scale_method == "homography":
            return self._homography_scale(p0[road], p1[road], R, t.ravel(), dyaw)
        P0 = np.hstack([np.eye(3), np.zeros((3, 1))])
        P1 = np.hstack([R, t.reshape(3, 1)])
        n0 = cv2.undistortPoints(p0[road].reshape(-1, 1, 2), K, None).reshape(-1, 2)
        n1 = cv2.undistortPoints(p1[road].reshape(-1, 1, 2), K, None).reshape(-1, 2)
        X = cv2.triangulatePoints(P0, P1, n0.T, n1.T)
        X = (X[:3] / X[3]).T
        front = (X[:, 2] > 0) & np.all(np.isfinite(X), axis=1)
        X = X[front]
        if len(X) < MIN_ROAD_POINTS:
            return float("nan"), dyaw, len(X)
        fit = fit_road_plane(X, self._down, seed=self.seed + self._frame)
        if fit is None or fit[2].sum() < MIN_ROAD_POINTS:
            return float("nan"), dyaw, len(X)
        _, d, plane_inl = fit
        metres = self.camera.height_m / d  # |t| = 1 in triangulation units
        return metres, dyaw, int(plane_inl.sum())

    def _homography_scale(
        self, q0: np.ndarray, q1: np.ndarray, R: np.ndarray, t: np.ndarray, dyaw: float
    ) -> tuple[float, float, int]:
        """Scale from the road-plane homography: ``K^-1 H K = R + t n^T / d`` (|t| = 1, R known).

        ``H`` is fitted to the road correspondences (RANSAC); ``R + t n^T / d`` minus the rotation is
        rank one with singular value 1/d, so the metres travelled are ``height / d``. The plane
        normal (the right singular vector) must point within 15 deg of the calibrated down vector.
        Returns (metres, yaw change, homography inliers).
        """
        assert self._K is not None
        K = self._K
        H, inl = cv2.findHomography(q0, q1, cv2.RANSAC, 1.0)
        if H is None or inl is None or int(inl.sum()) < MIN_ROAD_POINTS:
            return float("nan"), dyaw, 0
        Hn = np.linalg.inv(K) @ H @ K
        Hn /= np.linalg.svd(Hn, compute_uv=False)[1]
        if np.linalg.det(Hn) < 0:
            Hn = -Hn
        u, sv, vt = np.linalg.svd(Hn - R)
        inv_d = float(sv[0])
        normal = vt[0] if vt[0] @ self._down > 0 else -vt[0]
        if not np.isfinite(inv_d) or inv_d <= 0 or normal @ self._down < math.cos(math.radians(15)):
            return float("nan"), dyaw, int(inl.sum())
        return self.camera.height_m * inv_d, dyaw, int(inl.sum())

    # ------------------------------------------------------------------ API
    def update(
        self, frame_bgr: np.ndarray, time: float, vehicle_boxes: Sequence[Sequence[float]] | np.ndarray | None = None
    ) -> EgoState:
        """Add one frame (BGR or grey, full resolution) at ``time`` seconds; returns the ego state."""
        cur = self._prepare(frame_bgr)
        boxes = np.zeros((0, 4)) if vehicle_boxes is None else np.asarray(vehicle_boxes, dtype=float).reshape(-1, 4)
        idx = self._frame
        self._frame += 1
        if self._prev is None or self._last_time is None:
            self._prev = cur
            self._last_time = float(time)
            state = EgoState(idx, float(time), 0.0, 0.0, 0.0, 0.0, 0.0, True)
            self._states.append(state)
            return state
        dt = float(time) - self._last_time
        if dt <= 0:
            dt = 1e-3
        self._pairs += 1
        if float(cur.std()) < DARK_CONTRAST:
            p0 = p1 = np.zeros((0, 2), np.float32)  # too dark / flat to measure anything
        else:
            p0, p1 = self._track(self._prev, cur, self._static_mask(cur.shape, boxes))
        valid = True
        raw: float | None = None
        dyaw = 0.0
        n_road = 0
        if len(p0) < MIN_MATCHES:
            valid = False
            self._invalid += 1
        elif float(np.median(np.linalg.norm(p1 - p0, axis=1))) < self.static_flow_px:
            raw = 0.0
            self._static += 1
        else:
            res = self._pair_motion(p0, p1, cur.shape)
            if res is None:
                valid = False
                self._invalid += 1
            else:
                metres, dyaw, n_road = res
                if np.isfinite(metres):
                    raw = metres / dt
                else:
                    self._unscaled += 1
        if raw is not None:
            self._speeds.append(raw)
        speed = float(np.median(self._speeds)) if self._speeds else self._last_speed
        self._last_speed = speed
        ds = speed * dt
        mid = self._yaw + 0.5 * dyaw
        self._x += ds * math.cos(mid)
        self._y += ds * math.sin(mid)
        self._yaw += dyaw
        state = EgoState(idx, float(time), speed, dyaw / dt, self._x, self._y, self._yaw, valid, len(p0), n_road, raw)
        self._states.append(state)
        self._prev = cur
        self._last_time = float(time)
        return state

    def result(self) -> EgoMotion:
        """All states so far as arrays, with warnings about static, dark or featureless input."""
        s = self._states
        warnings: list[str] = []
        static = self._pairs > 0 and self._static >= 0.9 * self._pairs
        if static:
            warnings.append("ego-motion: the camera does not move (static camera?); ego speed set to 0")
        if self._pairs and self._invalid > 0.2 * self._pairs:
            warnings.append(
                f"ego-motion: {self._invalid} of {self._pairs} frame pairs had too few trackable static-scene "
                "features (dark, blurred or featureless frames); speed held over those frames"
            )
        if self._pairs and self._unscaled > 0.5 * self._pairs:
            warnings.append(
                f"ego-motion: the road gave no metric scale in {self._unscaled} of {self._pairs} frame pairs "
                "(road hidden, textureless or dashboard not masked); speeds there are held"
            )
        return EgoMotion(
            frame=np.array([e.frame for e in s], dtype=int),
            t=np.array([e.time for e in s]),
            x=np.array([e.x for e in s]),
            y=np.array([e.y for e in s]),
            yaw=np.array([e.yaw for e in s]),
            speed=np.array([e.speed for e in s]),
            yaw_rate=np.array([e.yaw_rate for e in s]),
            valid=np.array([e.valid for e in s], dtype=bool),
            warnings=warnings,
            static=bool(static),
        )
