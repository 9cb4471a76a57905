"""H.264 MP4 writing for rendered videos: a context-manager face of :class:`deepcrashtest.video.writer.VideoWriter`."""

from __future__ import annotations

import os
from collections.abc import Callable, Iterator
from contextlib import contextmanager

import numpy as np

from deepcrashtest.video.writer import VideoWriter


@contextmanager
def h264_writer(
    path: str | os.PathLike[str],
    width: int,
    height: int,
    rate: int,
    force: bool = False,
    crf: int = 24,
    preset: str = "veryfast",
) -> Iterator[Callable[[np.ndarray], None]]:
    """Open an H.264 (yuv420p) MP4 at ``path``, written atomically; yields ``write(frame)``.

    ``frame``: (height, width, 3) uint8 BGR image. ``rate``: frames per second. The file appears
    at ``path`` only when the block finishes without an exception (refused if it exists, unless
    ``force``).
    """
    with VideoWriter(os.fspath(path), rate, width, height, force=force, crf=crf, preset=preset) as writer:
        yield writer.write
