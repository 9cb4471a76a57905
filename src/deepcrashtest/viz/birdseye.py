"""Bird's-eye video of a simulation run (H.264 MP4 via PyAV), drawn with OpenCV.

The view follows the ego (world x forward = right of the image, y left = up), ``PX_PER_M``
pixels per metre. Drawn: road edges and lane lines from ``Scenario.road`` (the centre line is the
ego's lane centre when ``road.source`` is ``ego_path``; the road spans ``lane_count`` lanes of
``lane_width`` with the ego in ``ego_lane``, 0 = rightmost; the oncoming lanes left of it, beyond a solid
yellow line between the two directions, or two across a median), every present vehicle as its box with
its id and class (ego blue, cars grey, two-wheelers with their rider yellow, pedestrians green
discs; road users in a collision red), 3-second trails, a clock, the ego's speed, the ego's first
collision and the first contact between two other road users (a third-party crash), each marked at
its impact point from then on. A road that was inferred rather than seen says so.
"""

from __future__ import annotations

import os
from dataclasses import dataclass
from typing import Any

import cv2
import numpy as np

from deepcrashtest.geometry.road import boundary_polylines, divider_index, oncoming_polylines
from deepcrashtest.scenario import Scenario
from deepcrashtest.viz.h264 import h264_writer

WIDTH, HEIGHT = 960, 540
PX_PER_M = 8.0
AHEAD_M = 25.0  # the view centre is this far ahead of the ego
TRAIL_S = 3.0
FPS = 25.0

BG = (40, 40, 40)
ROAD = (70, 70, 70)
EDGE = (230, 230, 230)
LANE = (160, 160, 160)
DIRECTIONS = (40, 200, 240)  # yellow: the solid line between the two directions
EGO = (235, 140, 30)
AGENT = (190, 190, 190)
HIT = (40, 40, 230)
TWO_WHEELER = (60, 200, 230)
PEDESTRIAN = (90, 200, 90)
SHORT = {"pedestrian": "ped", "motorcycle": "moto", "bicycle": "bike"}
TEXT = (255, 255, 255)


@dataclass(frozen=True)
class _RoadLines:
    """The road's lines in world metres: outer edges, dashed lane dividers, the solid line(s) between the two
    directions (none on a one-way road) and the carriageways' polygons."""

    edges: list[np.ndarray]
    lanes: list[np.ndarray]
    directions: list[np.ndarray]
    polygons: list[np.ndarray]


def _road_lines(scenario: Scenario) -> _RoadLines:
    """The ego's carriageway and the oncoming lanes' lines (:mod:`deepcrashtest.geometry.road`)."""
    own, other = boundary_polylines(scenario.road), oncoming_polylines(scenario.road)
    polygons = [np.vstack([own[0], own[-1][::-1]])]
    if not other:
        return _RoadLines([own[0], own[-1]], own[1:-1], [], polygons)
    polygons.append(np.vstack([other[0], other[-1][::-1]]))
    k = divider_index(scenario.road)
    outer, divider = own[-1 - k], own[k]
    return _RoadLines([outer, other[-1]], own[1:-1] + other[1:-1], [divider, other[0]], polygons)


class _View:
    def __init__(self, centre: np.ndarray) -> None:
        self.centre = centre

    def px(self, xy: np.ndarray) -> np.ndarray:
        d = (np.asarray(xy, float) - self.centre) * PX_PER_M
        return np.column_stack([WIDTH / 2 + d[:, 0], HEIGHT / 2 - d[:, 1]]).round().astype(np.int32)


def _box(x: float, y: float, yaw: float, length: float, width: float) -> np.ndarray:
    c, s = np.cos(yaw), np.sin(yaw)
    lx = np.array([1, -1, -1, 1]) * length / 2
    ly = np.array([1, 1, -1, -1]) * width / 2
    return np.column_stack([x + lx * c - ly * s, y + lx * s + ly * c])


def _text(img: np.ndarray, text: str, org: tuple[int, int], scale: float, colour: Any, thick: int = 1) -> None:
    cv2.putText(img, text, org, cv2.FONT_HERSHEY_SIMPLEX, scale, colour, thick, cv2.LINE_AA)


TAG_SCALE = 0.45
TAG_PAD_PX = 2
#: Where a road user's tag may go, tried in turn: (dx, dy, left) px from its centre to the text's lower left ("left":
#: the text ends there instead): above, below, right, left, the four corners, then each again further out.
TAG_OFFSETS = tuple(
    (dx * ring, dy + (ring - 1) * sy, left)
    for ring in (1, 2, 3)
    for dx, dy, sy, left in (
        (-6, -14, -16, False),
        (-6, 26, 16, False),
        (14, 5, 0, False),
        (-14, 5, 0, True),
        (14, -10, -16, False),
        (-14, -10, -16, True),
        (14, 20, 16, False),
        (-14, 20, 16, True),
    )
)


