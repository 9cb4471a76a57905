"""The camera's global image motion per frame (the ego's jolt for :mod:`~deepcrashtest.perception.crash_detect`).

Its own module without pandas: ``extract`` builds one before its decoding pass starts, and the crash
detection's pandas then loads in the background while the first frames decode instead of before them.
"""

from __future__ import annotations

import cv2
import numpy as np


class GlobalMotion:
    """Per-frame global image translation (px at ``width`` columns) by phase correlation of
    consecutive downscaled grey frames (the upper part, away from the bonnet/dashboard). ``area``: the
    picture ``(x0, y0, x1, y1)`` (px) inside black bars; static bars would pull the shift toward zero
    (ccd_000132 letterboxed: its vertical jolt 0.6 -> 0.1 px, the crash found 0.7 s late)."""

    def __init__(
        self, width: int = 192, keep_rows: float = 0.75, area: tuple[int, int, int, int] | None = None
    ) -> None:
        self.width = width
        self.keep_rows = keep_rows
        self.area = area
        self._prev: np.ndarray | None = None
        self.frames: list[int] = []
        self.shift: list[tuple[float, float]] = []

    def update(self, frame_index: int, image: np.ndarray) -> None:
        if self.area is not None:
            x0, y0, x1, y1 = self.area
            image = image[y0:y1, x0:x1]
        h, w = image.shape[:2]
        small = cv2.resize(
            image[: int(h * self.keep_rows)], (self.width, max(8, int(self.width * h * self.keep_rows / w)))
        )
        grey = np.asarray(cv2.cvtColor(small, cv2.COLOR_BGR2GRAY) if small.ndim == 3 else small, np.float32)
        if self._prev is None or self._prev.shape != grey.shape:
            d = (0.0, 0.0)
        else:
            win = cv2.createHanningWindow(grey.shape[::-1], cv2.CV_32F)
            (dx, dy), _resp = cv2.phaseCorrelate(self._prev, grey, win)
            d = (float(dx), float(dy))
        self._prev = grey
        self.frames.append(int(frame_index))
        self.shift.append(d)

    def arrays(self) -> tuple[np.ndarray, np.ndarray]:
        """(frames (N,), shifts (N, 2) px)."""
        return np.array(self.frames, int), np.array(self.shift, float).reshape(-1, 2)
