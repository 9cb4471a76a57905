"""Carry boxes from one frame to the next with pyramidal Lucas-Kanade optical flow (OpenCV).

Corners inside each box (inner 80 %) are tracked forwards and backwards on a grey image at most
``work_width`` px wide; points whose forward-backward error exceeds ``fb_max_px`` are dropped. A box
moves by the median point displacement and scales by the median ratio of point-pair distances.
Corners that lie inside the box of a road user in front of it (:func:`occluded_points`) are left out: they
are the passer-by's, and a parked car's box would otherwise be dragged along by a scooter passing in front.
Boxes with too few good points are reported as failed; the caller falls back to constant velocity.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

_WIN = (15, 15)
_LEVELS = 3
#: A box is in front of another (nearer on the road) when its bottom edge lies lower in the picture by more than
#: this share of the other's height.
IN_FRONT_BOTTOM_SHARE = 0.1


@dataclass
class GreyFrame:
    """A frame prepared for flow: grey uint8 at ``scale`` x the original size."""

    grey: np.ndarray
    scale: float


class BoxFlow:
    """Pyramidal-LK box propagation (all boxes of a frame in one LK call)."""

    def __init__(
        self, work_width: int = 640, max_points: int = 24, min_points: int = 4, fb_max_px: float = 1.0
    ) -> None:
        self.work_width = int(work_width)
        self.max_points = int(max_points)
        self.min_points = int(min_points)
        self.fb_max_px = float(fb_max_px)

    def prepare(self, image: np.ndarray) -> GreyFrame:
        import cv2

        h, w = image.shape[:2]
        scale = min(1.0, self.work_width / w)
        grey = cv2.cvtColor(image, cv2.COLOR_BGR2GRAY)
        if scale < 1.0:
            grey = cv2.resize(grey, (int(round(w * scale)), int(round(h * scale))), interpolation=cv2.INTER_AREA)
        return GreyFrame(grey, scale)

    def _points_in(self, grey: np.ndarray, box: np.ndarray) -> np.ndarray:
        """Corner points inside the inner 80 % of ``box`` (work pixels); a 5x5 grid if there are too few."""
        import cv2

        h, w = grey.shape
        bw, bh = box[2] - box[0], box[3] - box[1]
        x0 = int(np.clip(box[0] + 0.1 * bw, 0, w - 1))
        x1 = int(np.clip(box[2] - 0.1 * bw, 0, w))
        y0 = int(np.clip(box[1] + 0.1 * bh, 0, h - 1))
        y1 = int(np.clip(box[3] - 0.1 * bh, 0, h))
        if x1 - x0 < 3 or y1 - y0 < 3:
            return np.zeros((0, 2), np.float32)
        pts = cv2.goodFeaturesToTrack(grey[y0:y1, x0:x1], self.max_points, 0.01, 2, blockSize=3)
        if pts is None or len(pts) < self.min_points:
            gx, gy = np.meshgrid(np.linspace(x0, x1 - 1, 5), np.linspace(y0, y1 - 1, 5))
            return np.stack([gx.ravel(), gy.ravel()], axis=1).astype(np.float32)
        return (pts.reshape(-1, 2) + np.array([x0, y0], np.float32)).astype(np.float32)

    def propagate(self, prev: GreyFrame, cur: GreyFrame, boxes: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Boxes (N, 4, original pixels) in ``prev`` -> their boxes in ``cur`` and an (N,) success mask."""
        import cv2

        boxes = np.asarray(boxes, dtype=np.float64).reshape(-1, 4)
        out = boxes.copy()
        ok = np.zeros(len(boxes), dtype=bool)
        if not len(boxes):
            return out, ok
        s = prev.scale
        pts_list = [self._points_in(prev.grey, b * s) for b in boxes]
        pts_list = [p[~occluded_points(p / s, i, boxes)] for i, p in enumerate(pts_list)]
        owner = np.concatenate([np.full(len(p), i) for i, p in enumerate(pts_list)])
        p0 = np.concatenate(pts_list).reshape(-1, 1, 2).astype(np.float32)
        if not len(p0):
            return out, ok
        lk = cv2.calcOpticalFlowPyrLK
        p1, st1, _ = lk(prev.grey, cur.grey, p0, np.empty_like(p0), winSize=_WIN, maxLevel=_LEVELS)
        p0r, st2, _ = lk(cur.grey, prev.grey, p1, np.empty_like(p1), winSize=_WIN, maxLevel=_LEVELS)
        fb = np.linalg.norm((p0r - p0).reshape(-1, 2), axis=1)
        good = (st1.ravel() == 1) & (st2.ravel() == 1) & (fb <= self.fb_max_px)
        a, b = p0.reshape(-1, 2), p1.reshape(-1, 2)
        for i in range(len(boxes)):
            sel = good & (owner == i)
            if sel.sum() < self.min_points:
                continue
            pa, pb = a[sel], b[sel]
            d = np.median(pb - pa, axis=0) / s
            scale = _median_scale(pa, pb)
            cx, cy = (boxes[i, 0] + boxes[i, 2]) / 2 + d[0], (boxes[i, 1] + boxes[i, 3]) / 2 + d[1]
            hw, hh = (boxes[i, 2] - boxes[i, 0]) * scale / 2, (boxes[i, 3] - boxes[i, 1]) * scale / 2
            out[i] = (cx - hw, cy - hh, cx + hw, cy + hh)
            ok[i] = True
        return out, ok


