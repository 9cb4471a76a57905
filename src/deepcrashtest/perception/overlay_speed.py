"""The ego's speed burned into a dashcam's picture by its GPS ("58KM/H", "006km/h", "35 MPH"), read over a clip.

Many dashcams write their GPS speed into the picture, beside the date and the position; a clip's metric scale is
otherwise the weakest figure an uncalibrated camera gives (its focal length, :mod:`deepcrashtest.geometry.
selfcalib`). :class:`OverlaySpeedReader` samples the frames every :data:`SAMPLE_S` seconds: on the first
:data:`SEARCH_SAMPLES` samples a :class:`~deepcrashtest.perception.text.TextReader` looks for a speed in the top
and bottom bands of the picture (:data:`BAND`, where dashcams put their overlay; a band is read only where the
reader's cheap text detection at half size finds a line there); once found, only the speed's
place is read again on the later samples. :meth:`OverlaySpeedReader.result` keeps readings that agree with their
neighbours (:data:`MAX_JUMP_KMH`) and returns them as an :class:`OverlaySpeed` (None: no speed in the picture).

A speed is a number of 1-3 digits standing as a word of its own followed by its unit (km/h, kph, mph, км/ч), so a
road sign's bare "60" or a clock's digits are never taken. GPS speeds lag the wheels by ~0.5-1 s.
"""

from __future__ import annotations

import re
from dataclasses import dataclass, field

import cv2
import numpy as np

from deepcrashtest.perception.text import TextLine, TextReader

#: Seconds between the frames read.
SAMPLE_S = 0.5
#: The first samples searched for a speed (both bands, the whole text reader); none found: the clip has none.
SEARCH_SAMPLES = 3
#: Each band's height (fraction of the picture's) at its top and bottom searched for the overlay.
BAND = 0.16
#: A reading further than this (km/h) from the median of its 5 neighbours is a misreading (GPS speeds change
#: by ~1-5 km/h in half a second; a misread digit by 10 or more).
MAX_JUMP_KMH = 12.0
#: Readings needed for a speed: a single reading may be a misread sign or caption.
MIN_READINGS = 3
#: Samples in a row whose speed's place reads no speed (and a new search finds none) before the reader stops.
MAX_MISSES = 3
#: Readings under this confidence (0-1) are not taken.
MIN_SCORE = 0.7
#: The largest speed taken (km/h).
MAX_KMH = 250.0
MPH_KMH = 1.609344

#: A speed's unit as text readers write it: km/h (kmh, kph; the glyphs may come apart into words), mph, and the
#: Cyrillic км/ч, whose last glyph a Latin reader writes y, 4, u or drops.
_UNIT = r"[kк]\s?[mм]\s?/?\s?h|kph|m\s?p\s?h|[kк]\s?[mм]\s?/\s?[чy4u]?"
_SPEED = re.compile(rf"(?<![\d.,:])(\d{{1,3}})\s?({_UNIT})(?![a-zа-я])", re.IGNORECASE)


def parse_speed(text: str) -> tuple[float, str] | None:
    """(km/h, unit as written: ``"km/h"`` or ``"mph"``) of the one speed in ``text``; None where there is none or
    more than one."""
    found = _speed_match(text)
    if found is None:
        return None
    unit = "mph" if "p" in found.group(2).lower() and "k" not in found.group(2).lower() else "km/h"
    return float(found.group(1)) * _factor(unit), unit


def _speed_match(text: str) -> re.Match[str] | None:
    """The one speed's match in ``text`` (None: none, or more than one)."""
    found = [m for m in _SPEED.finditer(text) if float(m.group(1)) * _factor(m.group(2)) <= MAX_KMH]
    return found[0] if len(found) == 1 else None


def _factor(unit: str) -> float:
    unit = unit.lower()
    return MPH_KMH if "p" in unit and "k" not in unit else 1.0


@dataclass(frozen=True)
class OverlaySpeed:
    """The speeds read off a clip's overlay: per reading the video ``frame``, its time ``times_s`` (s) and ``kmh``;
    ``unit`` as the overlay writes it (``"km/h"`` or ``"mph"``, converted); ``box`` where the speed is written
    (x1, y1, x2, y2 px of the frames read); ``sample``: one line as read, for the notes."""

    frames: np.ndarray
    times_s: np.ndarray
    kmh: np.ndarray
    unit: str
    box: tuple[int, int, int, int]
    sample: str

    def describe(self) -> str:
        """One line for the notes: how many readings, their range and where they came from."""
        lo, hi = float(np.min(self.kmh)), float(np.max(self.kmh))
        span = f"{lo:.0f} km/h" if round(lo) == round(hi) else f"{lo:.0f}-{hi:.0f} km/h"
        return f"{span}, {len(self.kmh)} readings ({self.sample!r})"


@dataclass(frozen=True)
class _Place:
    """Where the speed is written: the band's first row (px of the frame) and the speed word's box in the band."""

    band_y0: int
    box: tuple[int, int, int, int]

    def frame_box(self) -> tuple[int, int, int, int]:
        x1, y1, x2, y2 = self.box
        return x1, self.band_y0 + y1, x2, self.band_y0 + y2


