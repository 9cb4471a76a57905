"""Lane markings -> tracked lane lines, ego lane width, lateral offset and lane changes.

Classical detector (:class:`ClassicalLaneDetector`), one frame at a time:

1. Road ROI: rows from a little below the horizon down to the dashboard (or the frame bottom),
   frame downscaled to ``work_width`` pixels.
2. Marking pixels: bright (white: high HLS lightness relative to the road) or yellow (HLS hue
   15-35, saturated) *and* next to a strong horizontal gradient (Sobel x), which removes bright
   but flat areas (sky, concrete).
3. DBSCAN on the pixel coordinates with rows compressed (markings are long and nearly vertical in
   the image, dashes of one line join up), each cluster fitted with a straight line ``u = a v + b``
   near the car; clusters on one line are merged. :func:`dbscan` gives scikit-learn's labels exactly
   from a SciPy k-d tree and connected components, at a fraction of the per-call cost (and without
   scikit-learn's ~1.3 s import).
4. Tracking: Hungarian assignment (SciPy) on the symmetric directed Hausdorff distance between
   a detected line and a tracked line, both sampled over the ROI rows.
5. Ego lane: the nearest tracked lines left and right of the camera at the ROI's bottom row; their
   positions on the road (flat road, camera height, horizon) give lane width and the ego's
   offset; a jump of the offset by more than half a lane is a lane change.

Image coordinates are pixels of the full frame (u right, v down); metric values are metres on
the road, camera frame (x right). ``lateral_offset`` follows ``scenario.LaneTimeline``: the ego
centre's distance *left* of its lane centre. Any detector with the :class:`LaneDetector`
protocol (a learned model) can replace this one.
"""

from __future__ import annotations

import math
from collections import deque
from dataclasses import dataclass, field
from typing import Protocol

import cv2
import numpy as np

from deepcrashtest.scenario import Camera

PLAUSIBLE_LANE_WIDTH_M = (2.5, 5.0)
#: The ego lane's last this many plausible widths make its reference width (:meth:`ClassicalLaneDetector._ego_pair`).
LANE_WIDTH_MEMORY = 50
#: ... and a pair whose width is off that reference by more than this share is taken only when no other pair fits.
LANE_WIDTH_TOLERANCE = 0.2


def plausible_lane_width(width: float | None) -> bool:
    """Whether ``width`` (m) is a lane's (:data:`PLAUSIBLE_LANE_WIDTH_M`); None (not measured) is not."""
    return width is not None and PLAUSIBLE_LANE_WIDTH_M[0] <= width <= PLAUSIBLE_LANE_WIDTH_M[1]


@dataclass
class LaneLine:
    """A straight lane line in full-frame pixels: ``u = a * v + b`` for ``v`` in [v_top, v_bottom]."""

    a: float
    b: float
    v_top: float
    v_bottom: float
    support: int = 0
    track_id: int = 0

    def u_at(self, v: float | np.ndarray) -> float | np.ndarray:
        return self.a * np.asarray(v) + self.b

    def samples(self, v_top: float, v_bottom: float, n: int = 12) -> np.ndarray:
        v = np.linspace(v_top, v_bottom, n)
        return np.column_stack([self.u_at(v), v])


@dataclass
class LaneState:
    """Lanes after one frame. Metric values are metres on the road (None when not measured)."""

    frame: int
    time: float
    lines: list[LaneLine]
    left: LaneLine | None = None
    right: LaneLine | None = None
    lane_width: float | None = None
    lateral_offset: float | None = None
    lane_index: int = 0
    lane_change: int = 0  # +1 moved one lane left, -1 one lane right, 0 none
    roi_top: float = 0.0  # top row of the road region, pixels


@dataclass
class LaneTrack:
    """A lane line followed over frames."""

    track_id: int
    line: LaneLine
    hits: int = 1
    missed: int = 0


class LaneDetector(Protocol):
    """Anything that turns frames into :class:`LaneState` (a learned model can plug in here).

    ``update`` gets each frame (BGR), its time (s) and the road users' boxes (N, 4) x1, y1, x2, y2 px to
    ignore; ``timeline`` gives the per-frame lane figures at the end (None when nothing was measured).
    """

    def update(self, frame_bgr: np.ndarray, time: float, vehicle_boxes: np.ndarray | None = None) -> LaneState: ...

    def timeline(self) -> LaneTimelineResult | None: ...


