"""H.264 MP4 writing with PyAV, shared by every video the package renders (BGR frames from OpenCV)."""

from __future__ import annotations

import os
from collections.abc import Callable, Iterator
from contextlib import contextmanager

import av
import numpy as np

from deepcrashtest.fileio import atomic_path


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
    with atomic_path(path, force, suffix=".mp4") as tmp:
        container = av.open(str(tmp), mode="w", format="mp4")
        try:
            stream = container.add_stream("libx264", rate=rate)
            stream.width, stream.height, stream.pix_fmt = width, height, "yuv420p"
            stream.options = {"crf": str(crf), "preset": preset}

            def write(img: np.ndarray) -> None:
                for packet in stream.encode(av.VideoFrame.from_ndarray(img, format="bgr24")):
                    container.mux(packet)

            yield write
            for packet in stream.encode():
                container.mux(packet)
        finally:
            container.close()
