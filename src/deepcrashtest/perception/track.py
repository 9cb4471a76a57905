"""Image-plane multi-object tracking of road users: detect (every N frames), associate, carry boxes.

Per frame:

1. every live track's box is carried from the previous frame by LK optical flow inside the box
   (:mod:`deepcrashtest.perception.flow`), or by its constant velocity when the flow fails;
2. on detection frames (every ``detect_every``-th), riders are joined to their two-wheelers and
   vehicle occupants dropped (:func:`~deepcrashtest.perception.roadusers.road_users`); detections are
   assigned to tracks by the Hungarian method on 1 - IoU (:mod:`deepcrashtest.perception.lifecycle`);
   a matched track takes the detected box; unmatched detections scoring >= ``new_track_score`` start new tracks;
3. tracks that left the image are deleted; confirmed tracks are reported as ``detected`` (box
   from this frame's detection) or ``predicted`` (carried). When a track is confirmed, its boxes of
   the frames while it was tentative are reported too (``FrameTracks.backfill``), so an object is
   not lost for the ``min_hits - 1`` frames the lifecycle needs to trust it.

Pixels are optional: :meth:`BoxTracker.update_boxes` takes a frame's detections (a detector's, or
boxes read from a file) and, when no image comes with them, carries boxes by their constant image
velocity instead of optical flow; :func:`track_boxes` runs a whole sequence of boxes that way. Where the
camera's own rotation between frames is known (a pose log:
:func:`~deepcrashtest.geometry.frames.rotation_homographies`), ``motion`` moves those boxes by it first, and
their velocity is the road user's own image motion (camera-motion compensation, as BoT-SORT's; without pixels a
turning ego otherwise leaves the boxes behind between detections).

``iter_tracks`` yields one :class:`FrameTracks` per frame, so later stages can share one decoding
pass; ``track_video`` collects everything into the ``tracks.csv`` DataFrame.
"""

from __future__ import annotations

import itertools
import math
from collections.abc import Callable, Iterable, Iterator, Sequence
from dataclasses import dataclass, field, replace
from typing import TYPE_CHECKING

import numpy as np

from deepcrashtest.perception.boxes import iou_matrix
from deepcrashtest.perception.detections import Detections, Detector
from deepcrashtest.perception.flow import BoxFlow, GreyFrame
from deepcrashtest.perception.lifecycle import (
    Assignment,
    StepResult,
    TrackBase,
    TrackCore,
    TrackState,
    assign,
)
from deepcrashtest.perception.roadusers import TWO_WHEELERS, road_users, track_category
from deepcrashtest.video.source import Frame, VideoSource

if TYPE_CHECKING:  # pandas is needed at the end of a pass only (the tables)
    import pandas as pd

__all__ = [
    "TRACK_COLUMNS",
    "Assignment",
    "BoxTracker",
    "FrameTracks",
    "StepResult",
    "TrackBase",
    "TrackCore",
    "TrackState",
    "TrackedBox",
    "assign",
    "iter_tracks",
    "detect_ahead",
    "track_detected",
    "track_boxes",
    "track_video",
    "tracks_dataframe",
]