@dataclass
class LaneTimelineResult:
    """Per-frame lane figures (NaN where not measured) and warnings."""

    t: np.ndarray
    lane_width: np.ndarray
    lateral_offset: np.ndarray
    lane_index: np.ndarray
    both_found: np.ndarray
    warnings: list[str] = field(default_factory=list)

    def median_lane_width(self) -> float | None:
        w = self.lane_width[np.isfinite(self.lane_width)]
        return float(np.median(w)) if w.size else None


class ClassicalLaneDetector:
    """Colour + gradient markings, DBSCAN lines, Hungarian/Hausdorff tracking (module docstring)."""

    def __init__(
        self,
        camera: Camera,
        mask_bottom_rows: int = 0,
        horizon_v: float | None = None,
        work_width: int = 640,
        max_missed: int = 8,
        gate_px: float = 60.0,
        seed: int = 0,
    ) -> None:
        self.camera = camera
        self.mask_bottom_rows = int(mask_bottom_rows)
        self.horizon_v = camera.horizon_v() if horizon_v is None else horizon_v
        self.work_width = work_width
        self.max_missed = max_missed
        self.gate_px = gate_px
        self.seed = seed
        self.tracks: list[LaneTrack] = []
        self._next_id = 1
        self._frame = 0
        self._states: list[LaneState] = []
        self._lane_index = 0
        self._last_offset: float | None = None
        self._last_width: float | None = None
        self._widths: deque[float] = deque(maxlen=LANE_WIDTH_MEMORY)  # the ego lane's last plausible widths (m)
        self._size: tuple[int, int] | None = None

    # ------------------------------------------------------------------ geometry
    def roi_rows(self, height: int) -> tuple[float, float]:
        """(top, bottom) rows of the road ROI, full-frame pixels."""
        bottom = height - 1 - self.mask_bottom_rows
        top = self.horizon_v + 0.12 * (bottom - self.horizon_v)
        return max(0.0, top), float(bottom)

    def road_x(self, u: float, v: float) -> float | None:
        """Lateral road position (metres, right positive) of pixel (u, v) on a flat road."""
        below = v - self.horizon_v
        if below <= 1.0:
            return None
        z = self.camera.fy * self.camera.height_m / below
        return (u - self.camera.cx) * z / self.camera.fx

    # ------------------------------------------------------------------ detection
    def marking_mask(self, frame_bgr: np.ndarray) -> tuple[np.ndarray, float, int]:
        """Binary marking mask of the ROI (downscaled), the scale factor and the ROI's top row (downscaled)."""
        h, w = frame_bgr.shape[:2]
        s = min(1.0, self.work_width / float(w))
        small = cv2.resize(frame_bgr, None, fx=s, fy=s, interpolation=cv2.INTER_AREA) if s < 1 else frame_bgr
        top, bottom = self.roi_rows(h)
        r0, r1 = int(top * s), int(bottom * s) + 1
        roi = small[r0:r1]
        if roi.size == 0:
            return np.zeros((0, small.shape[1]), np.uint8), s, r0
        hls = cv2.cvtColor(roi, cv2.COLOR_BGR2HLS)
        hue, light, sat = hls[..., 0], hls[..., 1].astype(np.float32), hls[..., 2]
        road_level = float(np.median(light))
        white = light > max(road_level + 45.0, float(np.percentile(light, 93)))
        yellow = (hue >= 15) & (hue <= 35) & (sat > 90) & (light > road_level)
        gx = np.abs(cv2.Sobel(light, cv2.CV_32F, 1, 0, ksize=3))
        grad = gx > max(25.0, float(np.percentile(gx, 90)))
        grad = cv2.dilate(grad.astype(np.uint8), np.ones((3, 7), np.uint8)) > 0
        mask = ((white | yellow) & grad).astype(np.uint8)
        mask = cv2.morphologyEx(mask, cv2.MORPH_OPEN, np.ones((2, 2), np.uint8))  # type: ignore[assignment]
        return mask, s, r0

    def detect(self, frame_bgr: np.ndarray) -> list[LaneLine]:
        """Straight lane lines of one frame (no tracking), full-frame pixels."""
        h, w = frame_bgr.shape[:2]
        mask, s, r0 = self.marking_mask(frame_bgr)
        vs, us = np.nonzero(mask)
        if len(us) < 30:
            return []
        rng = np.random.default_rng(self.seed)
        if len(us) > 5000:
            keep = rng.choice(len(us), 5000, replace=False)
            us, vs = us[keep], vs[keep]
        pts = np.column_stack([us, (vs + r0) * 0.35]).astype(float)
        labels = dbscan(pts, eps=4.0, min_samples=6)
        top, bottom = self.roi_rows(h)
        lines: list[LaneLine] = []
        for lab in set(labels.tolist()) - {-1}:
            sel = labels == lab
            u = us[sel] / s
            v = (vs[sel] + r0) / s
            if v.max() - v.min() < 0.08 * (bottom - top) or len(u) < 15:
                continue
            a, b = np.polyfit(v, u, 1)
            resid = float(np.median(np.abs(u - (a * v + b))))
            if resid > 4.0 / s:
                continue
            lines.append(LaneLine(float(a), float(b), float(v.min()), float(v.max()), int(sel.sum())))
        lines = self._merge(lines, bottom)
        return [ln for ln in lines if self._plausible(ln, w, bottom)]

    def _plausible(self, ln: LaneLine, width: int, bottom: float) -> bool:
        u_h = float(ln.u_at(self.horizon_v))
        u_b = float(ln.u_at(bottom))
        if abs(u_h - self.camera.cx) > 0.35 * width:
            return False  # does not head for the vanishing point
        if abs(ln.a) < 0.15:
            return False  # near-vertical in the image: a pole, a car edge
        return (u_b < self.camera.cx) == (ln.a < 0) or abs(u_b - self.camera.cx) < 0.05 * width

    def _merge(self, lines: list[LaneLine], bottom: float) -> list[LaneLine]:
        lines = sorted(lines, key=lambda ln: -ln.support)
        merged: list[LaneLine] = []
        for ln in lines:
            for m in merged:
                if abs(float(m.u_at(bottom)) - float(ln.u_at(bottom))) < 25 / max(self.work_width / 1280, 0.25) and abs(
                    math.atan(m.a) - math.atan(ln.a)
                ) < math.radians(6):
                    wsum = m.support + ln.support
                    m.a = (m.a * m.support + ln.a * ln.support) / wsum
                    m.b = (m.b * m.support + ln.b * ln.support) / wsum
                    m.v_top, m.v_bottom = min(m.v_top, ln.v_top), max(m.v_bottom, ln.v_bottom)
                    m.support = wsum
                    break
            else:
                merged.append(ln)
        return merged

    # ------------------------------------------------------------------ tracking
    def _associate(self, lines: list[LaneLine], top: float, bottom: float) -> None:
        if self.tracks and lines:
            cost = hausdorff_matrix(
                np.stack([tr.line.samples(top, bottom) for tr in self.tracks]),
                np.stack([ln.samples(top, bottom) for ln in lines]),
            )
            from scipy.optimize import linear_sum_assignment  # SciPy loads while the first frames decode

            rows, cols = linear_sum_assignment(cost)
            gate = self.gate_px * (self._size[0] / 1280.0 if self._size else 1.0)
            pairs = [(r, c) for r, c in zip(rows, cols, strict=True) if cost[r, c] < gate]
        else:
            pairs = []
        matched_t = {r for r, _ in pairs}
        matched_d = {c for _, c in pairs}
        for r, c in pairs:
            tr, ln = self.tracks[r], lines[c]
            k = 0.5  # exponential smoothing of the line parameters
            a = (1 - k) * tr.line.a + k * ln.a
            b = (1 - k) * tr.line.b + k * ln.b
            tr.line = LaneLine(a, b, ln.v_top, ln.v_bottom, ln.support, tr.track_id)
            tr.hits += 1
            tr.missed = 0
        for i, tr in enumerate(self.tracks):
            if i not in matched_t:
                tr.missed += 1
        self.tracks = [t for t in self.tracks if t.missed <= self.max_missed]
        for j, ln in enumerate(lines):
            if j not in matched_d:
                ln.track_id = self._next_id
                self.tracks.append(LaneTrack(self._next_id, ln))
                self._next_id += 1

    def update(self, frame_bgr: np.ndarray, time: float, vehicle_boxes: np.ndarray | None = None) -> LaneState:
        """Detect, track and measure lanes in one frame (``vehicle_boxes`` px are masked out)."""
        h, w = frame_bgr.shape[:2]
        self._size = (w, h)
        img = frame_bgr
        if vehicle_boxes is not None and len(vehicle_boxes):
            img = frame_bgr.copy()
            for x1, y1, x2, y2 in np.asarray(vehicle_boxes, dtype=float).reshape(-1, 4):
                img[max(0, int(y1)) : max(0, int(y2)), max(0, int(x1)) : max(0, int(x2))] = 0
        top, bottom = self.roi_rows(h)
        self._associate(self.detect(img), top, bottom)
        live = [t for t in self.tracks if t.missed <= 2 and t.hits >= 2]
        lines = [LaneLine(t.line.a, t.line.b, t.line.v_top, t.line.v_bottom, t.line.support, t.track_id) for t in live]
        left, right = self._ego_pair(lines, bottom)
        state = LaneState(self._frame, float(time), lines, left, right, lane_index=self._lane_index, roi_top=top)
        if left is not None and right is not None:
            xl = self.road_x(float(left.u_at(bottom)), bottom)
            xr = self.road_x(float(right.u_at(bottom)), bottom)
            if xl is not None and xr is not None:
                width = xr - xl
                offset = 0.5 * (xl + xr)
                if self._last_offset is not None and self._last_width is not None:
                    jump = offset - self._last_offset
                    if abs(jump) > 0.5 * self._last_width:
                        state.lane_change = 1 if jump < 0 else -1
                        self._lane_index = max(0, self._lane_index + state.lane_change)
                state.lane_width, state.lateral_offset, state.lane_index = width, offset, self._lane_index
                if plausible_lane_width(width):
                    self._widths.append(width)
                self._last_offset, self._last_width = offset, width
        self._frame += 1
        self._states.append(state)
        return state

    def _ego_pair(self, lines: list[LaneLine], bottom: float) -> tuple[LaneLine | None, LaneLine | None]:
        """The ego lane's boundaries: the nearest line left and the nearest right of the image centre at the ROI's
        bottom row (``bottom``, px), unless their road width is outside :data:`PLAUSIBLE_LANE_WIDTH_M` or off the
        lane's median width so far by more than :data:`LANE_WIDTH_TOLERANCE` while another left / right pair's is
        not: then the pair whose width is nearest that median (the range's middle before any). A seam, a tar line or
        a shadow edge inside the lane was taken for its boundary: the Udacity challenge clip's ego lane drawn 2.2 m
        wide through the middle of its 3.8 m."""
        cx = self.camera.cx
        sides = [(float(ln.u_at(bottom)), ln) for ln in lines]
        lefts = sorted([p for p in sides if p[0] < cx], key=lambda p: -p[0])  # the nearest first
        rights = sorted([p for p in sides if p[0] >= cx], key=lambda p: p[0])
        if not lefts or not rights:
            return (lefts[0][1] if lefts else None), (rights[0][1] if rights else None)
        xls = [self.road_x(u, bottom) for u, _ in lefts]  # road x (m) of each line at the bottom row
        xrs = [self.road_x(u, bottom) for u, _ in rights]
        widths = {
            (i, j): xr - xl for i, xl in enumerate(xls) for j, xr in enumerate(xrs) if xl is not None and xr is not None
        }
        ref = float(np.median(self._widths)) if self._widths else None

        def fits(width: float) -> bool:
            return plausible_lane_width(width) and (ref is None or abs(width - ref) <= LANE_WIDTH_TOLERANCE * ref)

        nearest = widths.get((0, 0))
        fitting = {k: w for k, w in widths.items() if fits(w)}
        if nearest is None or fits(nearest) or not fitting:
            return lefts[0][1], rights[0][1]
        centre = 0.5 * sum(PLAUSIBLE_LANE_WIDTH_M) if ref is None else ref
        i, j = min(fitting, key=lambda k: abs(fitting[k] - centre))
        return lefts[i][1], rights[j][1]

    def timeline(self) -> LaneTimelineResult:
        """Per-frame lane width, lateral offset, lane index; warns when lanes were rarely found."""
        s = self._states
        width = np.array([np.nan if x.lane_width is None else x.lane_width for x in s])
        both = np.isfinite(width)
        warnings: list[str] = []
        if s and both.mean() < 0.3:
            warnings.append(
                f"lanes: both ego-lane boundaries found in only {100 * both.mean():.0f}% of frames "
                "(no clear markings, darkness or glare); lane offsets not used"
            )
        good = width[both]
        if good.size and not plausible_lane_width(float(np.median(good))):
            warnings.append(
                f"lanes: median lane width {float(np.median(good)):.2f} m is implausible: camera height, "
                "horizon or focal length may be wrong"
            )
        return LaneTimelineResult(
            t=np.array([x.time for x in s]),
            lane_width=width,
            lateral_offset=np.array([np.nan if x.lateral_offset is None else x.lateral_offset for x in s]),
            lane_index=np.array([x.lane_index for x in s], dtype=int),
            both_found=both,
            warnings=warnings,
        )


