"""The size frames are processed at: light to import (the command line reads the default before any command runs).

Frames wider than ``max_width`` are processed scaled down to it (``extract --max-width``,
:func:`deepcrashtest.video.source.open_video`). The detector's input is ~864x480 whatever the frame's size and
ego-motion works at 960 px, so a 1920x1080 or 4K frame gives them nothing more, while decoding it to BGR, its
optical flow, lanes and the annotated video cost 2.25-9x the pixels, and the calibration buffer (2 s of frames)
held 1.5 GB of a 4K clip at 30 fps. The pipeline's pixel settings were chosen on 1280x720 clips (the crash
clips, the highway clip).
"""

#: Frames wider than this (px) are processed scaled down to it by default (``extract --max-width``).
DEFAULT_MAX_WIDTH = 1280
#: The narrowest ``--max-width`` (px) accepted.
MIN_MAX_WIDTH = 160


def processed_size(width: int, height: int, max_width: int | None) -> tuple[int, int]:
    """The size (px) a ``width`` x ``height`` frame is processed at: as it is, or scaled to ``max_width``
    wide when wider, its height keeping the aspect (rounded to an even number: H.264 needs even sides)."""
    if max_width is None or width <= max_width:
        return int(width), int(height)
    return int(max_width), max(2, 2 * round(height * max_width / width / 2))
