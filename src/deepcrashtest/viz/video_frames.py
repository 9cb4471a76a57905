"""Random access to the frames of a video by time (PyAV), for the viewer and the report.

Seeking goes to the key frame at or before the requested time and decodes forward; a request a
little after the previous one (playback) decodes on from where the last one stopped.
"""

from __future__ import annotations

import itertools
import threading
from pathlib import Path
from typing import Any

import numpy as np

from deepcrashtest.errors import UserError
from deepcrashtest.video.source import display_array, display_size, main_video_stream

#: Decode on instead of seeking when the requested time is at most this far ahead (seconds).
_DECODE_AHEAD_S = 2.0
#: A seek that lands past the requested frame is tried again this much earlier (s; inf: from the stream's start).
_SEEK_BACK_S = (0.0, 1.0, 4.0, 16.0, float("inf"))


class VideoFrames:
    """Frames of one video file by time in seconds (thread-safe; one decoder)."""

    def __init__(self, path: str | Path) -> None:
        import av

        self.path = Path(path)
        try:
            self._container: Any = av.open(str(self.path))
        except (av.error.FFmpegError, OSError) as exc:  # type: ignore[attr-defined]
            raise UserError(f"{self.path}: cannot open video ({exc})") from None
        stream = main_video_stream(self._container)
        if stream is None:
            self._container.close()
            raise UserError(f"{self.path}: has no video stream")
        self._stream = stream
        rate = self._stream.average_rate or self._stream.guessed_rate
        self.fps = float(rate) if rate else 25.0
        tb = self._stream.time_base
        if self._stream.duration is not None and tb is not None:
            self.duration_s = float(self._stream.duration * tb)
        elif self._container.duration is not None:
            self.duration_s = self._container.duration / 1_000_000
        else:
            self.duration_s = (self._stream.frames or 0) / self.fps
        self.frame_count = int(self._stream.frames or round(self.duration_s * self.fps))
        start = self._stream.start_time
        self.start_s = float(start * tb) if start is not None and tb is not None else 0.0
        self._lock = threading.Lock()
        self._times_lock = threading.Lock()
        self._times: np.ndarray | None = None
        self._frames: Any = None
        self._last: tuple[float, np.ndarray] | None = None
        first = self._first_frame()
        if first is None:
            self.width = int(self._stream.codec_context.width)
            self.height = int(self._stream.codec_context.height)
        else:  # as players show it (square pixels, upright), like extract's frames
            self.width, self.height = display_size(first, self._stream.sample_aspect_ratio)

    def _first_frame(self) -> Any:
        """The first decoded frame (its rotation is per frame), or None when none decodes (the next request seeks
        back to the start)."""
        import av

        try:
            frame = next(iter(self._container.decode(self._stream)), None)
        except (av.error.FFmpegError, OSError):  # type: ignore[attr-defined]
            frame = None
        self._frames = None
        return frame

    def _shown(self, frame: Any) -> np.ndarray:
        return display_array(frame, "rgb24", self._stream.sample_aspect_ratio)

    def info(self) -> dict[str, Any]:
        return {
            "path": self.path.name,
            "fps": self.fps,
            "duration_s": self.duration_s,
            "frame_count": self.frame_count,
            "width": self.width,
            "height": self.height,
        }

    def frame(self, index: int) -> np.ndarray:
        """The RGB frame number ``index`` (0-based, in the order frames are shown, clamped to the video): at its own
        timestamp, which the file's packets list (a phone's variable frame rate: frame k is not at k / fps), else at
        the stream's start + ``index`` / fps."""
        times = self.frame_times()
        if times is None:
            return self.frame_at(self.start_s + index / self.fps)
        k = min(max(int(index), 0), len(times) - 1)
        gaps = np.diff(times[max(k - 1, 0) : k + 2])
        half = 0.5 * float(gaps[gaps > 0].min()) if np.any(gaps > 0) else 0.5 / self.fps
        return self._decoded_at(float(times[k]), min(half, 0.5 / self.fps))

    def frame_times(self) -> np.ndarray | None:
        """Every frame's timestamp (s, the stream's clock, in the order shown) from the file's packets (read once,
        without decoding), or None where a packet has none (the frame's place then comes from the frame rate)."""
        with self._times_lock:
            if self._times is None:
                self._times = _packet_times(self.path, self._stream.index)
            return self._times if len(self._times) else None

    def frame_at(self, t: float) -> np.ndarray:
        """The RGB frame (H, W, 3) uint8 shown at time ``t`` seconds (clamped to the video)."""
        t = min(max(float(t), self.start_s), self.start_s + max(self.duration_s - 0.5 / self.fps, 0.0))
        return self._decoded_at(t, 0.5 / self.fps)

    def _decoded_at(self, t: float, within: float) -> np.ndarray:
        """The frame starting at or after ``t - within`` (s), the one the last request decoded if within of it."""
        with self._lock:
            if self._last is not None and abs(self._last[0] - t) <= within:
                return self._last[1]
            last_t = self._last[0] if self._last is not None else None
            if self._frames is None or last_t is None or not (last_t < t <= last_t + _DECODE_AHEAD_S):
                self._seek_before(t)
            img = self._decode_until(t, within)
            return img

    def _seek_before(self, t: float) -> None:
        """Seek so that decoding starts at or before the frame shown at ``t`` (s). A container without an index
        (an MPEG transport stream, a dashcam's ``.TS``) seeks by bytes and may land a few frames past the key frame
        it was asked for, or past the last one (the decoder then gives nothing until the next key frame): the
        frame shown would be a later one, or none near the end. Such a landing is tried again from further back
        (:data:`_SEEK_BACK_S`), at the last from the start."""
        for back in _SEEK_BACK_S:
            self._seek(t - back if np.isfinite(back) else None)
            first = self._next_decoded()
            if first is not None and (first.time is None or float(first.time) <= t + 0.5 / self.fps):
                self._frames = itertools.chain([first], self._frames)
                return

    def _next_decoded(self) -> Any:
        """The next decoded frame after a seek, or None (nothing decodes from there)."""
        import av

        try:
            return next(self._frames, None)
        except (av.error.FFmpegError, OSError):  # type: ignore[attr-defined]
            return None

    def _seek(self, t: float | None) -> None:
        """Seek to the key frame at or before ``t`` (s; None: the stream's start)."""
        tb = self._stream.time_base
        target = int(max(t, 0.0) / tb) if t is not None and tb else 0
        self._container.seek(target, stream=self._stream, backward=True, any_frame=False)
        self._frames = self._container.decode(self._stream)
        self._last = None

    def _decode_until(self, t: float, within: float) -> np.ndarray:
        """Decode forward to the frame nearest ``t``: the first one starting at or after ``t - within`` (s)."""
        last: Any = None
        for frame in self._frames:
            last = frame
            ft = float(frame.time) if frame.time is not None else 0.0
            if ft >= t - within:
                self._last = (ft, self._shown(frame))
                return self._last[1]
        self._frames = None  # end of stream: the next request seeks
        if last is not None:
            self._last = (float(last.time or 0.0), self._shown(last))
        if self._last is None:
            raise UserError(f"{self.path}: no frame could be decoded at {t:.3f} s")
        return self._last[1]

    def close(self) -> None:
        with self._lock:
            self._container.close()