def dbscan(points: np.ndarray, eps: float, min_samples: int) -> np.ndarray:
    """DBSCAN cluster labels of ``points`` (n, d), -1 for noise: the labels scikit-learn's
    ``DBSCAN(eps, min_samples).fit_predict`` gives, numbering included.

    A point is a core point with at least ``min_samples`` points (itself included) within ``eps``;
    clusters are the connected components of core points, numbered in the order of their first
    point; a border point joins the lowest-numbered cluster among its core neighbours (the cluster
    whose expansion reaches it first in scikit-learn's scan).
    """
    n = len(points)
    if n == 0:
        return np.zeros(0, np.int64)
    from scipy.sparse import coo_matrix  # SciPy loads while the first frames decode
    from scipy.sparse.csgraph import connected_components
    from scipy.spatial import cKDTree

    pairs = cKDTree(points).query_pairs(eps, output_type="ndarray")
    i, j = pairs[:, 0], pairs[:, 1]
    core = np.bincount(np.concatenate([i, j]), minlength=n) + 1 >= min_samples
    labels = np.full(n, -1, np.int64)
    both = core[i] & core[j]
    graph = coo_matrix((np.ones(int(both.sum()), np.int8), (i[both], j[both])), shape=(n, n))
    _, comp = connected_components(graph, directed=False)
    core_idx = np.flatnonzero(core)
    found, first = np.unique(comp[core_idx], return_index=True)  # components of core points, first point
    rank = np.zeros(int(comp.max()) + 1, np.int64)
    rank[found[np.argsort(first)]] = np.arange(len(found))
    labels[core_idx] = rank[comp[core_idx]]
    src = np.concatenate([i, j])
    dst = np.concatenate([j, i])
    border = core[src] & ~core[dst]
    if border.any():
        best = np.full(n, np.iinfo(np.int64).max, np.int64)
        np.minimum.at(best, dst[border], labels[src[border]])
        reached = best < np.iinfo(np.int64).max
        labels[reached] = best[reached]
    return labels


