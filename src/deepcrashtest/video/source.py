"""Streaming video input: video files through PyAV, numbered image folders through OpenCV.

``open_video(path, fps=None, max_width=None)`` returns a :class:`VideoSource`; iterating it yields one
:class:`Frame` at a time (BGR uint8, H x W x 3), so a whole clip is never held in memory. With ``max_width``
frames wider than that come scaled down to it (:func:`processed_size`; pixel areas averaged, at decoding):
``meta.width`` / ``meta.height`` are then the frames' size and ``meta.scaled_from`` the file's.
Times are seconds from the first frame. Problems with the input are one-line ``UserError``s;
a truncated file yields the frames that decoded and records a warning saying how many.
"""

from __future__ import annotations

import re
from collections.abc import Iterator
from dataclasses import dataclass, field
from fractions import Fraction
from pathlib import Path
from types import TracebackType
from typing import Any, Literal

import numpy as np

from deepcrashtest.errors import UserError
from deepcrashtest.fileio import require_file, sha256_file
from deepcrashtest.video.size import processed_size

#: File names taken for videos where a folder is read (``batch``): phones' and dashcams' containers (MP4 / QuickTime,
#: AVI, Matroska, WebM, MPEG transport streams of AVCHD and some dashcams, 3GP, MPEG program streams, Flash, Windows
#: Media).
#: ``extract`` opens any file FFmpeg reads, whatever its name.
VIDEO_SUFFIXES = (
    ".mp4", ".mov", ".m4v", ".avi", ".mkv", ".webm", ".ts", ".mts", ".m2ts", ".3gp", ".mpg", ".mpeg", ".flv", ".wmv",
    ".asf",
)  # fmt: skip
IMAGE_SUFFIXES = (".png", ".jpg", ".jpeg", ".bmp")


@dataclass(frozen=True)
class Frame:
    """One decoded frame: running ``index`` (file number for numbered image folders), ``time`` in
    seconds since the first frame, ``image`` BGR uint8 of shape (height, width, 3)."""

    index: int
    time: float
    image: np.ndarray


@dataclass
class VideoMeta:
    """What is known about an input before and while decoding it.

    ``frame_count`` is the container's count (estimated from duration x fps where the container
    has none); ``decoded_frames`` counts the frames actually yielded so far (final after a full pass).
    ``sha256`` is the file's hash (None for image folders). ``warnings`` collects non-fatal problems.
    """

    path: Path
    kind: Literal["video", "image_folder"]
    fps: float
    frame_count: int
    width: int
    height: int
    sha256: str | None
    decoded_frames: int = 0
    warnings: list[str] = field(default_factory=list)
    #: (lowest, highest) frame rate (1/s) between consecutive decoded frames' timestamps when they vary by more
    #: than the timestamps' rounding (a variable-frame-rate video; ``fps`` is then the mean); None: constant
    rate_range: tuple[float, float] | None = None
    #: The file's frame size (width, height px) when the frames are yielded scaled to ``width`` x ``height``
    #: (``open_video(max_width=...)``); None: as stored.
    scaled_from: tuple[int, int] | None = None
    #: The time (s) of every frame yielded so far, by index: a variable-frame-rate file's frames are not
    #: ``index / fps`` apart (``rate_range``), and the Scenario keeps these times then (``VideoSource.frame_times``).
    frame_times: list[float] = field(default_factory=list)

    @property
    def stored_size(self) -> tuple[int, int]:
        """The file's frame size (width, height px), whether or not the frames are scaled."""
        return self.scaled_from or (self.width, self.height)

    def variable_frame_times(self) -> list[float] | None:
        """Every frame's time (s, by index, rounded to the microsecond) where the file's frame rate varies
        (``rate_range``: the one rule of what a variable rate is), else None (frames ``index / fps`` apart); the
        Scenario's ``VideoSource.frame_times`` and the monocular filter's steps come from it."""
        if self.rate_range is None or not self.frame_times:
            return None
        return [round(float(t), 6) for t in self.frame_times]

    @property
    def scale(self) -> float:
        """Frame px per file px (1.0 unless the frames are scaled)."""
        return self.width / self.stored_size[0]

    def as_dict(self) -> dict[str, Any]:
        return {
            "path": str(self.path),
            "kind": self.kind,
            "fps": self.fps,
            "frame_count": self.frame_count,
            "width": self.width,
            "height": self.height,
            "sha256": self.sha256,
            "decoded_frames": self.decoded_frames,
            "warnings": list(self.warnings),
            "scaled_from": None if self.scaled_from is None else list(self.scaled_from),
        }