def jpeg_bytes(rgb: np.ndarray, max_width: int = 960, quality: int = 85) -> bytes:
    """Encode an RGB frame as JPEG, scaled down to at most ``max_width`` pixels wide."""
    import cv2

    h, w = rgb.shape[:2]
    if w > max_width:
        rgb = cv2.resize(rgb, (max_width, round(h * max_width / w)), interpolation=cv2.INTER_AREA)
    ok, buf = cv2.imencode(".jpg", cv2.cvtColor(rgb, cv2.COLOR_RGB2BGR), [cv2.IMWRITE_JPEG_QUALITY, quality])
    if not ok:  # pragma: no cover - OpenCV always encodes uint8 RGB
        raise RuntimeError("JPEG encoding failed")
    return bytes(buf)


def _packet_times(path: Path, index: int) -> np.ndarray:
    """The presentation times (s, sorted: the order frames are shown) of stream ``index``'s packets in ``path``, read
    without decoding; empty where a packet has no timestamp or the file cannot be read again."""
    import av

    try:
        with av.open(str(path)) as container:
            stream = container.streams[index]
            tick = stream.time_base
            pts = [p.pts for p in container.demux(stream) if p.size]
    except (av.error.FFmpegError, OSError):  # type: ignore[attr-defined]
        return np.zeros(0)
    if not pts or any(p is None for p in pts) or tick is None:
        return np.zeros(0)
    return np.sort(np.asarray(pts, dtype=np.int64)) * float(tick)