_NO_IMAGE = np.zeros((0, 0, 3), np.uint8)
TRACK_COLUMNS = ["frame", "time", "track_id", "category", "x1", "y1", "x2", "y2", "score", "state"]
#: A track stays a two-wheeler for good once seen as one in this many detections: a walker is joined with a bicycle
#: box beside it now and then (a parked bicycle, a false box), and one such detection at a walker's first frame made
#: its track a bicycle for good (KITTI 0019: a walker on the pavement, 106 of its 108 frames typed bicycle after a
#: false bicycle box joined it at its start; 10 of its frames had one near). Round wid42, tune split of
#: bench/mono_vru.py: cyclist MOTA 28.65 -> 34.83 (2 or 3 alike; 0019 31.5 -> 61.7), pedestrians unchanged; on the 20
#: crash clips only dad_000512's scooter reads pedestrian for its first 5 frames (dad_000487's riders at the bumper
#: are a two-wheeler in 2 of their 7 detection rounds).
WHEEL_LATCH_HITS = 2
#: Classes a track may switch between: motor vehicles; vulnerable road users (a rider seen without
#: the two-wheeler is detected as a pedestrian for a frame or two, the votes keep the track's class).
_GROUP = {"car": 0, "van": 0, "truck": 0, "bus": 0, "motorcycle": 1, "bicycle": 1, "pedestrian": 1}
#: A detection more than this many times taller (or shorter) than a track's last detected box is another road
#: user (its distance does not halve in the <= 1 s a track is carried without detection). Against the last
#: *detected* box: a carried box drifts with whatever passes in front of it. dad_000487: walkers on the
#: pavement (154-161 px) hidden by a passing scooter took over its riders' box (350 px), one track for both.
MAX_HEIGHT_RATIO = 2.0
#: A track leaving the image across its left or right border (its last detected box cut by that border, its
#: inner edge moving toward it) is not matched to a detection whose inner edge lies further inside the image
#: than that box's by more than this share of the box's width: another road user coming into view there
#: (ccd_001143: a bus leaving on the right, box 871-1280 px, inner edge moving out at 56 px/frame, took over
#: the box 699-1280 px of the next bus two frames later).
MAX_LEAVING_BACK = 0.25
#: ... leaving: its inner edge moves toward the border by more than this share of the box's width per frame.
LEAVING_RATE = 0.03
#: A box edge within this many pixels of the image border is cut by it.
BORDER_PX = 4
#: Classes whose tracks get a second matching (:func:`_recovered`): a two-wheeler or a walker is small and
#: changes speed and direction fast against its box's size, so at a low frame rate the optical flow inside its
#: box stalls on the background while it moves on (dad_000550 at 15 fps: the scooter's carried box stood still
#: for three frames, 40 px a frame behind it, and the next detection started a new track beside the truck).
RECOVER_CATEGORIES = frozenset({"motorcycle", "bicycle", "pedestrian"})
#: Any other confirmed track is matched, in that second matching, by its constant-velocity box at any round of
#: its ``max_age_s`` when that box overlaps a free detection by at least this IoU: a road user passing in front
#: of a standing car drags the optical flow inside the car's box with it, and the car detected again where it
#: stands started a second track (dad_000512, its ego stopped: a parked car's carried box ran 500 px across the
#: picture with a scooter in 24 frames, and a new track took its next detection 0.5 s on, two cars in one
#: place in the scenario). Stricter than ``min_iou``: a box extrapolated over many frames has drifted.
REACQUIRE_IOU = 0.5


@dataclass
class ImageTrack(TrackBase):
    """A vehicle in the image: current box (x1, y1, x2, y2 px), per-frame box velocity, class votes."""

    box: np.ndarray = field(default_factory=lambda: np.zeros(4))
    velocity: np.ndarray = field(default_factory=lambda: np.zeros(4))
    score: float = 0.0
    votes: dict[str, float] = field(default_factory=dict)
    last_detected: int = 0  # running frame number of the last matched detection
    detected_frame: int = 0  # video frame index of the last matched detection
    detected_box: np.ndarray = field(default_factory=lambda: np.zeros(4))
    detected_now: bool = False
    tentative_rows: list[tuple[int, float, TrackedBox]] = field(default_factory=list)
    carried_rows: list[tuple[int, float, TrackedBox]] = field(default_factory=list)  # reported since its last detection
    corrected_rows: list[tuple[int, float, TrackedBox]] = field(default_factory=list)  # to report again (bridged)
    wheel: str = ""  # the two-wheeler class once the track was one
    wheel_hits: int = 0  # detections seen as a two-wheeler
    flow_carried: bool = False  # moved by optical flow since its last detection (the height gate applies)
    # the last detected box moved on by the camera's own rotation since (None: no rotation given since)
    rotated_detected_box: np.ndarray | None = None

    @property
    def anchor_box(self) -> np.ndarray:
        """The last detected box where the camera's rotation since has moved it (px): what the box velocity adds to."""
        return self.detected_box if self.rotated_detected_box is None else self.rotated_detected_box

    @property
    def category(self) -> str:
        """The class of most votes (:func:`~deepcrashtest.perception.roadusers.track_category`); once a two-wheeler in
        :data:`WHEEL_LATCH_HITS` detections, always one (its riders are seen without it)."""
        return self.wheel or track_category(self.votes)

    def vote(self, category: str, score: float) -> None:
        """Add a detection's class vote (its score)."""
        self.votes[category] = self.votes.get(category, 0.0) + score
        self.wheel_hits += category in TWO_WHEELERS
        if (
            not self.wheel
            and self.wheel_hits >= WHEEL_LATCH_HITS
            and (cat := track_category(self.votes)) in TWO_WHEELERS
        ):
            self.wheel = cat