class VideoSource:
    """Base of the two readers: ``meta``, iteration over frames, context manager, ``close()``."""

    meta: VideoMeta

    def __iter__(self) -> Iterator[Frame]:  # pragma: no cover - overridden
        raise NotImplementedError

    def close(self) -> None:
        """Release file handles (idempotent)."""

    def __enter__(self) -> VideoSource:
        return self

    def __exit__(self, et: type[BaseException] | None, ev: BaseException | None, tb: TracebackType | None) -> None:
        self.close()


MIN_FPS = 0.01  # frames per second: one frame in 100 s (the H.264 writer's rate is a fraction over <= 1001)
MAX_FPS = 10_000.0  # the Scenario schema's limit of source.fps (video/ stays free of pydantic)


def check_fps(fps: float | None) -> None:
    """Refuse a frame rate (``--fps``, 1/s) outside ``MIN_FPS``-``MAX_FPS`` (the Scenario's limit of
    ``source.fps``), NaN and inf too, in one line; None (the container's rate) passes."""
    if fps is not None and not (np.isfinite(fps) and MIN_FPS <= fps <= MAX_FPS):
        raise UserError(f"--fps must be a positive number of frames per second, {MIN_FPS:g}-{MAX_FPS:g} (got {fps})")


def open_video(path: str | Path, fps: float | None = None, max_width: int | None = None) -> VideoSource:
    """Open a video file or a folder of numbered images (``fps`` required for folders).

    For video files ``fps`` overrides the container's frame rate (frame times become index / fps).
    ``max_width`` (px): frames wider than this are scaled down to it (:func:`processed_size`).
    """
    p = Path(path)
    check_fps(fps)
    if p.is_dir():
        return ImageFolderSource(p, fps, max_width)
    return PyAVSource(p, fps, max_width)


def _scale_meta(meta: VideoMeta, max_width: int | None) -> None:
    """Make ``meta`` describe its frames scaled by :func:`processed_size` (unchanged when they are not)."""
    size = processed_size(meta.width, meta.height, max_width)
    if size != (meta.width, meta.height):
        meta.scaled_from = (meta.width, meta.height)
        meta.width, meta.height = size