def occluded_points(points: np.ndarray, i: int, boxes: np.ndarray) -> np.ndarray:
    """(n,) True for each of ``points`` (n, 2; x, y px) inside a box of ``boxes`` (N, 4; x1, y1, x2, y2 px) that
    stands in front of box ``i``: its bottom edge lower in the picture than box ``i``'s by more than
    :data:`IN_FRONT_BOTTOM_SHARE` of box ``i``'s height (on a road seen from above, the nearer road user)."""
    b = boxes[i]
    margin = IN_FRONT_BOTTOM_SHARE * max(b[3] - b[1], 1.0)
    front = boxes[(boxes[:, 3] > b[3] + margin) & (boxes[:, 0] < b[2]) & (boxes[:, 2] > b[0]) & (boxes[:, 1] < b[3])]
    if not len(front) or not len(points):
        return np.zeros(len(points), bool)
    x, y = points[:, 0:1], points[:, 1:2]
    inside = (x >= front[:, 0]) & (x <= front[:, 2]) & (y >= front[:, 1]) & (y <= front[:, 3])
    return inside.any(axis=1)


def _median_scale(pa: np.ndarray, pb: np.ndarray, max_pairs: int = 64) -> float:
    """Median ratio of distances between point pairs after / before, clamped to [0.9, 1.1] per frame."""
    n = len(pa)
    i, j = np.triu_indices(n, 1)
    if len(i) > max_pairs:
        step = len(i) // max_pairs
        i, j = i[::step], j[::step]
    da = np.linalg.norm(pa[i] - pa[j], axis=1)
    db = np.linalg.norm(pb[i] - pb[j], axis=1)
    keep = da > 2.0
    if keep.sum() < 3:
        return 1.0
    return float(np.clip(np.median(db[keep] / da[keep]), 0.9, 1.1))


# --------------------------------------------------------------------------- sparse scene points
def track_points(
    prev: np.ndarray,
    cur: np.ndarray,
    p0: np.ndarray,
    guess: np.ndarray | None = None,
    win: int = 15,
    levels: int = 3,
    fb_max_px: float = 0.5,
) -> tuple[np.ndarray, np.ndarray]:
    """Lucas-Kanade tracks of (N, 2) points from grey image ``prev`` to ``cur`` (pixels).

    ``guess`` (N, 2): predicted positions in ``cur`` (e.g. from the last frame's motion); LK starts
    there, which keeps large near-road displacements from converging short. A point is good when
    both directions converge and the backward track returns within ``fb_max_px``.
    Returns (positions in ``cur`` (N, 2) float32, good mask (N,)).
    """
    import cv2

    n = len(p0)
    if n == 0:
        return np.zeros((0, 2), np.float32), np.zeros(0, bool)
    a = np.ascontiguousarray(p0, np.float32).reshape(-1, 1, 2)
    crit = (cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, 20, 0.01)
    flags = 0
    b = a.copy()
    if guess is not None:
        b = np.ascontiguousarray(guess, np.float32).reshape(-1, 1, 2)
        flags = cv2.OPTFLOW_USE_INITIAL_FLOW
    lk = cv2.calcOpticalFlowPyrLK
    p1, st1, _ = lk(prev, cur, a, b, winSize=(win, win), maxLevel=levels, criteria=crit, flags=flags)
    back = p1.copy()  # p1 is near the truth: start the backward pass from p0, one pyramid level fewer
    back[:] = a
    p0r, st2, _ = lk(
        cur, prev, p1, back, winSize=(win, win), maxLevel=levels, criteria=crit, flags=cv2.OPTFLOW_USE_INITIAL_FLOW
    )
    fb = np.linalg.norm((p0r - a).reshape(-1, 2), axis=1)
    h, w = prev.shape[:2]
    q = p1.reshape(-1, 2)
    inside = (q[:, 0] >= 0) & (q[:, 1] >= 0) & (q[:, 0] <= w - 1) & (q[:, 1] <= h - 1)
    good = (st1.ravel() == 1) & (st2.ravel() == 1) & (fb <= fb_max_px) & inside
    return q.astype(np.float32), good


def top_up_corners(
    grey: np.ndarray,
    mask: np.ndarray,
    existing: np.ndarray,
    target: int,
    quality: float = 0.01,
    min_distance: int = 8,
    coarse: bool = False,
) -> np.ndarray:
    """New corners (M, 2) inside ``mask`` and at least ``min_distance`` px from ``existing`` points,
    so that ``len(existing) + M`` reaches about ``target``. Corners are reused from frame to frame;
    only the gaps are filled, inside the mask's bounding box (``quality`` is relative to the best
    corner there). ``coarse``: look for them at half resolution (4x cheaper; LK then tracks the
    patch around each point at full resolution, so nothing is lost but corner sharpness)."""
    import cv2

    need = int(target) - len(existing)
    if need <= max(4, target // 10):
        return np.zeros((0, 2), np.float32)
    m = mask.copy()
    for x, y in np.asarray(existing, np.float32).reshape(-1, 2):
        cv2.circle(m, (int(x), int(y)), int(min_distance), 0, -1)
    x0, y0, bw, bh = cv2.boundingRect(m)
    if bw < 8 or bh < 8:
        return np.zeros((0, 2), np.float32)
    g, mm = grey[y0 : y0 + bh, x0 : x0 + bw], m[y0 : y0 + bh, x0 : x0 + bw]
    f = 2.0 if coarse else 1.0
    if coarse:
        g = cv2.resize(g, (bw // 2, bh // 2), interpolation=cv2.INTER_AREA)
        mm = cv2.resize(mm, (bw // 2, bh // 2), interpolation=cv2.INTER_NEAREST)
    dist = max(1, int(round(min_distance / f)))
    pts = cv2.goodFeaturesToTrack(g, maxCorners=need, qualityLevel=quality, minDistance=dist, mask=mm)
    if pts is None:
        return np.zeros((0, 2), np.float32)
    return (pts.reshape(-1, 2) * f + np.array([x0, y0], np.float32)).astype(np.float32)