@dataclass(frozen=True)
class TrackedBox:
    """One confirmed track in one frame (pixels of the original frame)."""

    track_id: int
    category: str
    box: tuple[float, float, float, float]
    score: float
    state: str  # 'detected' | 'predicted'
    missed: int = 0  # the detector's calls in a row that have not seen it (0: seen at its last call)


@dataclass
class FrameTracks:
    """The tracker's output for one frame; ``detections`` is None on frames without detection.

    ``backfill``: (frame index, time s, box) of earlier frames of the tracks confirmed in this one;
    ``bridged``: the same for earlier frames of tracks matched again in this one by their constant-velocity box
    (their carried boxes set on the line between the two detections, :func:`_bridged`), replacing the rows
    reported there."""

    frame: Frame
    tracks: list[TrackedBox]
    detections: Detections | None
    backfill: list[tuple[int, float, TrackedBox]] = field(default_factory=list)
    bridged: list[tuple[int, float, TrackedBox]] = field(default_factory=list)


class BoxTracker:
    """IoU + optical-flow tracker over a stream of frames (call :meth:`update` once per frame).

    ``max_age_s``: a confirmed track survives this long without a matched detection (carried by
    flow); ``min_hits``: detection rounds needed to confirm a track; ``min_iou``: the least IoU
    between a carried box and a detection for them to be matched; ``min_score``: weaker detections
    are ignored; ``new_track_score``: the least score of a detection that starts a track (weaker ones
    only extend tracks); ``min_evidence``: the least sum of a tentative track's detection scores for
    it to be confirmed, besides ``min_hits`` (0: the hits alone). ``detector`` may be None when
    detections are passed to :meth:`update_boxes`. ``picture``: the picture's ``(x0, y0, x1, y1)`` inside any
    black bars, px (None: the whole frame), where :func:`~deepcrashtest.perception.roadusers.road_users` looks
    for the ego's bumper.
    """

    def __init__(
        self,
        detector: Detector | None,
        fps: float,
        detect_every: int = 1,
        min_hits: int = 2,
        max_age_s: float = 1.0,
        min_iou: float = 0.2,
        new_track_score: float = 0.5,
        flow: BoxFlow | None = None,
        min_score: float = 0.0,
        min_evidence: float = 0.0,
        picture: tuple[int, int, int, int] | None = None,
    ) -> None:
        if detect_every < 1:
            raise ValueError(f"detect_every must be >= 1 (got {detect_every})")
        self.detector = detector
        self.fps = float(fps)
        self.detect_every = int(detect_every)
        self.min_iou = float(min_iou)
        self.new_track_score = float(new_track_score)
        self.min_score = float(min_score)
        max_misses = max(1, math.ceil(max_age_s * fps / detect_every))
        self.core: TrackCore[ImageTrack] = TrackCore(
            min_hits=min_hits, max_misses=max_misses, min_evidence=min_evidence
        )
        self.flow = flow or BoxFlow()
        self.picture = picture
        self._prev: GreyFrame | None = None
        self._width = 0  # image width (px) of the current frame
        self._height = 0  # ... and height (px)
        self._frame = 0  # video frame index of the current frame
        self._n = 0  # frames seen

    def update(self, frame: Frame) -> FrameTracks:
        """Advance every track to ``frame`` (detecting on detection frames) and return the confirmed tracks."""
        image = frame.image
        dets: Detections | None = None
        if self._n % self.detect_every == 0:
            if self.detector is None:
                raise ValueError("BoxTracker without a detector: pass detections to update_boxes")
            dets = self.detector(image)
        h, w = image.shape[:2]
        return self.update_boxes(dets, frame.index, frame.time, (w, h), image)

    def update_boxes(
        self,
        dets: Detections | None,
        index: int,
        time: float,
        size: tuple[int, int],
        image: np.ndarray | None = None,
        motion: np.ndarray | None = None,
    ) -> FrameTracks:
        """Advance every track by one frame given its detections (None: no detection round).

        ``size``: (width, height) of the frame, pixels; ``image``: the frame (BGR) for optical flow,
        or None to carry boxes by their constant image velocity; ``motion``: the 3x3 homography taking the
        previous frame's pixels to this frame's for the camera's own rotation (None: unknown), which moves the
        boxes optical flow does not carry before their velocity does."""
        w, h = size
        self._width, self._height, self._frame = int(w), int(h), int(index)
        self._carry(self.flow.prepare(image) if image is not None else None, motion)
        for t in self.core.tracks:
            t.detected_now = False
        was_confirmed = {id(t) for t in self.core.confirmed}
        if dets is not None:
            dets = road_users(dets, picture=self.picture or (0, 0, w, h))
            self._associate(dets.subset(np.nonzero(dets.scores >= self.min_score)[0]))
        for t in self.core.tracks:
            if _visible_fraction(t.box, w, h) < 0.3 or min(t.box[2] - t.box[0], t.box[3] - t.box[1]) < 3:
                self.core.delete(t)
        self.core.prune()
        self._n += 1
        out: list[TrackedBox] = []
        backfill: list[tuple[int, float, TrackedBox]] = []
        bridged: list[tuple[int, float, TrackedBox]] = []
        for t in self.core.tracks:
            row = TrackedBox(
                track_id=t.track_id,
                category=t.category,
                box=_clip_box(t.box, w, h),
                score=round(t.score, 4),
                state="detected" if t.detected_now else "predicted",
                missed=t.misses,
            )
            if not t.confirmed:
                t.tentative_rows.append((int(index), float(time), row))
                continue
            out.append(row)
            if t.detected_now:
                t.carried_rows = []
            else:
                t.carried_rows.append((int(index), float(time), row))
            bridged += t.corrected_rows
            t.corrected_rows = []
            if id(t) not in was_confirmed:  # confirmed in this frame: report its tentative frames
                backfill += [(f, s, replace(b, track_id=t.track_id)) for f, s, b in t.tentative_rows]
                t.tentative_rows = []
        frame = Frame(int(index), float(time), image if image is not None else _NO_IMAGE)
        return FrameTracks(frame, sorted(out, key=lambda b: b.track_id), dets, backfill, bridged)

    def _carry(self, grey: GreyFrame | None, motion: np.ndarray | None = None) -> None:
        """Move every track's box into the new frame: optical flow, else the camera's rotation (``motion``, a 3x3
        homography; None: none known) and the box's constant image velocity."""
        tracks = self.core.tracks
        prev, self._prev = self._prev, grey
        if not tracks:
            return
        boxes = np.stack([t.box for t in tracks])
        if prev is not None and grey is not None:
            moved, ok = self.flow.propagate(prev, grey, boxes)
        else:
            moved, ok = boxes, np.zeros(len(tracks), bool)
        if motion is not None:
            rotated = warp_boxes(np.stack([t.anchor_box for t in tracks]), motion)
            boxes = np.where(ok[:, None], boxes, warp_boxes(boxes, motion))
        for i, (t, b, good) in enumerate(zip(tracks, moved, ok, strict=True)):
            t.box = b if good else boxes[i] + t.velocity
            t.flow_carried = t.flow_carried or bool(good)
            if motion is not None:
                t.rotated_detected_box = rotated[i]

    def _associate(self, dets: Detections) -> None:
        tracks = self.core.tracks
        cost = np.ones((len(tracks), len(dets)))
        if len(tracks) and len(dets):
            cost = 1.0 - iou_matrix(np.stack([t.box for t in tracks]), dets.boxes)
            tg = np.array([_GROUP.get(t.category, 0) for t in tracks])
            dg = np.array([_GROUP.get(str(c), 0) for c in dets.categories])
            cost[tg[:, None] != dg[None, :]] = np.inf
            cost[_height_jumps(tracks, dets.boxes)] = np.inf
            cost[_comes_back(tracks, dets.boxes, self._width) & (cost <= 1.0 - self.min_iou)] = np.inf
        max_cost = 1.0 - self.min_iou

        recovered: set[int] = set()

        def second(first: Assignment) -> list[tuple[int, int]]:
            pairs = _recovered(tracks, dets, cost, first, max_cost, self._n, self.detect_every)
            recovered.update(id(tracks[r]) for r, _ in pairs)
            return pairs

        result = self.core.step(cost, max_cost=max_cost, scores=dets.scores, second=second)
        for t, j in result.matched:
            if id(t) in recovered:
                ends = (t.detected_box, t.detected_frame, dets.boxes[j], self._frame)
                t.corrected_rows = _bridged(t.carried_rows, *ends, (self._width, self._height))
            self._absorb(t, dets, j)
        live = [t for t in self.core.tracks if t.state is not TrackState.DELETED]
        for j in result.unmatched_detections:
            if dets.scores[j] < self.new_track_score:
                continue
            group = _GROUP.get(str(dets.categories[j]), 0)
            # a duplicate of a live track's box; not of a carried box of the other group (a track typed "car" by the
            # detections of a frozen stretch, carried on over the motorcycle it was: robust dad_000550 frozen)
            same = [t.box for t in live if t.detected_now or _GROUP.get(t.category, 0) == group]
            if same and iou_matrix(dets.boxes[j], np.stack(same)).max() > 0.5:
                continue
            t = self.core.spawn(ImageTrack(), float(dets.scores[j]))
            t.box = dets.boxes[j].astype(np.float64)
            t.detected_box = t.box.copy()
            t.last_detected, t.detected_frame = self._n, self._frame
            t.score = float(dets.scores[j])
            t.vote(str(dets.categories[j]), float(dets.scores[j]))
            t.detected_now = True
            live.append(t)

    def _absorb(self, t: ImageTrack, dets: Detections, j: int) -> None:
        box = dets.boxes[j].astype(np.float64)
        gap = max(1, self._n - t.last_detected)
        v = (box - t.anchor_box) / gap
        t.velocity = 0.5 * t.velocity + 0.5 * v if t.hits > 2 else v
        t.box = box
        t.flow_carried = False
        t.detected_box = box.copy()
        t.rotated_detected_box = None
        t.last_detected, t.detected_frame = self._n, self._frame
        t.score = float(dets.scores[j])
        t.vote(str(dets.categories[j]), float(dets.scores[j]))
        t.detected_now = True