def place_tags(
    anchors: list[tuple[int, int]], texts: list[str], shapes: list[tuple[int, int, int, int]] | None = None
) -> list[tuple[tuple[int, int], bool]]:
    """Where to write each road user's tag ``texts[i]`` near its centre ``anchors[i]`` (px) so that no two tags
    overlap and as few as can cover a road user: of the :data:`TAG_OFFSETS` whose text box meets no tag placed
    before (earlier road users keep theirs), the first that covers the fewest other road users (``shapes``: each
    one's drawn box, x0, y0, x1, y1 px, in the order of ``anchors``); the first offset where every one meets a tag.
    Returns each tag's text origin (lower left, px) and whether it moved from the first offset (then a thin line
    joins it to its road user). A crowd of pedestrians at a kerb wrote their ids over each other (dad_000487's 10,
    14, 16)."""
    shapes = shapes or []
    placed: list[tuple[int, int, int, int]] = []
    out: list[tuple[tuple[int, int], bool]] = []
    for i, ((ax, ay), text) in enumerate(zip(anchors, texts, strict=True)):
        others = shapes[:i] + shapes[i + 1 :]
        (w, h), base = cv2.getTextSize(text, cv2.FONT_HERSHEY_SIMPLEX, TAG_SCALE, 1)
        boxes = []
        for dx, dy, left in TAG_OFFSETS:
            x, y = ax + dx - (w if left else 0), ay + dy
            boxes.append(((x, y), (x - TAG_PAD_PX, y - h - TAG_PAD_PX, x + w + TAG_PAD_PX, y + base + TAG_PAD_PX)))
        free = [k for k, (_, b) in enumerate(boxes) if not any(_meet(b, q) for q in placed)]
        k = min(free, key=lambda k: (sum(_meet(boxes[k][1], q) for q in others), k)) if free else 0
        placed.append(boxes[k][1])
        out.append((boxes[k][0], k > 0))
    return out


def _meet(a: tuple[int, int, int, int], b: tuple[int, int, int, int]) -> bool:
    """Whether two pixel rectangles (x0, y0, x1, y1) overlap."""
    return a[0] < b[2] and b[0] < a[2] and a[1] < b[3] and b[1] < a[3]