@dataclass
class OverlaySpeedReader:
    """Reads a clip's overlay speed from frames offered in order (see the module docstring).

    Call :meth:`wants` with each frame's time and :meth:`offer` the frames it wants, then :meth:`result`. Where the
    speed's place reads no speed, the bands are searched again (a flash, a wiper); after :data:`MAX_MISSES` misses in
    a row the reader stops (the text found was no overlay: a sign the camera passed)."""

    reader: TextReader
    sample_s: float = SAMPLE_S
    _next_s: float | None = None
    _samples: int = 0
    _misses: int = 0
    _place: _Place | None = None
    _readings: list[tuple[int, float, float, str, _Place]] = field(default_factory=list)
    _texts: dict[_Place, str] = field(default_factory=dict)

    def wants(self, time_s: float) -> bool:
        """Whether the frame at ``time_s`` (s) is to be read (every :data:`SAMPLE_S`; none once the search found
        nothing, or the place found stopped reading a speed)."""
        if self._place is None and self._samples >= SEARCH_SAMPLES or self._misses > MAX_MISSES:
            return False
        return self._next_s is None or time_s >= self._next_s - 1e-6

    def offer(self, frame: int, time_s: float, image: np.ndarray) -> None:
        """Read the speed in ``image`` (BGR uint8, the whole frame) at video ``frame`` / ``time_s`` (s)."""
        self._next_s = time_s + self.sample_s
        self._samples += 1
        found = self._read_place(image, self._place) if self._place is not None else None
        if found is None:
            found = self._search(image)
        if found is None:
            self._misses += self._place is not None
            return
        self._misses = 0
        assert self._place is not None
        self._readings.append((frame, time_s, *found, self._place))

    def _read_place(self, image: np.ndarray, place: _Place) -> tuple[float, str] | None:
        x1, y1, x2, y2 = place.frame_box()
        text, score = self.reader.read(image[y1:y2, x1:x2])
        return parse_speed(text) if score >= MIN_SCORE else None

    def _search(self, image: np.ndarray) -> tuple[float, str] | None:
        h = image.shape[0]
        band_h = max(1, int(round(BAND * h)))
        for y0 in (h - band_h, 0):
            band = image[y0 : y0 + band_h]
            half = cv2.resize(band, (max(1, band.shape[1] // 2), max(1, band_h // 2)), interpolation=cv2.INTER_AREA)
            if not self.reader.detect(half):  # no text there: not worth reading
                continue
            for line in self.reader.find(band):
                speed = parse_speed(line.text) if line.score >= MIN_SCORE else None
                if speed is not None:
                    self._place = _Place(y0, _speed_box(line, image.shape[1], band_h))
                    self._texts.setdefault(self._place, line.text)
                    return speed
        return None

    def result(self) -> OverlaySpeed | None:
        """The readings at the place read most often, in its unit of most readings, that agree with their
        neighbours; None where fewer than :data:`MIN_READINGS` are left."""
        if not self._readings:
            return None
        places = [r[4] for r in self._readings]
        place = max(dict.fromkeys(places), key=places.count)  # the first found of the most read
        rows = [r for r in self._readings if r[4] == place]
        units = [r[3] for r in rows]
        unit = max(dict.fromkeys(units), key=units.count)
        rows = [r for r in rows if r[3] == unit]
        kmh = np.array([r[2] for r in rows])
        keep = np.array([abs(v - np.median(kmh[max(0, i - 2) : i + 3])) <= MAX_JUMP_KMH for i, v in enumerate(kmh)])
        if keep.sum() < MIN_READINGS:
            return None
        rows = [r for r, k in zip(rows, keep, strict=True) if k]
        return OverlaySpeed(
            frames=np.array([r[0] for r in rows], dtype=int),
            times_s=np.array([r[1] for r in rows]),
            kmh=np.array([r[2] for r in rows]),
            unit=unit,
            box=place.frame_box(),
            sample=self._texts[place],
        )


def _speed_box(line: TextLine, width: int, band_h: int) -> tuple[int, int, int, int]:
    """The box (px of the band) to read the speed again: its line's rows (a few px more), from the end of the word
    before the speed's number (the line's start where there is none) to one glyph past the line's end (a number
    that grows a digit)."""
    x1, y1, x2, y2 = line.box
    pad = max(2, (y2 - y1) // 4)
    words = line.text.split(" ")
    left = x1 - pad
    found = _speed_match(line.text)
    if found is not None and line.words and len(words) == len(line.words):
        number = line.text[: found.start(1)].count(" ")  # the word the speed's number starts
        if number > 0:  # just after the word before: its last digits are not the speed's
            left = line.words[number - 1][1] + 1
    glyph = y2 - y1
    return max(0, left), max(0, y1 - pad), min(width, x2 + glyph), min(band_h, y2 + pad)