def _bridged(
    carried: list[tuple[int, float, TrackedBox]],
    box0: np.ndarray,
    frame0: int,
    box1: np.ndarray,
    frame1: int,
    size: tuple[int, int],
) -> list[tuple[int, float, TrackedBox]]:
    """The rows a track reported while carried between two detections (``box0`` at video frame ``frame0``,
    ``box1`` at ``frame1``; x1, y1, x2, y2 px; ``size``: the frame's width and height, px) with their boxes
    moved onto the straight line between the two:
    the track was matched again by its constant-velocity box, so the optical flow had carried it off the road
    user (dragged by one passing in front, or stalled)."""
    span = max(frame1 - frame0, 1)
    out = []
    for f, s, row in carried:
        a = min(max((f - frame0) / span, 0.0), 1.0)
        b = (1.0 - a) * np.asarray(box0, float) + a * np.asarray(box1, float)
        out.append((f, s, replace(row, box=_clip_box(b, *size))))
    return out


def _recovered(
    tracks: list[ImageTrack], dets: Detections, cost: np.ndarray, first: Assignment, max_cost: float, n: int,
    every: int,
) -> list[tuple[int, int]]:  # fmt: skip
    """The second matching (:meth:`TrackCore.step`'s ``second``): (track row, detection column) pairs of a
    confirmed track left unmatched by the ``first`` assignment of ``cost`` (tracks x detections, 1 - IoU; its
    carried box overlaps no free detection enough) with a free detection of its group that its constant-velocity
    box (its last detected box moved on by the camera's rotation and its box velocity; ``n``: this round's running
    frame number) overlaps:
    a track of :data:`RECOVER_CATEGORIES` detected in the previous detection round (``every`` frames ago) by
    IoU >= 1 - ``max_cost`` (only one round on: further on, a walker's extrapolated box ran 280 px across a crowd
    onto another one, dad_000487), any other track by IoU >= :data:`REACQUIRE_IOU`."""
    rows = [
        r
        for r in first.unmatched_rows
        if tracks[r].confirmed
        and (tracks[r].category not in RECOVER_CATEGORIES or n - tracks[r].last_detected <= every)
    ]
    if not rows or not first.unmatched_cols:
        return []
    cols = first.unmatched_cols
    moved = np.stack([tracks[r].anchor_box + tracks[r].velocity * (n - tracks[r].last_detected) for r in rows])
    second_cost = 1.0 - iou_matrix(moved, dets.boxes[cols])
    strict = np.array([tracks[r].category not in RECOVER_CATEGORIES for r in rows])
    second_cost[strict[:, None] & (second_cost > 1.0 - REACQUIRE_IOU)] = np.inf
    second_cost[~np.isfinite(cost[np.ix_(rows, cols)])] = np.inf  # the first matching's gates hold
    return [(rows[i], cols[j]) for i, j in assign(second_cost, max_cost).pairs]


