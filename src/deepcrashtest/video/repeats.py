"""Frames that show the last new picture again.

A clip re-encoded at a higher frame rate repeats its pictures (10 -> 30 fps: each one three times; 24 -> 30 fps:
every fourth twice), and a frozen stretch repeats one for longer. A repeat is no new view of the scene: a motion
measured across it is zero and the motion of the next new picture lands on one frame interval instead of the
several it took (KITTI odometry seq06 through H.264 at 30 fps, each frame three times: the ego-motion's median
speed error 23 % where the 10 fps original's is 0.6 %).

:class:`RepeatWatch` tells them by the 99.9th percentile of the absolute grey change from the last new picture,
both shrunk to ``WIDTH`` px by area averaging (float, no rounding): a few changed pixels, a scooter crossing a still
scene, make a new picture. H.264's noise on a repeated picture (the encoder refines it block by block) reaches 2.9
grey levels (ccd_000053 at 640 px re-encoded at 30 fps, crf 23; the four 30 fps robust variants <= 1.5), and the
stopped egos' still scenes change by as little from frame to frame (dad_000512 and its variants, dad_000528: from
3.6), so no one level parts them. A repeat is told against the video's own new pictures: under ``REPEAT_SHARE`` of
the upper quartile of the changes of the last ``HISTORY`` new ones (the quartile: a repeat taken for new before
the first new picture, where nothing is known yet, does not lower it), never above ``REPEAT_CHANGE_CAP`` (a moving
scene's new pictures change by 100 and more), never below ``REPEAT_CHANGE_FLOOR`` (a still scene's repeats are then
told only where they are as good as identical; measuring them changes nothing there). Measured in round repeat23:
the four 30 fps robust variants and the 13 CCD clips, every frame told right; dad_000512 (every variant) and
dad_000528, no frame taken for a repeat.
"""

from __future__ import annotations

from collections import deque

import cv2
import numpy as np

WIDTH = 80  # px of the shrunk frame the change is measured on
CHANGE_PERCENTILE = 99.9  # of the absolute grey change (0-255)
REPEAT_SHARE = 0.1  # a repeat changes less than this share of the recent new pictures' changes (docstring)
# Not video.shots.REPEAT_MAX_CHANGE: the shot watch and the camera jolt (perception.global_motion) keep that older rule
# (mean absolute change < 1 grey level at their own widths); their crash-detection inputs were tuned with it.
REPEAT_CHANGE_CAP = 6.0  # grey levels: above this no frame is a repeat
REPEAT_CHANGE_FLOOR = 1.5  # grey levels: below this every frame is one
HISTORY = 15  # new pictures whose changes are the reference


class RepeatWatch:
    """``repeats(image)``: whether a frame (BGR or grey, any size) shows the last new picture fed again."""

    def __init__(self, width: int = WIDTH) -> None:
        self.width = width
        self._last: np.ndarray | None = None  # the last new picture, shrunk
        self._changes: deque[float] = deque(maxlen=HISTORY)  # the last new pictures' changes

    def repeats(self, image: np.ndarray) -> bool:
        """True when ``image`` differs from the last new picture by no more than codec noise (module docstring);
        else it becomes the new reference (the first frame is new)."""
        grey = image if image.ndim == 2 else cv2.cvtColor(image, cv2.COLOR_BGR2GRAY)
        h, w = grey.shape[:2]
        size = (self.width, max(8, round(self.width * h / w)))
        small = cv2.resize(grey.astype(np.float32), size, interpolation=cv2.INTER_AREA)
        last, self._last = self._last, small
        if last is None or last.shape != small.shape:
            return False
        change = float(np.percentile(np.abs(small - last), CHANGE_PERCENTILE))
        typical = float(np.percentile(self._changes, 75)) if self._changes else 0.0
        if change < min(REPEAT_CHANGE_CAP, max(REPEAT_CHANGE_FLOOR, REPEAT_SHARE * typical)):
            self._last = last
            return True
        self._changes.append(change)
        return False
