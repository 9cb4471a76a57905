"""Black bars around the picture (letterbox, pillarbox): online crash videos are often re-framed.

The camera's default field of view and principal point belong to the picture, not to the bars around it.
A bar is a run of rows (columns) at the frame's edge that stays black (every pixel's grey level under
``BAR_MAX_GREY``) in every frame looked at; bars count only in opposite pairs of about the same
thickness (a dark night sky alone is no letterbox), each at least ``BAR_MIN_SHARE`` of the frame.
Checked on letterboxed and pillarboxed variants of the DAD and CCD clips, none found on the clips
themselves (tests/test_robust_variants.py).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from deepcrashtest.video.source import open_video

BAR_MAX_GREY = 24  # grey level 0-255: the brightest pixel of a bar row or column (after re-encoding)
BAR_MIN_SHARE = 0.02  # of the frame's height (width): thinner edges are encoder padding, not bars
BAR_PAIR_TOL = 0.02  # of the frame's height (width): the two bars of a pair differ by at most this
SAMPLE_FRAMES = 8  # frames looked at, the first ones of the video


def _bar_pair(bright: np.ndarray) -> tuple[int, int]:
    """Thickness of the dark runs at both ends of a brightest-pixel profile, (0, 0) without a pair."""
    n = len(bright)
    lit = np.flatnonzero(bright >= BAR_MAX_GREY)
    if len(lit) == 0:
        return 0, 0  # a black frame: no picture to find
    a, b = int(lit[0]), int(n - 1 - lit[-1])
    if min(a, b) < BAR_MIN_SHARE * n or abs(a - b) > BAR_PAIR_TOL * n + 2:
        return 0, 0
    return a, b


def picture_area(images: list[np.ndarray]) -> tuple[int, int, int, int]:
    """The picture inside black bars, ``(x0, y0, x1, y1)`` pixels (x1, y1 exclusive); the whole frame
    when there are no bars."""
    h, w = images[0].shape[:2]
    peak = np.zeros((h, w), np.uint8)
    for im in images:  # the brightest channel of each pixel, over the frames (np.max(axis=2) is ~10x slower)
        for channel in (im[:, :, c] for c in range(im.shape[2])) if im.ndim == 3 else (im,):
            np.maximum(peak, channel, out=peak)
    top, bottom = _bar_pair(peak.max(axis=1))
    left, right = _bar_pair(peak.max(axis=0))
    return left, top, w - right, h - bottom


def video_picture_area(path: str | Path, fps: float | None = None) -> tuple[int, int, int, int] | None:
    """:func:`picture_area` of the first ``SAMPLE_FRAMES`` frames of a video (or image folder); None
    when it has no frame."""
    images = []
    with open_video(Path(path), fps) as source:
        for frame in source:
            images.append(frame.image)
            if len(images) == SAMPLE_FRAMES:
                break
    return picture_area(images) if images else None