def _height_jumps(tracks: list[ImageTrack], boxes: np.ndarray) -> np.ndarray:
    """(tracks, detections) True where the detection's height is off the track's last detected box's by more
    than :data:`MAX_HEIGHT_RATIO` (a track is carried for at most ``max_age_s``, ~1 s), for tracks whose box
    optical flow moved since that detection: the gate guards against a box dragged by whatever passes in
    front of it. Boxes without pixels (constant image velocity) are not gated: on the 18 KITTI training
    sequences through the monocular path the gate cost 3.9 MOTA (60.68 -> 56.75) there."""
    last = np.array([max(t.detected_box[3] - t.detected_box[1], 1.0) for t in tracks])
    ratio = np.abs(np.log(np.maximum(boxes[:, 3] - boxes[:, 1], 1.0)[None, :] / last[:, None]))
    carried = np.array([t.flow_carried for t in tracks])
    return (ratio > math.log(MAX_HEIGHT_RATIO)) & carried[:, None]


def _comes_back(tracks: list[ImageTrack], boxes: np.ndarray, width: int) -> np.ndarray:
    """(tracks, detections) True where a track leaves the image across its left or right border (its last
    detected box reaches that border, its inner edge moves toward it by more than ``LEAVING_RATE`` of the
    box's width per frame) and the detection's inner edge lies more than ``MAX_LEAVING_BACK`` of that width
    further inside the image: a road user leaving the view does not turn back within a detection round.
    Only tracks whose velocity spans two detection rounds or more (``_absorb``): one round of a jittery box
    cut by the border is no direction (ccd_000031: a van's box 1076 -> 1162 -> 1100 px, one road user)."""
    out = np.zeros((len(tracks), len(boxes)), bool)
    if width <= 0:
        return out
    for i, t in enumerate(tracks):
        if t.hits < 3:
            continue
        d, v = t.detected_box, t.velocity
        w = max(d[2] - d[0], 1.0)
        if d[2] >= width - BORDER_PX and d[0] > BORDER_PX and v[0] > LEAVING_RATE * w:  # out to the right
            out[i] = d[0] - boxes[:, 0] > MAX_LEAVING_BACK * w
        elif d[0] <= BORDER_PX and d[2] < width - BORDER_PX and -v[2] > LEAVING_RATE * w:  # out to the left
            out[i] = boxes[:, 2] - d[2] > MAX_LEAVING_BACK * w
    return out


