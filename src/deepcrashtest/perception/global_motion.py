"""The camera's global image motion per frame (the ego's jolt for :mod:`~deepcrashtest.perception.crash_detect`).

A frame repeating the last one (a clip resampled to a higher frame rate repeats its frames: 10 -> 30 fps
each one three times; a frozen stretch) has no shift of its own (NaN): the whole motion of the next new
frame then lands on that frame alone, which made every third frame of a 10 fps clip at 30 fps a "jolt" to
its repeats' zero shifts (ccd_000330 at 30 fps: the ego crash found 0.73 s early). Repeats are told as the
shot watch tells them (``video.shots.REPEAT_MAX_CHANGE``, mean absolute grey change).

OpenCV's ``phaseCorrelate`` multiplies its inputs by the Hanning window in place, so each frame is
correlated against the previous one windowed twice (it was the current frame of the previous call): the
measure every jolt threshold was chosen on. Correlating unwindowed copies shifts the ego crashes' jolts
(on the 20 fidelity clips: ccd_000014 -0.2 -> 0.0 s, dad_000493 0.05 -> -0.15 s, ccd_000330 -0.1 ->
-0.5 s, a jolt 0.4 s before its contact): kept as it is until the thresholds are chosen again.

Its own module without pandas: ``extract`` builds one before its decoding pass starts, and the crash
detection's pandas then loads in the background while the first frames decode instead of before them.
"""

from __future__ import annotations

import cv2
import numpy as np

from deepcrashtest.video.shots import REPEAT_MAX_CHANGE


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
        self._last: np.ndarray | None = None  # the last frame as it came (the repeat test)
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
        last, self._last = self._last, grey.copy()
        if self._prev is None or self._prev.shape != grey.shape:
            d = (0.0, 0.0)
        elif last is not None and last.shape == grey.shape and np.abs(grey - last).mean() < REPEAT_MAX_CHANGE:
            self.frames.append(int(frame_index))
            self.shift.append((np.nan, np.nan))  # a repeat of the last frame: no motion (module docstring)
            return
        else:
            win = cv2.createHanningWindow(grey.shape[::-1], cv2.CV_32F)
            (dx, dy), _resp = cv2.phaseCorrelate(self._prev, grey, win)  # windows both in place (docstring)
            d = (float(dx), float(dy))
        self._prev = grey
        self.frames.append(int(frame_index))
        self.shift.append(d)

    def arrays(self) -> tuple[np.ndarray, np.ndarray]:
        """(frames (N,), shifts (N, 2) px; NaN at a repeated frame)."""
        return np.array(self.frames, int), np.array(self.shift, float).reshape(-1, 2)
