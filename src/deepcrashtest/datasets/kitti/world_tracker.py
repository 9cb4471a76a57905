"""A multi-object tracker in the world frame (bird's-eye view), for 3D detections of vehicles.

Detections come in already placed in the world frame (x forward, y left at the ego's start; metres),
i.e. the ego motion is compensated before tracking, so a parked car stands still and a constant-
velocity model holds for every car whatever the ego does. Per frame:

1. every track's Kalman filter predicts its centre one step ahead (constant velocity, white-noise
   acceleration ``accel_std``);
2. detections below ``min_score`` are dropped; the rest are assigned to tracks by the Hungarian
   algorithm (``scipy.optimize.linear_sum_assignment``) on the ground-plane distance between the
   predicted centre and the detection, pairs farther than ``gate_m`` forbidden; confident
   detections (score >= ``birth_score``) are assigned first, the weaker ones then only to the
   tracks still free (they extend tracks but never start one);
3. matched tracks are corrected; unmatched confident detections start tentative tracks; unmatched
   tracks age and are deleted after ``max_age`` frames without a detection.

Track lifecycle: the one of every tracker here, :class:`~deepcrashtest.perception.lifecycle.TrackCore`
(*tentative* until ``min_hits`` detections, then *confirmed*; *deleted* after more than ``max_age``
misses in a row, a tentative track on its first miss; ids given at birth, since tentative tracks
are reported during the warm-up). Output: confirmed tracks that were detected in this
frame or missed at most ``max_coast_output`` frames, plus, during the first ``min_hits`` frames of
a sequence, tentative ones (so objects present at the start are not lost to the warm-up).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from scipy.optimize import linear_sum_assignment

from deepcrashtest.perception.lifecycle import TrackBase, TrackCore


@dataclass(frozen=True)
class WorldTrackerConfig:
    """Tracker settings. Distances metres, times seconds; scores in the detector's own units."""

    dt: float = 0.1
    min_score: float = 0.0
    birth_score: float = 0.0
    gate_m: float = 2.0
    min_hits: int = 2
    max_age: int = 3
    max_coast_output: int = 0
    accel_std: float = 3.0
    meas_std_m: float = 0.3
    init_speed_std: float = 10.0


@dataclass(frozen=True)
class WorldDetections:
    """Detections of one frame in the world frame: centres (n, 2) m, bottom heights (n,) m,
    sizes (n, 3) l w h m, yaws (n,) rad, scores (n,)."""

    xy: np.ndarray
    z: np.ndarray
    size: np.ndarray
    yaw: np.ndarray
    score: np.ndarray

    def __len__(self) -> int:
        return len(self.xy)


@dataclass(frozen=True)
class TrackOutput:
    """One reported track in one frame: world box (x, y, z, l, w, h, yaw) and velocity (m/s)."""

    track_id: int
    box: np.ndarray
    velocity: np.ndarray
    score: float
    detected: bool


@dataclass(frozen=True)
class TrackHistory:
    """A track's filtered boxes (n, 7) in the n frames where a detection updated it, with that
    detection's score and index in its frame's :class:`WorldDetections` (-1: none, interpolated)."""

    track_id: int
    frames: np.ndarray
    boxes: np.ndarray
    scores: np.ndarray
    detections: np.ndarray


@dataclass
class _Track(TrackBase):
    x: np.ndarray = field(default_factory=lambda: np.zeros(4))  # state (x, y, vx, vy)
    P: np.ndarray = field(default_factory=lambda: np.eye(4))
    z: float = 0.0
    size: np.ndarray = field(default_factory=lambda: np.zeros(3))
    yaw: float = 0.0
    score: float = 0.0
    detection: int = -1
    frames: list[int] = field(default_factory=list)
    detections: list[int] = field(default_factory=list)
    boxes: list[np.ndarray] = field(default_factory=list)
    detected: list[bool] = field(default_factory=list)
    scores: list[float] = field(default_factory=list)

    def box(self) -> np.ndarray:
        return np.array([self.x[0], self.x[1], self.z, *self.size, self.yaw])

    def record(self, frame: int) -> None:
        """Remember this frame's estimate (for the offline pass)."""
        self.frames.append(frame)
        self.boxes.append(self.box())
        self.detected.append(self.misses == 0)
        self.detections.append(self.detection if self.misses == 0 else -1)
        self.scores.append(self.score if self.misses == 0 else np.nan)