def warp_boxes(boxes: np.ndarray, H: np.ndarray) -> np.ndarray:
    """(n, 4) boxes ``x1, y1, x2, y2`` (px) through the 3x3 homography ``H``: each edge at the mean of its two
    corners' images (a rotation about the optical axis does not grow the box as its corners' hull would)."""
    x1, y1, x2, y2 = np.asarray(boxes, float).T
    corners = np.stack([[x1, y1], [x2, y1], [x2, y2], [x1, y2]], axis=0)  # (4, 2, n): tl, tr, br, bl
    pts = np.concatenate([corners, np.ones((4, 1, corners.shape[2]))], axis=1)  # (4, 3, n)
    img = np.einsum("ij,kjn->kin", H, pts)
    u, v = img[:, 0] / img[:, 2], img[:, 1] / img[:, 2]  # (4, n)
    return np.stack([(u[0] + u[3]) / 2, (v[0] + v[1]) / 2, (u[1] + u[2]) / 2, (v[2] + v[3]) / 2], axis=1)


def _visible_fraction(box: np.ndarray, w: int, h: int) -> float:
    area = max(box[2] - box[0], 0.0) * max(box[3] - box[1], 0.0)
    if area <= 0:
        return 0.0
    ix = max(min(box[2], w) - max(box[0], 0.0), 0.0)
    iy = max(min(box[3], h) - max(box[1], 0.0), 0.0)
    return float(ix * iy / area)