# --------------------------------------------------------------------------- video files
class PyAVSource(VideoSource):
    """A video file decoded with PyAV (FFmpeg), frame by frame."""

    def __init__(self, path: Path, fps: float | None = None, max_width: int | None = None) -> None:
        import av

        require_file(path, "video file")
        self._path = path
        self._fps_override = fps
        try:
            self._container: Any = av.open(str(path))
        except (av.error.FFmpegError, UnicodeDecodeError) as exc:
            if _is_unfinished_mp4(path):
                raise UserError(
                    f"{path}: truncated mp4/mov: the index ('moov' box) is missing, the recording was cut off "
                    "before it was finalised; no frame can be located"
                ) from None
            raise UserError(f"{path}: not a readable video ({_short(exc)})") from None
        stream = main_video_stream(self._container)
        if stream is None:
            self._container.close()
            still = " (only a still picture: a cover or thumbnail)" if self._container.streams.video else ""
            raise UserError(f"{path}: contains no video stream{still}")
        stream.thread_type = "AUTO"
        self._stream = stream
        rate = stream.average_rate or stream.guessed_rate or stream.base_rate
        container_fps = float(rate) if rate else 0.0
        use_fps = fps if fps is not None else container_fps
        if not use_fps or not np.isfinite(use_fps) or use_fps <= 0:
            self._container.close()
            raise UserError(f"{path}: frame rate unknown; give it with --fps")
        self._decoder = self._container.decode(stream)
        self._first: Any = self._next_raw()
        if self._first is None:
            n_bad = self._bad
            self._container.close()
            why = f" ({n_bad})" if n_bad else ""
            raise UserError(f"{path}: no frame could be decoded (0-frame or unreadable video){why}")
        rotation = float(getattr(self._first, "rotation", 0) or 0)
        turns = _quarter_turns(rotation)
        if turns is None:
            self._container.close()
            raise UserError(
                f"{path}: video is stored rotated by {rotation:g} degrees (display matrix), not a multiple "
                "of 90; re-encode it upright first, e.g. ffmpeg -i IN -c:v libx264 OUT.mp4"
            )
        frames = int(stream.frames or 0)
        if frames <= 0:
            dur = _duration_s(self._container, stream)
            frames = int(round(dur * use_fps)) if dur else 0
        self._start = self._first.time if self._first.time is not None else 0.0
        self._square = _square_pixels(self._first.width, self._first.height, stream.sample_aspect_ratio)
        width, height = display_size(self._first, stream.sample_aspect_ratio)
        self.meta = VideoMeta(
            path=path,
            kind="video",
            fps=float(use_fps),
            frame_count=frames,
            width=width,
            height=height,
            sha256=sha256_file(path),
        )
        others = other_video_streams(self._container, stream)
        if others:
            self.meta.warnings.append(
                f"{path}: {len(others) + 1} video streams; reading stream {stream.index} ({_stream_text(stream)}), the "
                f"one players show, and leaving out {', '.join(f'{s.index} ({_stream_text(s)})' for s in others)}"
            )
        if self._square is not None:
            self.meta.warnings.append(
                f"{path}: pixels {stream.sample_aspect_ratio} as wide as high (sample aspect ratio); frames resampled "
                f"to square pixels, {self._first.width}x{self._first.height} -> {self._square[0]}x{self._square[1]}, "
                "as players show them"
            )
        if turns:
            self.meta.warnings.append(
                f"{path}: stored turned (display matrix rotation {rotation:g} degrees: a phone held upright or "
                "upside down); frames turned upright as players show them"
            )
        _scale_meta(self.meta, max_width)
        self._used = False

    _bad: str = ""

    def _next_raw(self) -> Any:
        """Next decoded av.VideoFrame, or None at the end / at the first undecodable packet."""
        import av

        try:
            return next(self._decoder)
        except StopIteration:
            return None
        except (av.error.FFmpegError, EOFError) as exc:
            self._bad = _short(exc)
            return None

    def __iter__(self) -> Iterator[Frame]:
        if self._used:
            raise UserError(f"{self._path}: a video source can be iterated once; open it again")
        self._used = True
        raw = self._first
        self._first = None
        index = 0
        last_t = -np.inf
        pts_ok = self._fps_override is None
        gaps = _FrameGaps(float(self._stream.time_base or 0.0))
        while raw is not None:
            t = float(raw.time - self._start) if pts_ok and raw.time is not None else np.nan
            if not t > last_t:  # missing or non-increasing timestamps (broken muxers): index / fps from here on
                if pts_ok and index > 0:
                    self.meta.warnings.append(
                        f"frame {index}: timestamps missing or not increasing; "
                        f"frame times are index / {self.meta.fps:g} fps"
                    )
                pts_ok = False
                t = index / self.meta.fps
            elif index > 0:
                self.meta.rate_range = gaps.add(t - last_t)
                if (note := gaps.recording_gap(index, t - last_t, self.meta.fps)) is not None:
                    self.meta.warnings.append(note)
            last_t = t
            resampled = self.meta.scaled_from is not None or self._square is not None
            image = display_array(raw, "bgr24", size=(self.meta.width, self.meta.height) if resampled else None)
            self.meta.decoded_frames = index + 1
            self.meta.frame_times.append(t)
            yield Frame(index=index, time=t, image=image)
            index += 1
            raw = self._next_raw()
        self._finish(index)

    def _finish(self, decoded: int) -> None:
        expected = self.meta.frame_count
        if self._bad or (expected and decoded < expected - 1):
            why = f": {self._bad}" if self._bad else ""
            self.meta.warnings.append(
                f"{self._path}: truncated or damaged video, decoded {decoded} of {expected or '?'} frames{why}"
            )
        self.close()

    def close(self) -> None:
        try:
            self._container.close()
        except Exception:  # noqa: BLE001 - closing twice or after an error is harmless
            pass


#: Frames further apart than this (s, and than 3 mean intervals) are a gap in the recording (:class:`_FrameGaps`).
RECORDING_GAP_S = 1.0
#: At most this many recording gaps are named in the warnings.
MAX_GAP_NOTES = 3