class WorldTracker:
    """Constant-velocity Kalman tracker with Hungarian association on ground-plane distance."""

    def __init__(self, config: WorldTrackerConfig | None = None):
        self.config = config or WorldTrackerConfig()
        c = self.config
        self._F = np.eye(4)
        self._F[0, 2] = self._F[1, 3] = c.dt
        g = np.array([[c.dt**2 / 2, 0], [0, c.dt**2 / 2], [c.dt, 0], [0, c.dt]])
        self._Q = g @ g.T * c.accel_std**2
        self._H = np.hstack([np.eye(2), np.zeros((2, 2))])
        self._R = np.eye(2) * c.meas_std_m**2
        self._core: TrackCore[_Track] = TrackCore(min_hits=c.min_hits, max_misses=c.max_age, ids_at_birth=True)
        self._finished: list[_Track] = []
        self._frame = 0

    @property
    def _tracks(self) -> list[_Track]:
        return self._core.tracks

    def step(self, dets: WorldDetections) -> list[TrackOutput]:
        """Advance one frame with this frame's detections; return the tracks to report."""
        c = self.config
        keep = dets.score >= c.min_score
        index = np.nonzero(keep)[0]
        xy, z, size, yaw, score = dets.xy[keep], dets.z[keep], dets.size[keep], dets.yaw[keep], dets.score[keep]
        for t in self._tracks:
            t.x = self._F @ t.x
            t.P = self._F @ t.P @ self._F.T + self._Q
        strong = np.nonzero(score >= c.birth_score)[0]
        weak = np.nonzero(score < c.birth_score)[0]
        pairs, lone_tracks, lone_strong = self._associate(list(range(len(self._tracks))), xy, strong)
        more, lone_tracks, _ = self._associate(lone_tracks, xy, weak)
        for ti, di in pairs + more:
            t = self._tracks[ti]
            self._correct(t, xy[di])
            t.z, t.size, t.score = float(z[di]), size[di].astype(float), float(score[di])
            t.yaw = _align_yaw(float(yaw[di]), t.yaw)
            t.detection = int(index[di])
            self._core.hit(t)
        for t in [self._tracks[ti] for ti in lone_tracks]:
            self._core.miss(t)
        for di in lone_strong:
            t = self._core.spawn(self._new_track(xy[di], float(z[di]), size[di], float(yaw[di]), float(score[di])))
            t.detection = int(index[di])
        for t in self._tracks:
            t.record(self._frame)
        self._finished += self._core.prune()
        out = [self._output(t) for t in self._tracks if self._reported(t)]
        self._frame += 1
        return out

    def _associate(
        self, tracks: list[int], xy: np.ndarray, dets: np.ndarray
    ) -> tuple[list[tuple[int, int]], list[int], list[int]]:
        """Hungarian assignment of ``tracks`` (indices) to detections ``dets`` (indices into ``xy``)."""
        if not tracks or len(dets) == 0:
            return [], list(tracks), [int(d) for d in dets]
        pred = np.array([self._tracks[i].x[:2] for i in tracks])
        pts = xy[dets]
        dist = np.hypot(pred[:, None, 0] - pts[None, :, 0], pred[:, None, 1] - pts[None, :, 1])
        gate = self.config.gate_m
        rows, cols = linear_sum_assignment(np.where(dist <= gate, dist, 1e6))
        ok = dist[rows, cols] <= gate
        pairs = [(tracks[r], int(dets[c])) for r, c in zip(rows[ok], cols[ok], strict=True)]
        used_t = {p[0] for p in pairs}
        used_d = {p[1] for p in pairs}
        return pairs, [i for i in tracks if i not in used_t], [int(d) for d in dets if int(d) not in used_d]

    def _correct(self, t: _Track, meas: np.ndarray) -> None:
        S = self._H @ t.P @ self._H.T + self._R
        K = t.P @ self._H.T @ np.linalg.inv(S)
        t.x = t.x + K @ (meas - self._H @ t.x)
        t.P = (np.eye(4) - K @ self._H) @ t.P

    def _new_track(self, xy: np.ndarray, z: float, size: np.ndarray, yaw: float, score: float) -> _Track:
        c = self.config
        P = np.diag([c.meas_std_m**2, c.meas_std_m**2, c.init_speed_std**2, c.init_speed_std**2])
        return _Track(
            x=np.array([xy[0], xy[1], 0.0, 0.0]), P=P, z=z, size=np.asarray(size, dtype=float), yaw=yaw, score=score
        )

    def _reported(self, t: _Track) -> bool:
        if t.misses > self.config.max_coast_output:
            return False
        return t.confirmed or self._frame < self.config.min_hits

    def _output(self, t: _Track) -> TrackOutput:
        return TrackOutput(t.track_id, t.box(), t.x[2:].copy(), t.score, t.misses == 0)

    def histories(self) -> list[TrackHistory]:
        """Every track seen so far (deleted or alive) with its estimates in the frames it was detected."""
        out = []
        for t in sorted(self._finished + self._tracks, key=lambda t: t.track_id):
            keep = np.array(t.detected, bool)
            if keep.any():
                out.append(
                    TrackHistory(
                        track_id=t.track_id,
                        frames=np.array(t.frames, int)[keep],
                        boxes=np.array(t.boxes, float)[keep],
                        scores=np.array(t.scores, float)[keep],
                        detections=np.array(t.detections, int)[keep],
                    )
                )
        return out


def _align_yaw(new: float, old: float) -> float:
    """The detection's yaw, flipped by pi when that brings it within pi/2 of the track's yaw
    (box detectors confuse front and back)."""
    d = (new - old + np.pi) % (2 * np.pi) - np.pi
    if abs(d) > np.pi / 2:
        new += np.pi
    return float((new + np.pi) % (2 * np.pi) - np.pi)
