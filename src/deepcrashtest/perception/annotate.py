"""Draw tracked boxes, ids and short trails on frames (for ``annotated.mp4``).

Solid boxes were detected in that frame, thin ones carried by optical flow between two of the detector's
calls; a dashed box with a ``?`` after its label is a road user the detector's last call(s) did not see
(``TrackedBox.missed``): the tracker carries it on its last motion while it may be hidden behind a nearer road
user (ccd_001135: a car coasting 1.1 s across the windscreen of the car spinning in front of the ego), until it
is seen again or dropped. The trail is the path of the box's bottom centre over the last ``trail_s`` seconds.
Colours are fixed per id.
"""

from __future__ import annotations

import colorsys
from collections import deque

import numpy as np

from deepcrashtest.perception.track import FrameTracks


def id_colour(track_id: int) -> tuple[int, int, int]:
    """A distinct, stable BGR colour for a track id (golden-ratio hue steps)."""
    r, g, b = colorsys.hsv_to_rgb((track_id * 0.618033988749895) % 1.0, 0.85, 1.0)
    return int(b * 255), int(g * 255), int(r * 255)


class Annotator:
    """Stateful drawer: remembers each track's recent bottom-centre points for its trail."""

    def __init__(self, fps: float, trail_s: float = 1.0) -> None:
        self.trail_len = max(2, int(round(trail_s * fps)))
        self._trails: dict[int, deque[tuple[int, int]]] = {}
        self._last_seen: dict[int, int] = {}

    def draw(self, ft: FrameTracks) -> np.ndarray:
        """A copy of ``ft.frame.image`` with boxes, ``id class`` labels, trails and the frame time."""
        import cv2

        img = ft.frame.image.copy()
        n = ft.frame.index
        for b in ft.tracks:
            x1, y1, x2, y2 = (int(round(v)) for v in b.box)
            trail = self._trails.setdefault(b.track_id, deque(maxlen=self.trail_len))
            trail.append(((x1 + x2) // 2, y2))
            self._last_seen[b.track_id] = n
            colour = id_colour(b.track_id)
            if len(trail) > 1:
                cv2.polylines(img, [np.array(trail, np.int32).reshape(-1, 1, 2)], False, colour, 2, cv2.LINE_AA)
            if b.missed:
                dashed_rectangle(img, (x1, y1), (x2, y2), colour)
            else:
                cv2.rectangle(img, (x1, y1), (x2, y2), colour, 2 if b.state == "detected" else 1, cv2.LINE_AA)
            label = f"{b.track_id} {b.category}" + (" ?" if b.missed else "")
            (tw, th), _ = cv2.getTextSize(label, cv2.FONT_HERSHEY_SIMPLEX, 0.5, 1)
            ty = max(y1, th + 4)
            cv2.rectangle(img, (x1, ty - th - 4), (x1 + tw + 4, ty), colour, -1)
            cv2.putText(img, label, (x1 + 2, ty - 3), cv2.FONT_HERSHEY_SIMPLEX, 0.5, (0, 0, 0), 1, cv2.LINE_AA)
        stale = [k for k, last in self._last_seen.items() if n - last > self.trail_len]
        for k in stale:
            self._trails.pop(k, None)
            self._last_seen.pop(k, None)
        stamp = f"frame {n}  t={ft.frame.time:.2f}s  tracks {len(ft.tracks)}"
        cv2.putText(img, stamp, (10, 24), cv2.FONT_HERSHEY_SIMPLEX, 0.7, (0, 0, 0), 3, cv2.LINE_AA)
        cv2.putText(img, stamp, (10, 24), cv2.FONT_HERSHEY_SIMPLEX, 0.7, (255, 255, 255), 1, cv2.LINE_AA)
        return img


def dashed_rectangle(
    img: np.ndarray, p1: tuple[int, int], p2: tuple[int, int], colour: tuple[int, int, int], dash: int = 8
) -> None:
    """A one-pixel rectangle from ``p1`` to ``p2`` (px) in dashes of ``dash`` px with gaps as long, drawn in place."""
    import cv2

    (x1, y1), (x2, y2) = p1, p2
    for a, b in (((x1, y1), (x2, y1)), ((x2, y1), (x2, y2)), ((x2, y2), (x1, y2)), ((x1, y2), (x1, y1))):
        length = max(abs(b[0] - a[0]), abs(b[1] - a[1]))
        for start in range(0, max(length, 1), 2 * dash):
            end = min(start + dash, length)
            s, e = start / max(length, 1), end / max(length, 1)
            pa = (int(round(a[0] + s * (b[0] - a[0]))), int(round(a[1] + s * (b[1] - a[1]))))
            pb = (int(round(a[0] + e * (b[0] - a[0]))), int(round(a[1] + e * (b[1] - a[1]))))
            cv2.line(img, pa, pb, colour, 1, cv2.LINE_AA)
