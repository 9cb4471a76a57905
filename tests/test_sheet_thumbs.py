"""The report's contact sheet from the thumbnails extract keeps while it writes annotated.mp4 (no second decode).

Real data: the bundled highway clip's frames written through the project's H.264 writer, as extract does."""

from __future__ import annotations

import base64
import re
import shutil
from pathlib import Path

import cv2
import numpy as np

from deepcrashtest.video.source import open_video
from deepcrashtest.video.writer import VideoWriter
from deepcrashtest.viz.report import contact_sheet_section, sheet_frames
from deepcrashtest.viz.sheet_thumbs import SheetThumbs
from deepcrashtest.viz.video_frames import VideoFrames

SAMPLE_VIDEO = Path(__file__).resolve().parents[1] / "examples" / "highway_sample.mp4"
N = 60


def _write(path, kept: SheetThumbs | None = None, n: int = N) -> None:
    """The sample clip's first ``n`` frames, with a frame-number stamp, to ``path`` (and ``kept``)."""
    with open_video(SAMPLE_VIDEO) as src, VideoWriter(path, src.meta.fps, src.meta.width, src.meta.height) as w:
        for frame in src:
            if frame.index >= n:
                break
            img = frame.image.copy()
            cv2.putText(img, str(frame.index), (40, 200), cv2.FONT_HERSHEY_SIMPLEX, 5, (0, 0, 255), 8)
            w.write(img)
            if kept is not None:
                kept.add(img)


def _sheet(body: str) -> np.ndarray:
    (b64,) = re.findall(r'src="data:image/jpeg;base64,([A-Za-z0-9+/=]+)"', body)
    return cv2.imdecode(np.frombuffer(base64.b64decode(b64), np.uint8), cv2.IMREAD_COLOR)


def test_kept_thumbnails_are_the_written_frames(tmp_path):
    video = tmp_path / "annotated.mp4"
    kept = SheetThumbs(25.0, 1280, 720, expected=N)
    _write(video, kept)
    vf = VideoFrames(video)
    assert kept.count == vf.frame_count == N
    assert kept.frame(8) is None  # not a sheet frame: not kept
    for i in sheet_frames(N, 12):
        decoded = cv2.resize(vf.frame(i), kept.size, interpolation=cv2.INTER_AREA).astype(float)
        own = kept.frame(i)
        assert own is not None and own.shape == decoded.shape
        # the same frame (only H.264's loss apart); the neighbour frames differ more
        assert np.abs(own - decoded).mean() < 2.5
        neighbour = cv2.resize(vf.frame(i + 1), kept.size, interpolation=cv2.INTER_AREA).astype(float)
        assert np.abs(own - neighbour).mean() > np.abs(own - decoded).mean()
    vf.close()


def test_sheet_needs_no_video_with_kept_thumbnails(tmp_path):
    video = tmp_path / "annotated.mp4"
    kept = SheetThumbs(25.0, 1280, 720, expected=N)
    _write(video, kept)
    decoded = contact_sheet_section(video)
    shutil.move(video, tmp_path / "gone.mp4")  # the sheet from the kept thumbnails opens no video
    own = contact_sheet_section(video, kept=kept)
    assert re.sub("<img.*", "", own.body) == re.sub("<img.*", "", decoded.body)  # same caption, frames, times
    a, b = _sheet(own.body).astype(float), _sheet(decoded.body).astype(float)
    assert a.shape == b.shape and np.abs(a - b).mean() < 2.5


def test_frames_not_kept_are_decoded(tmp_path):
    """Only the evenly spaced frames are kept; another (the collision's) is decoded from the video."""
    from deepcrashtest.viz.report import _decoded_thumbs

    video = tmp_path / "annotated.mp4"
    kept = SheetThumbs(25.0, 1280, 720, expected=N)
    _write(video, kept)
    assert kept.frame(8) is None and all(kept.frame(i) is not None for i in sheet_frames(N, 12))
    (thumb,) = _decoded_thumbs(video, [8], kept.thumb_width)
    assert thumb.shape == kept.frame(sheet_frames(N, 12)[0]).shape  # type: ignore[union-attr]
    other = SheetThumbs(25.0, 1280, 720, expected=N + 1)  # a wrong frame count: the frames not kept are decoded
    _write(tmp_path / "b.mp4", other)
    own, decoded = contact_sheet_section(tmp_path / "b.mp4", kept=other), contact_sheet_section(tmp_path / "b.mp4")
    assert re.sub("<img.*", "", own.body) == re.sub("<img.*", "", decoded.body)
    assert np.abs(_sheet(own.body).astype(float) - _sheet(decoded.body)).mean() < 2.5
