"""Draw tracked boxes, ids and short trails on frames (for ``annotated.mp4``).

Solid boxes were detected in that frame, thin ones carried by optical flow. The trail is the
path of the box's bottom centre over the last ``trail_s`` seconds. Colours are fixed per id.
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
            cv2.rectangle(img, (x1, y1), (x2, y2), colour, 2 if b.state == "detected" else 1, cv2.LINE_AA)
            label = f"{b.track_id} {b.category}"
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