def hausdorff_matrix(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Symmetric Hausdorff distance between each point set of ``a`` (m, k, 2) and of ``b`` (n, l, 2):
    an (m, n) matrix, the larger of the two directed distances (px)."""
    d = np.sqrt(((a[:, None, :, None, :] - b[None, :, None, :, :]) ** 2).sum(axis=-1))  # (m, n, k, l)
    return np.maximum(d.min(axis=3).max(axis=2), d.min(axis=2).max(axis=2))


def draw_lanes(frame_bgr: np.ndarray, state: LaneState, top_v: float | None = None, copy: bool = True) -> np.ndarray:
    """A copy of the frame with tracked lane lines (the ego lane's boundaries thick green with its width and offset,
    others thin yellow); with ``copy=False`` they are drawn into ``frame_bgr`` itself (extract draws onto the
    annotator's copy: one full-frame copy less per frame). The ego lane is drawn only where it was measured with a
    plausible width (:data:`PLAUSIBLE_LANE_WIDTH_M`): elsewhere its lines are drawn as any others, not as a lane the
    video does not show (dad_000487: a 1 m "lane" up a building front, where the lane stage is not used)."""
    out = frame_bgr.copy() if copy else frame_bgr
    h = out.shape[0]
    lane = plausible_lane_width(state.lane_width)
    for ln in state.lines:
        v0 = (state.roi_top or ln.v_top) if top_v is None else top_v
        p0 = (int(round(float(ln.u_at(v0)))), int(round(v0)))
        p1 = (int(round(float(ln.u_at(h - 1)))), h - 1)
        ego = lane and (ln is state.left or ln is state.right)
        cv2.line(out, p0, p1, (0, 255, 0) if ego else (0, 220, 255), 4 if ego else 2, cv2.LINE_AA)
    if lane and state.lane_width is not None and state.lateral_offset is not None:
        text = f"lane {state.lane_width:.2f} m  offset {state.lateral_offset:+.2f} m"
        cv2.putText(out, text, (10, 60), cv2.FONT_HERSHEY_SIMPLEX, 0.8, (0, 255, 0), 2, cv2.LINE_AA)
    return out