class _FrameGaps:
    """The shortest and longest interval (s) between consecutive frames' timestamps; ``add`` returns the
    (lowest, highest) frame rate (1/s) once they differ by more than their rounding, else None: a constant
    rate's intervals rounded to the stream's time base (``tick``, s) differ by at most one tick, and many
    recorders round timestamps to milliseconds whatever the container's time base (30 fps: 33 or 34 ms)."""

    def __init__(self, tick: float) -> None:
        self.tick = tick
        self.lo, self.hi = np.inf, 0.0
        self.gap_notes = 0

    def recording_gap(self, index: int, gap: float, fps: float) -> str | None:
        """A warning for a gap in the recording (frames ``index - 1`` and ``index`` more than
        :data:`RECORDING_GAP_S` and 3 mean intervals apart: a paused or cut recording, not a phone's dropped frame),
        the first :data:`MAX_GAP_NOTES` of them; None otherwise."""
        if gap <= max(RECORDING_GAP_S, 3.0 / fps if fps > 0 else 0.0):
            return None
        self.gap_notes += 1
        if self.gap_notes > MAX_GAP_NOTES:
            return None
        return (
            f"frames {index - 1} and {index} are {gap:.2f} s apart: a gap in the recording; what moved across it is "
            "not seen, only carried over it by the motion models"
        )

    def add(self, gap: float) -> tuple[float, float] | None:
        self.lo, self.hi = min(self.lo, gap), max(self.hi, gap)
        return (1.0 / self.hi, 1.0 / self.lo) if self.hi - self.lo > max(self.tick, 1e-3) + 1e-6 else None


def display_array(frame: Any, fmt: str = "bgr24", sar: Any = None, size: tuple[int, int] | None = None) -> np.ndarray:
    """A decoded PyAV frame as players show it, (H, W, 3) uint8 in ``fmt``: resampled to square pixels
    (``sar``: the stream's sample aspect ratio) and turned upright by its display matrix's rotation (a
    rotation off the right angles is left as stored); ``size`` (width, height px, upright): scaled to it
    (FFmpeg's swscale averaging areas: ~10 ms for a 4K frame against ~30 with cv2.resize after). Used by
    :func:`open_video`'s frames and by readers of a file outside it (the viewer's and the report's frames), so
    that every view of a video shows the frames extract saw."""
    turns = _quarter_turns(float(getattr(frame, "rotation", 0) or 0)) or 0
    if size is None:
        stored = _square_pixels(frame.width, frame.height, sar)
    else:
        stored = (size[1], size[0]) if turns % 2 else size  # the stored frame's orientation
    if stored is None:
        image = frame.to_ndarray(format=fmt)
    else:
        image = frame.to_ndarray(format=fmt, width=stored[0], height=stored[1], interpolation="AREA")
    return np.ascontiguousarray(np.rot90(image, turns)) if turns else image


def display_size(frame: Any, sar: Any = None) -> tuple[int, int]:
    """(width, height) px of a decoded PyAV frame as :func:`display_array` gives it (square pixels, upright)."""
    width, height = _square_pixels(frame.width, frame.height, sar) or (int(frame.width), int(frame.height))
    turns = _quarter_turns(float(getattr(frame, "rotation", 0) or 0)) or 0
    return (height, width) if turns % 2 else (width, height)


def _square_pixels(width: int, height: int, sar: Any) -> tuple[int, int] | None:
    """The frame size (px, even width) with square pixels for a stored ``width`` x ``height`` whose pixels are
    ``sar`` (the stream's sample aspect ratio, a Fraction or None) as wide as high; None when they are square
    (or the ratio is missing or implausible: outside 1/4-4, as an unset 0:1 reads)."""
    ratio = float(sar) if sar else 1.0
    if abs(ratio - 1.0) < 0.01 or not 0.25 <= ratio <= 4.0:
        return None
    return 2 * max(1, round(width * ratio / 2)), int(height)


def _quarter_turns(rotation_deg: float) -> int | None:
    """Counter-clockwise quarter turns (0-3) that bring a frame upright from its display matrix's rotation
    (PyAV's ``VideoFrame.rotation``: libavutil's ``av_display_rotation_get``, degrees), as FFmpeg's autorotate
    applies it (a phone's portrait clip tagged "rotate 90" reads -90: one quarter turn clockwise); None where the
    rotation is not a multiple of 90 degrees."""
    turns = rotation_deg / 90.0
    if abs(turns - round(turns)) > 1.0 / 90.0:
        return None
    return int(round(turns)) % 4


def main_video_stream(container: Any) -> Any | None:
    """The video stream of an opened PyAV container that players show: FFmpeg's best one (``av_find_best_stream``:
    moving pictures before a still one, then the default track, then the higher bit rate), never a cover picture
    or thumbnail (disposition ``attached_pic``, which a downloaded clip may carry as its first video stream); None
    without one."""
    import av

    still = int(av.stream.Disposition.attached_pic)
    moving = [s for s in container.streams.video if not int(s.disposition) & still]
    if not moving:
        return None
    best = container.streams.best("video")
    return best if best in moving else moving[0]


