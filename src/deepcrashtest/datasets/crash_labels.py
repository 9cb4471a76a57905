"""Crash labels made by eye for real crash clips (``bench/labels/*_crashes.json``).

File layout (JSON)::

    {"format": "deepcrashtest-crash-labels", "version": 1,
     "clips": {
       "dad_000478": {
         "video": "crash_dad/dad_000478.mp4",      # relative to the shared data folder
         "fps": 20.0,
         "crash": true,
         "contact_frame": 88,                       # first frame where the two participants touch
         "first_accident_frame": null,              # the dataset's own label, when it has one (CCD)
         "participants": [
           {"who": "ego"},
           {"who": "road_user", "box": [x1, y1, x2, y2], "category": "motorcycle"}
         ],
         "description": "one line"},
       "highway_project_video": {"video": "...", "fps": 25.0, "crash": false, "description": "..."}}}

Frames are 0-based indices of decoded frames; boxes are pixels of the full frame at
``contact_frame``; categories are the Scenario's road-user categories. A crash the labeller could
not see has ``contact_frame: null`` and no participants.
"""

from __future__ import annotations

import os
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any

from deepcrashtest.errors import UserError
from deepcrashtest.fileio import read_json, require_file
from deepcrashtest.scenario import ROAD_USER_CATEGORIES

LABEL_FORMAT = "deepcrashtest-crash-labels"


@dataclass(frozen=True)
class Participant:
    """One road user of a labelled crash: the ego, or a pixel box at the contact frame with its category."""

    ego: bool
    box: tuple[float, float, float, float] | None = None
    category: str | None = None

    def describe(self) -> str:
        if self.ego:
            return "ego"
        assert self.box is not None
        return f"{self.category} [{', '.join(f'{v:.0f}' for v in self.box)}]"


@dataclass(frozen=True)
class CrashLabel:
    """The labelled crash of one clip (``crash`` false: the clip has none)."""

    clip: str
    video: str
    fps: float
    crash: bool
    contact_frame: int | None = None
    participants: tuple[Participant, ...] = field(default_factory=tuple)
    description: str = ""
    first_accident_frame: int | None = None

    @property
    def contact_video_time(self) -> float | None:
        """Video time (s, frame / fps) of the first contact, or None without a crash."""
        return None if self.contact_frame is None else self.contact_frame / self.fps

    @property
    def third_party(self) -> bool:
        """True when neither participant is the ego."""
        return self.crash and not any(p.ego for p in self.participants)

    def scaled(self, sx: float, sy: float) -> CrashLabel:
        """The label for the clip's frames scaled by ``sx`` x ``sy`` (its boxes scaled; frames unchanged)."""
        parts = tuple(
            p if p.box is None else replace(p, box=(p.box[0] * sx, p.box[1] * sy, p.box[2] * sx, p.box[3] * sy))
            for p in self.participants
        )
        return replace(self, participants=parts)


def _participant(data: Any, where: str) -> Participant:
    if not isinstance(data, dict) or data.get("who") not in ("ego", "road_user"):
        raise UserError(f"{where}: a participant is {{'who': 'ego'}} or {{'who': 'road_user', 'box': ..., ...}}")
    if data["who"] == "ego":
        return Participant(ego=True)
    box = data.get("box")
    cat = data.get("category")
    if not (isinstance(box, list) and len(box) == 4 and all(isinstance(v, int | float) for v in box)):
        raise UserError(f"{where}: box must be [x1, y1, x2, y2] pixels")
    if not (box[2] > box[0] and box[3] > box[1]):
        raise UserError(f"{where}: box {box} is empty (need x2 > x1 and y2 > y1)")
    if cat not in ROAD_USER_CATEGORIES:
        raise UserError(f"{where}: category {cat!r} is not one of {list(ROAD_USER_CATEGORIES)}")
    return Participant(ego=False, box=(float(box[0]), float(box[1]), float(box[2]), float(box[3])), category=cat)


def _label(clip: str, data: Any, where: str) -> CrashLabel:
    if not isinstance(data, dict):
        raise UserError(f"{where}: expected an object")
    try:
        fps = float(data["fps"])
        crash = bool(data["crash"])
        video = str(data["video"])
    except (KeyError, TypeError, ValueError) as exc:
        raise UserError(f"{where}: needs video, fps and crash ({exc})") from None
    if not fps > 0:
        raise UserError(f"{where}: fps must be > 0")
    contact = data.get("contact_frame")
    parts = tuple(_participant(p, f"{where}.participants[{i}]") for i, p in enumerate(data.get("participants", [])))
    if crash and contact is None:  # a crash the labeller could not see: no contact, no participants
        if parts:
            raise UserError(f"{where}: a crash without a contact_frame has no participants")
    elif crash:
        if not isinstance(contact, int) or contact < 0:
            raise UserError(f"{where}: contact_frame must be a frame index >= 0")
        if len(parts) != 2:
            raise UserError(f"{where}: a crash needs exactly two participants (found {len(parts)})")
    elif contact is not None or parts:
        raise UserError(f"{where}: a clip without a crash has no contact_frame or participants")
    first = data.get("first_accident_frame")
    if first is not None and not isinstance(first, int):
        raise UserError(f"{where}: first_accident_frame must be a frame index or null")
    return CrashLabel(clip, video, fps, crash, contact, parts, str(data.get("description", "")), first)


def load_crash_labels(path: str | os.PathLike[str]) -> dict[str, CrashLabel]:
    """Read a crash-label file; returns ``{clip name: CrashLabel}``. Bad files: one-line UserError."""
    p = require_file(path, "crash label file")
    data = read_json(p)
    if not isinstance(data, dict) or data.get("format") != LABEL_FORMAT or not isinstance(data.get("clips"), dict):
        raise UserError(f"{p}: not a crash label file (expected format {LABEL_FORMAT!r} with 'clips')")
    return {str(k): _label(str(k), v, f"{p}: clips.{k}") for k, v in data["clips"].items()}


def label_for_video(labels: dict[str, CrashLabel], video: str | os.PathLike[str]) -> CrashLabel | None:
    """The label of a video file by its name (stem), or None."""
    return labels.get(Path(video).stem)
