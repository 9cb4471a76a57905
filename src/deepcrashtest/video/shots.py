"""Shot cuts in a video: crash videos found online are often compilations of several clips.

A scenario must never span a cut (the ego and every track jump). :func:`detect_shots` decodes the
video once with this package's own frame source (so frame numbers are those of ``extract``; extract's
own pass feeds a :class:`ShotWatch` instead of decoding twice), feeds frames shrunk to
``ANALYSIS_WIDTH`` pixels to PySceneDetect's ``AdaptiveDetector`` (PyPI
``scenedetect-headless``) and returns the shots as frame ranges.

Why the adaptive detector: a dashcam crash has exactly the fast content changes that fire a fixed
threshold (the jolt, glass, a car filling the view). The adaptive detector compares each frame's
change with its neighbours' and only keeps isolated peaks, i.e. cuts. ``MIN_SHOT_S`` keeps a flash
or a few garbled frames from making a shot of their own. Chosen on the 6 DAD + 13 CCD crash clips
(no cut found in any of them) and on compilations of two of them (the join found at the exact frame):
tests/test_roadusers.py.

Repeated frames (a video re-encoded at a higher frame rate repeats its frames; a frozen stretch) are
not fed to the detector: between repeats the change is nil, so every real frame-to-frame change looks
like an isolated peak over its neighbours and the adaptive detector cut a 10 fps clip re-encoded at
25/30 fps into shots. A frame whose mean absolute grey change from the last frame fed is under
``REPEAT_MAX_CHANGE`` is a repeat (measured at ``ANALYSIS_WIDTH``: repeats <= 0.1 grey levels after an
H.264 re-encode at crf 20-35, consecutive distinct frames of the DAD/CCD clips >= 5.5; tests/test_robust_variants.py).
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from deepcrashtest.video.source import open_video

ANALYSIS_WIDTH = 320  # pixels: enough for cut detection, ~16x fewer pixels than 1280x720
MIN_SHOT_S = 0.5
ADAPTIVE_THRESHOLD = 3.0  # PySceneDetect's default: the frame's change over its neighbours' mean
MIN_CONTENT_VAL = 15.0  # PySceneDetect's default: least absolute change of a cut
REPEAT_MAX_CHANGE = 1.0  # grey levels (0-255), mean absolute change: a repeated frame (module docstring)


@dataclass(frozen=True)
class Shot:
    """One continuous shot: frames ``first_frame`` .. ``last_frame`` (inclusive, video frame numbers)."""

    index: int
    first_frame: int
    last_frame: int
    fps: float

    @property
    def start_s(self) -> float:
        """Video time of the first frame, seconds."""
        return self.first_frame / self.fps

    @property
    def end_s(self) -> float:
        """Video time just after the last frame, seconds."""
        return (self.last_frame + 1) / self.fps

    @property
    def frames(self) -> int:
        return self.last_frame - self.first_frame + 1


class ShotWatch:
    """Cut detection fed one frame at a time, in order (``extract`` feeds it from its own decoding
    pass, so a video without cuts, the usual case, is decoded once and not scanned beforehand)."""

    def __init__(self, fps: float) -> None:
        from scenedetect import AdaptiveDetector

        self.fps = float(fps)
        min_len = max(2, int(round(MIN_SHOT_S * self.fps)))
        self._detector = AdaptiveDetector(
            adaptive_threshold=ADAPTIVE_THRESHOLD, min_scene_len=min_len, min_content_val=MIN_CONTENT_VAL
        )
        self.cuts: list[int] = []
        self.first: int | None = None
        self.last: int | None = None
        self._grey: np.ndarray | None = None  # the last frame fed to the detector, grey

    def feed(self, index: int, image: np.ndarray) -> bool:
        """Look at video frame ``index`` (BGR); True when a cut has been found so far."""
        import cv2
        from scenedetect import FrameTimecode

        h, w = image.shape[:2]
        if w > ANALYSIS_WIDTH:
            size = (ANALYSIS_WIDTH, max(1, round(h * ANALYSIS_WIDTH / w)))
            image = cv2.resize(image, size, interpolation=cv2.INTER_AREA)
        if self.first is None:
            self.first = index
        self.last = index
        grey = cv2.cvtColor(image, cv2.COLOR_BGR2GRAY) if image.ndim == 3 else image
        if self._grey is not None and self._grey.shape == grey.shape:
            if float(cv2.absdiff(grey, self._grey).mean()) < REPEAT_MAX_CHANGE:
                return bool(self.cuts)  # a repeat of the last frame fed: no change to weigh
        self._grey = grey
        found = self._detector.process_frame(FrameTimecode(int(index), fps=self.fps), np.ascontiguousarray(image))
        self.cuts.extend(int(c.frame_num) for c in found)
        return bool(self.cuts)

    def shots(self) -> list[Shot]:
        """The shots of the frames fed so far (call once, after the last frame)."""
        from scenedetect import FrameTimecode

        if self.first is None or self.last is None:
            return []
        first, last = self.first, self.last
        self.cuts.extend(int(c.frame_num) for c in self._detector.post_process(FrameTimecode(int(last), fps=self.fps)))
        bounds = [first, *sorted(c for c in set(self.cuts) if first < c <= last), last + 1]
        return [Shot(i, a, b - 1, self.fps) for i, (a, b) in enumerate(zip(bounds[:-1], bounds[1:], strict=True))]


def detect_shots(path: str | Path, fps: float | None = None, max_frames: int | None = None) -> list[Shot]:
    """The shots of the video (or image folder) at ``path``, in order; one shot when there is no cut."""
    with open_video(Path(path), fps) as source:
        watch = ShotWatch(float(source.meta.fps))
        for k, frame in enumerate(source):
            if max_frames is not None and k >= max_frames:
                break
            watch.feed(int(frame.index), frame.image)
    return watch.shots()


def cut_times(shots: list[Shot]) -> list[float]:
    """Video times (s) of the cuts between consecutive shots."""
    return [round(s.start_s, 3) for s in shots[1:]]