def _clip_box(box: np.ndarray, w: int, h: int) -> tuple[float, float, float, float]:
    x1, y1, x2, y2 = (float(v) for v in box)
    return (
        round(min(max(x1, 0.0), w), 2),
        round(min(max(y1, 0.0), h), 2),
        round(min(max(x2, 0.0), w), 2),
        round(min(max(y2, 0.0), h), 2),
    )


def iter_tracks(
    source: VideoSource | Iterable[Frame],
    detector: Detector,
    detect_every: int = 1,
    max_frames: int | None = None,
    fps: float | None = None,
    **tracker_options: float,
) -> Iterator[FrameTracks]:
    """Decode ``source`` once and yield the tracked vehicles of every frame, in order.

    ``fps`` defaults to ``source.meta.fps``; ``tracker_options`` go to :class:`BoxTracker`.
    """
    rate = fps if fps is not None else getattr(getattr(source, "meta", None), "fps", None)
    if rate is None:
        raise ValueError("fps unknown: pass fps= for a plain iterable of frames")
    frames = itertools.islice(source, max_frames)
    yield from track_detected(detect_ahead(frames, detector, detect_every), rate, detect_every, None, **tracker_options)


def detect_ahead(
    frames: Iterable[Frame], detector: Detector, detect_every: int = 1
) -> Iterator[tuple[Frame, Detections | None]]:
    """Each frame with the detector's boxes on detection frames (the first and every ``detect_every``-th
    after it: :meth:`BoxTracker.update`'s schedule), None between.

    The schedule does not depend on the tracks, so a pipeline can run this in its own thread, ahead of
    :func:`track_detected` (the detector is most of the tracker's CPU; onnxruntime releases the GIL).
    """
    if detect_every < 1:
        raise ValueError(f"detect_every must be >= 1 (got {detect_every})")
    for k, frame in enumerate(frames):
        yield frame, detector(frame.image) if k % detect_every == 0 else None


def track_detected(
    detected: Iterable[tuple[Frame, Detections | None]],
    fps: float,
    detect_every: int = 1,
    picture: tuple[int, int, int, int] | None = None,
    **tracker_options: float,
) -> Iterator[FrameTracks]:
    """Track frames whose detections were made already (:func:`detect_ahead`): the same tracks as
    :func:`iter_tracks` with the same ``detect_every`` (``picture``: :class:`BoxTracker`'s)."""
    tracker = BoxTracker(
        None,
        fps=fps,
        detect_every=detect_every,
        picture=picture,
        **tracker_options,  # type: ignore[arg-type]
    )
    for frame, dets in detected:
        h, w = frame.image.shape[:2]
        yield tracker.update_boxes(dets, frame.index, frame.time, (w, h), frame.image)


def frame_records(ft: FrameTracks, bridged: bool = True) -> list[tuple[object, ...]]:
    """Rows of :data:`TRACK_COLUMNS`: this frame's tracks, then the backfilled rows of earlier frames, then (with
    ``bridged``) :func:`bridged_records`."""
    rows: list[tuple[object, ...]] = [
        (ft.frame.index, ft.frame.time, b.track_id, b.category, *b.box, b.score, b.state) for b in ft.tracks
    ]
    rows += _earlier_records(ft.backfill)
    return rows + bridged_records(ft) if bridged else rows