def other_video_streams(container: Any, stream: Any) -> list[Any]:
    """The container's video streams other than ``stream`` (a cover picture, a second camera)."""
    return [s for s in container.streams.video if s.index != stream.index]


def _stream_text(stream: Any) -> str:
    """``codec WxH`` of a video stream, e.g. ``h264 1280x720``."""
    ctx = stream.codec_context
    return f"{ctx.name} {ctx.width}x{ctx.height}"


def _duration_s(container: Any, stream: Any) -> float:
    if stream.duration and stream.time_base:
        return float(stream.duration * stream.time_base)
    if container.duration:
        return float(Fraction(container.duration, 1_000_000))
    return 0.0


def _is_unfinished_mp4(path: Path) -> bool:
    """An ISO-BMFF file (starts with an 'ftyp' box) that has media data but no 'moov' index."""
    with open(path, "rb") as fh:
        head = fh.read(12)
        if head[4:8] != b"ftyp":
            return False
        seen_mdat, tail = False, b""
        while block := fh.read(1 << 20):
            chunk = tail + block
            if b"moov" in chunk:
                return False
            seen_mdat = seen_mdat or b"mdat" in chunk
            tail = block[-3:]
    return seen_mdat


def _short(exc: BaseException) -> str:
    text = str(exc).strip().splitlines()[0] if str(exc).strip() else type(exc).__name__
    return text[:200]


# --------------------------------------------------------------------------- image folders
class ImageFolderSource(VideoSource):
    """A folder of images in name order (``000000.png``...; KITTI ``image_02/data`` or ``image_02/NNNN``).

    When every file name is a number, the frame index is that number and time is
    (number - first number) / fps, so gaps in the numbering stay gaps in time.
    """

    def __init__(self, folder: Path, fps: float | None, max_width: int | None = None) -> None:
        import cv2

        if fps is None:
            raise UserError(f"{folder}: an image folder needs its frame rate: give --fps")
        if (folder / "data").is_dir() and not _images_in(folder):
            folder = folder / "data"  # KITTI raw layout image_02/data/*.png
        files = _images_in(folder)
        if not files:
            raise UserError(f"{folder}: folder contains no images ({', '.join(IMAGE_SUFFIXES)})")
        stems = [f.stem for f in files]
        self._numbers = [int(s) for s in stems] if all(re.fullmatch(r"\d+", s) for s in stems) else None
        if self._numbers is not None:
            order = np.argsort(self._numbers, kind="stable")
            files = [files[i] for i in order]
            self._numbers = [self._numbers[i] for i in order]
        first = cv2.imread(str(files[0]), cv2.IMREAD_COLOR)
        if first is None:
            raise UserError(f"{files[0]}: not a readable image")
        self._files = files
        self.meta = VideoMeta(
            path=folder,
            kind="image_folder",
            fps=float(fps),
            frame_count=len(files),
            width=int(first.shape[1]),
            height=int(first.shape[0]),
            sha256=None,
        )
        _scale_meta(self.meta, max_width)

    def __iter__(self) -> Iterator[Frame]:
        import cv2

        base = self._numbers[0] if self._numbers else 0
        self.meta.decoded_frames = 0
        for k, f in enumerate(self._files):
            image = cv2.imread(str(f), cv2.IMREAD_COLOR)
            if image is None:
                self.meta.warnings.append(f"{f}: unreadable image, stopped after {k} frames")
                return
            stored = self.meta.stored_size
            if (image.shape[1], image.shape[0]) != stored:
                raise UserError(
                    f"{f}: image size {image.shape[1]}x{image.shape[0]} differs from the first "
                    f"({stored[0]}x{stored[1]})"
                )
            if self.meta.scaled_from is not None:
                image = cv2.resize(image, (self.meta.width, self.meta.height), interpolation=cv2.INTER_AREA)
            index = self._numbers[k] if self._numbers else k
            self.meta.decoded_frames = k + 1
            yield Frame(index=index, time=(index - base) / self.meta.fps, image=image)


def _images_in(folder: Path) -> list[Path]:
    return sorted(f for f in folder.iterdir() if f.is_file() and f.suffix.lower() in IMAGE_SUFFIXES)
