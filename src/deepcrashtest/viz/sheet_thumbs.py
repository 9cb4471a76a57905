"""Small copies of the annotated frames, kept while ``extract`` writes them, for the report's contact sheet.

The report's contact sheet (:func:`deepcrashtest.viz.report.contact_sheet_section`) shows 12 evenly spaced
frames of ``annotated.mp4`` (and the collision's frame in place of the nearest). Decoding the whole video again
for them cost ~1.1 s of CPU per 251 frames (x264 puts one key frame per 250); instead the draw + encode stage
hands every frame it writes to :class:`SheetThumbs`, which keeps a thumbnail (``thumb_width`` px wide,
OpenCV's area resize, as the sheet made from the decoded video) of each frame the sheet will show: 12 small
copies, whatever the clip's length. Keeping a thumbnail of every frame (for a collision frame, known only after
the pass) measured 0.69 s of CPU per 251 frames (resize + JPEG), most of what decoding costs; so a frame not
kept (the collision's, or all of them when the frame count differs from the one expected) is decoded from the
video by the report, seeking to the key frame before it.
"""

from __future__ import annotations

import threading
from typing import Any

import numpy as np

#: The contact sheet's thumbnail width (px) and number of evenly spaced frames.
SHEET_THUMB_WIDTH = 320
SHEET_FRAMES = 12
THUMB_MAX_ASPECT = 2.0  # height / width at most (a 9:16 portrait, 1.78, keeps the full width)


def thumb_size(width: int, height: int, thumb_width: int = SHEET_THUMB_WIDTH) -> tuple[int, int]:
    """A thumbnail's (width, height) px of a ``width`` x ``height`` frame: ``thumb_width`` wide, and no taller than
    ``THUMB_MAX_ASPECT`` x that (a sliver of a video, 2 x 400 px, made a 64,000-row sheet no JPEG can hold)."""
    scale = min(thumb_width / width, THUMB_MAX_ASPECT * thumb_width / height)
    return max(1, round(width * scale)), max(1, round(height * scale))


def sheet_frames(frame_count: int, frames: int, include: int | None = None) -> list[int]:
    """``frames`` frame indices evenly spread over a video of ``frame_count`` frames (middle of each slice);
    ``include`` (the collision's frame) takes the place of the nearest one."""
    if frame_count <= 0:
        return []
    k = min(frames, frame_count)
    out = sorted({int((i + 0.5) * frame_count / k) for i in range(k)})
    if include is not None and 0 <= include < frame_count and include not in out:
        out[int(np.argmin([abs(i - include) for i in out]))] = include
    return sorted(out)


class SheetThumbs:
    """Thumbnails (RGB, ``thumb_width`` px wide) of the frames written to an annotated video, by write order.

    ``expected``: the frame count the video will have, when known (its evenly spaced sheet frames are kept
    exactly); ``fps``, ``width``, ``height``: the written video's (the sheet's caption).
    """

    def __init__(
        self,
        fps: float,
        width: int,
        height: int,
        expected: int | None = None,
        thumb_width: int = SHEET_THUMB_WIDTH,
    ) -> None:
        self.fps, self.width, self.height = float(fps), int(width), int(height)
        self.thumb_width = int(thumb_width)
        self.size = thumb_size(self.width, self.height, self.thumb_width)
        self.count = 0
        self._sheet = set(sheet_frames(expected or 0, SHEET_FRAMES))
        self._raw: dict[int, np.ndarray] = {}
        self._lock = threading.Lock()

    def add(self, bgr: np.ndarray) -> None:
        """The next frame written (BGR uint8, the video's size)."""
        import cv2

        k = self.count
        self.count += 1
        if k in self._sheet:
            small = cv2.resize(bgr, self.size, interpolation=cv2.INTER_AREA)
            with self._lock:
                self._raw[k] = cv2.cvtColor(small, cv2.COLOR_BGR2RGB)

    def frame(self, index: int) -> np.ndarray | None:
        """The RGB thumbnail of written frame ``index``, or None when it was not kept."""
        with self._lock:
            return self._raw.get(index)

    def info(self) -> dict[str, Any]:
        """As :meth:`deepcrashtest.viz.video_frames.VideoFrames.info` of the written video."""
        return {
            "fps": self.fps,
            "duration_s": self.count / self.fps,
            "frame_count": self.count,
            "width": self.width,
            "height": self.height,
        }