def bridged_records(ft: FrameTracks) -> list[tuple[object, ...]]:
    """Rows of :data:`TRACK_COLUMNS` of :attr:`FrameTracks.bridged` (earlier frames reported again: a table keeps
    a frame's later row, :func:`records_table`)."""
    return _earlier_records(ft.bridged)


def _earlier_records(items: list[tuple[int, float, TrackedBox]]) -> list[tuple[object, ...]]:
    return [(f, s, b.track_id, b.category, *b.box, b.score, b.state) for f, s, b in items]


def track_boxes(
    detections: Iterable[Detections | None],
    fps: float,
    size: tuple[int, int],
    camera_motion: Sequence[np.ndarray | None] | None = None,
    **tracker_options: float,
) -> pd.DataFrame:
    """Track a sequence of per-frame detections without pixels (frame k at time k / fps; None: a frame the
    detector did not run on, its boxes carried, as with ``detect_every`` in ``tracker_options``).

    ``size``: (width, height) of the frames, pixels; ``camera_motion``: per frame the 3x3 homography of the
    camera's own rotation from the frame before (:meth:`BoxTracker.update_boxes`' ``motion``; None: unknown).
    Returns the ``tracks.csv`` table sorted by frame and track (rows of frames before a track's confirmation
    included)."""
    tracker = BoxTracker(None, fps=fps, **tracker_options)  # type: ignore[arg-type]
    records: list[tuple[object, ...]] = []
    for k, dets in enumerate(detections):
        if camera_motion is not None and k >= len(camera_motion):
            raise ValueError(f"camera_motion has {len(camera_motion)} frames, the detections more")
        motion = camera_motion[k] if camera_motion is not None else None
        records.extend(frame_records(tracker.update_boxes(dets, k, k / fps, size, motion=motion)))
    return records_table(records).sort_values(["frame", "track_id"], ignore_index=True)


#: dtype of each column of :data:`TRACK_COLUMNS` (None: Python strings).
_COLUMN_TYPES = ("int64", "float64", "int64", None, "float64", "float64", "float64", "float64", "float64", None)


def records_table(records: list[tuple[object, ...]]) -> pd.DataFrame:
    """Rows of :data:`TRACK_COLUMNS` -> the tracks table (built column by column: extract makes one per
    frame, and ``DataFrame.from_records`` + ``astype`` cost ~7x as much). A track's frame reported twice keeps its
    later row: a track matched again by its constant-velocity box reports its carried frames again, bridged
    (:func:`_bridged`)."""
    cols: list[tuple[object, ...]] = list(zip(*records, strict=True)) if records else [()] * len(TRACK_COLUMNS)
    data = {
        name: np.array(values, dtype=kind) if kind else np.array([str(v) for v in values], dtype=object)
        for name, values, kind in zip(TRACK_COLUMNS, cols, _COLUMN_TYPES, strict=True)
    }
    import pandas as pd

    table = pd.DataFrame(data)
    again = table.duplicated(["frame", "track_id"], keep="last")
    return table[~again].reset_index(drop=True) if again.any() else table


def tracks_dataframe(rows: Iterable[FrameTracks]) -> pd.DataFrame:
    """Per-frame tracker results -> the ``tracks.csv`` table (columns :data:`TRACK_COLUMNS`)."""
    return records_table([r for ft in rows for r in frame_records(ft)])


def track_video(
    source: VideoSource | Iterable[Frame],
    detector: Detector,
    detect_every: int = 1,
    max_frames: int | None = None,
    on_frame: Callable[[FrameTracks], None] | None = None,
    **options: float,
) -> pd.DataFrame:
    """Track every vehicle in ``source``; returns the ``tracks.csv`` DataFrame.

    ``on_frame`` is called with each frame's :class:`FrameTracks` as it is produced (annotation,
    ego-motion ... in the same decoding pass); frames are not kept.
    """
    records: list[tuple[object, ...]] = []
    for ft in iter_tracks(source, detector, detect_every=detect_every, max_frames=max_frames, **options):
        if on_frame is not None:
            on_frame(ft)
        records.extend(frame_records(ft))
    return records_table(records).sort_values(["frame", "track_id"], ignore_index=True)