def render_frames(scenario: Scenario, result: Any, stride: int | None = None) -> Any:
    """Yield BGR frames (HEIGHT, WIDTH, 3) of ``result`` (a ``SimResult``), one per ``stride`` steps."""
    dt = float(result.dt)
    stride = stride or max(1, int(round(1.0 / (FPS * dt))))
    sizes = {v.id: (v.length, v.width) for v in scenario.vehicles()}
    cats = {v.id: v.category for v in scenario.vehicles()}
    road = _road_lines(scenario)
    trail_n = int(round(TRAIL_S / dt))
    first = result.collision
    third = next((c for c in result.collisions if scenario.ego.id not in c["vehicles"]), None)
    hit_ids = {i for c in result.collisions for i in c["vehicles"]}
    hit_times: dict[int, float] = {}
    for c in result.collisions:
        for i in c["vehicles"]:
            hit_times.setdefault(i, c["time"])
    for k in range(0, len(result.times), stride):
        t = float(result.times[k])
        ego = result.states[k, 0]
        view = _View(np.array([ego[0] + AHEAD_M * np.cos(ego[2]), ego[1] + AHEAD_M * np.sin(ego[2])]))
        img = np.full((HEIGHT, WIDTH, 3), BG, np.uint8)
        cv2.fillPoly(img, [view.px(poly) for poly in road.polygons], ROAD)
        for e in road.edges:
            cv2.polylines(img, [view.px(e)], False, EDGE, 2, cv2.LINE_AA)
        for e in road.directions:
            cv2.polylines(img, [view.px(e)], False, DIRECTIONS, 2, cv2.LINE_AA)
        for lane in road.lanes:
            pts = view.px(lane)
            for a in range(0, len(pts) - 1, 2):
                cv2.line(img, tuple(map(int, pts[a])), tuple(map(int, pts[a + 1])), LANE, 1, cv2.LINE_AA)
        lo = max(0, k - trail_n)
        tags: list[tuple[tuple[int, int], str]] = []  # (centre px, tag), written once every box is drawn
        shapes: list[tuple[int, int, int, int]] = []  # each drawn road user's bounding box (px)
        for i, vid in enumerate(result.vehicle_ids):
            pres = result.present[lo : k + 1, i]
            if pres.sum() >= 2:
                tr = result.states[lo : k + 1, i, :2][pres]
                cv2.polylines(img, [view.px(tr)], False, EGO if i == 0 else (120, 120, 120), 1, cv2.LINE_AA)
            if not result.present[k, i]:
                continue
            x, y, yaw, _ = result.states[k, i]
            cat = cats[vid]
            own = EGO if i == 0 else PEDESTRIAN if cat == "pedestrian" else TWO_WHEELER if cat in SHORT else AGENT
            colour = HIT if vid in hit_ids and t >= hit_times[vid] else own
            p = view.px(np.array([[x, y]]))[0]
            if cat == "pedestrian":
                r = max(3, int(round(0.5 * max(sizes[vid]) * PX_PER_M)))
                cv2.circle(img, (int(p[0]), int(p[1])), r, colour, -1, cv2.LINE_AA)
                cv2.circle(img, (int(p[0]), int(p[1])), r, (20, 20, 20), 1, cv2.LINE_AA)
                shapes.append((int(p[0]) - r, int(p[1]) - r, int(p[0]) + r, int(p[1]) + r))
            else:
                pts = view.px(_box(x, y, yaw, *sizes[vid]))
                cv2.fillPoly(img, [pts], colour, cv2.LINE_AA)
                cv2.polylines(img, [pts], True, (20, 20, 20), 1, cv2.LINE_AA)
                cv2.line(img, tuple(map(int, pts[0])), tuple(map(int, pts[3])), (20, 20, 20), 3, cv2.LINE_AA)  # front
                (x0, y0), (x1, y1) = pts.min(axis=0), pts.max(axis=0)
                shapes.append((int(x0), int(y0), int(x1), int(y1)))
            tags.append(((int(p[0]), int(p[1])), f"{vid} {SHORT[cat]}" if cat in SHORT else str(vid)))
        where = place_tags([a for a, _ in tags], [t for _, t in tags], shapes)
        for (anchor, tag), (org, moved) in zip(tags, where, strict=True):
            if moved:
                cv2.line(img, anchor, (org[0], org[1] - 4), (150, 150, 150), 1, cv2.LINE_AA)
            _text(img, tag, org, TAG_SCALE, TEXT)
        label = f"t = {t:6.2f} s   ego {ego[3] * 3.6:5.1f} km/h   controller: {result.controller}"
        _text(img, label, (12, 26), 0.6, TEXT)
        if scenario.road.source == "road_users":
            _text(img, "road inferred from road users' paths (no lanes seen)", (12, HEIGHT - 44), 0.5, LANE)
        aeb = result.metrics.get("aeb_time")
        if aeb is not None and t >= aeb:
            _text(img, f"AEB braking since {aeb:.2f} s", (12, 52), 0.6, (0, 200, 255))
        if first is not None and t >= first["time"]:
            if first["point"] is not None:
                p = view.px(np.array([first["point"]]))[0]
                cv2.drawMarker(img, (int(p[0]), int(p[1])), HIT, cv2.MARKER_TILTED_CROSS, 22, 3)
            dv = result.metrics.get("delta_v_ego")
            txt = f"COLLISION at {first['time']:.2f} s with {first['vehicles'][1]}"
            if dv is not None:
                txt += f"  ego delta-v {dv:.1f} m/s"
            _text(img, txt, (12, HEIGHT - 18), 0.65, HIT, 2)
        if third is not None and t >= third["time"]:
            if third["point"] is not None:
                p = view.px(np.array([third["point"]]))[0]
                cv2.drawMarker(img, (int(p[0]), int(p[1])), HIT, cv2.MARKER_TILTED_CROSS, 22, 3)
            a, b = third["vehicles"]
            _text(img, f"CONTACT of {a} and {b} at {third['time']:.2f} s", (12, 78), 0.6, HIT, 2)
        yield img


def write_birdseye(
    scenario: Scenario, result: Any, path: str | os.PathLike[str], force: bool = False, fps: float = FPS
) -> str:
    """Write the bird's-eye H.264 MP4 of ``result`` to ``path`` atomically; returns the path."""
    stride = max(1, int(round(1.0 / (fps * float(result.dt)))))
    rate = round(1.0 / (stride * float(result.dt)))
    with h264_writer(path, WIDTH, HEIGHT, rate, force, crf=24) as write:
        for img in render_frames(scenario, result, stride):
            write(img)
    return str(path)
