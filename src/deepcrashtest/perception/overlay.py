"""What a dashcam burns into its picture, read over a clip: its GPS speed ("58KM/H", "006km/h", "35 MPH") and its
clock ("09:16:27").

Many dashcams write their GPS speed into the picture, beside the date, the time and the position. The speed gives
a clip's metric scale, otherwise the weakest figure an uncalibrated camera gives (its focal length,
:mod:`deepcrashtest.geometry.selfcalib`); the clock tells whether the video runs in real time (a compilation's
slow-motion replay does not, and every speed in its scenario would be off by the same factor).

:class:`OverlayReader` samples the frames every :data:`SAMPLE_S` seconds: on the first :data:`SEARCH_SAMPLES`
samples a :class:`~deepcrashtest.perception.text.TextReader` looks for each field in the top and bottom bands of the
picture (:data:`BAND`, where dashcams put their overlay; a band is read only where the reader's cheap text detection
at half size finds a line there); once found, only the field's place is read again on the later samples (the clock
for the first :data:`CLOCK_MAX_S` seconds). :meth:`OverlayReader.speed` keeps speed readings that agree with their
neighbours (:data:`MAX_JUMP_KMH`) and returns them as an :class:`OverlaySpeed` (None: no speed in the picture);
:meth:`OverlayReader.clock` the clock's readings as an :class:`OverlayClock`.

A speed is a number of 1-3 digits standing as a word of its own followed by its unit (km/h, kph, mph, км/ч), so a
road sign's bare "60" or a clock's digits are never taken; a clock is hours, minutes and seconds standing alone
(``HH:MM:SS``, ``:``, ``.`` or ``-`` between them, or what a text reader makes of a colon), so a date is not. GPS
speeds lag the wheels by ~0.5-1 s.
"""

from __future__ import annotations

import math
import re
from collections.abc import Callable
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
#: Samples in a row whose place reads nothing for a field (and a new search finds none) before it is no longer read.
MAX_MISSES = 3
#: Clock readings that fit no running clock (backwards, or far ahead) before the clock is not trusted.
MAX_CLOCK_MISREADS = 3
#: Readings under this confidence (0-1) are not taken.
MIN_SCORE = 0.7
#: The clock is read over the first seconds of video only (enough to tell its rate).
CLOCK_MAX_S = 10.0
#: A clock whose rate (clock seconds per video second) is further than this from 1 with 95 % confidence makes the video
#: a slow-motion or sped-up one (the tick frames are found to the frame where the digits read cleanly).
CLOCK_RATE_TOL = 0.05
#: The frame rates cameras record at (1/s): a re-timed video takes the one its clock's interval admits.
RECORDING_RATES = (
    10.0,
    12.0,
    15.0,
    20.0,
    24000 / 1001,
    24.0,
    25.0,
    30000 / 1001,
    30.0,
    50.0,
    60000 / 1001,
    60.0,
    120.0,
    240.0,
)
#: A recording rate within the clock's interval is taken where its distance to the clock's frame rate is at most this
#: share of the next nearest one's (else the clock's own rate).
RECORDING_RATE_CLEAR = 0.75
#: The video time (s) a clock's ticks must span to tell its rate.
CLOCK_MIN_SPAN_S = 2.0
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


#: ``HH:MM:SS``; between the numbers ``:``, ``.``, ``-`` or what a text reader makes of a colon (``#``, ``;``).
_CLOCK = re.compile(r"(?<![\d.:,\-/])([01]?\d|2[0-3])[:.\-#;]([0-5]\d)[:.\-#;]([0-5]\d)(?![\d.:\-/])")


def parse_clock(text: str) -> tuple[float, str] | None:
    """(seconds of the day, ``"s"``) of the one clock ``HH:MM:SS`` in ``text``; None where there is none or more
    than one."""
    found = _clock_match(text)
    if found is None:
        return None
    hh, mm, ss = (int(found.group(k)) for k in (1, 2, 3))
    return float(3600 * hh + 60 * mm + ss), "s"


def _clock_match(text: str) -> re.Match[str] | None:
    found = list(_CLOCK.finditer(text))
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
class OverlayClock:
    """The clock read off a clip's overlay, as its ticks: the video time ``ticks_t`` (s) of the first frame showing
    each new second ``ticks_s`` (the clock's seconds of the day), known to within ``ticks_dt`` (s: the gap to the
    frame before it, which still showed the old second); ``misreads``: readings that fit no running clock;
    ``sample``: one line as read."""

    ticks_t: np.ndarray
    ticks_s: np.ndarray
    ticks_dt: np.ndarray
    misreads: int
    sample: str

    def rate(self) -> tuple[float, float, float] | None:
        """(clock seconds per video second, and its 95 % interval): the Theil-Sen line through the ticks, each at the
        middle of its interval (a misread digit moves one tick, not the line). None with fewer than 3 ticks, ticks
        spanning under :data:`CLOCK_MIN_SPAN_S` of video, or more than :data:`MAX_CLOCK_MISREADS` readings that fit no
        running clock."""
        from scipy.stats import theilslopes

        t = self.ticks_t - 0.5 * self.ticks_dt
        if len(t) < 3 or float(t[-1] - t[0]) < CLOCK_MIN_SPAN_S or self.misreads > MAX_CLOCK_MISREADS:
            return None
        fit = theilslopes(self.ticks_s, t, alpha=0.95)
        return float(fit[0]), float(fit[2]), float(fit[3])

    def slow_motion(self) -> float | None:
        """The video's speed against real time (clock seconds per video second) where it is clearly not real time
        (its 95 % interval further than :data:`CLOCK_RATE_TOL` from 1); None where it is, or cannot be told."""
        found = self.rate()
        return found[0] if found is not None and _not_real_time(found) else None

    def real_time_fps(self, fps: float) -> float | None:
        """The frame rate (1/s) at which a video stored at ``fps`` plays in real time by this clock, where it is
        clearly not real time (:meth:`slow_motion`): the rate cameras record at (:data:`RECORDING_RATES`) within the
        95 % interval nearest to ``fps / rate``, where it is clearly the nearest (:data:`RECORDING_RATE_CLEAR`), else
        ``fps / rate`` to 0.1 fps. dad_000478's clock ticks every 25 frames of its 20 fps file: 25; dad_000550's
        every 25 and 24: 24.5 (24 and 25 as near); dad_000528's reads 26.8 in an interval of 24-33: 25. None where the
        video plays in real time, or the clock cannot tell."""
        found = self.rate()
        if found is None or not _not_real_time(found):
            return None
        rate, lo, hi = found
        real = fps / rate
        near = sorted((abs(r - real), r) for r in RECORDING_RATES if fps / hi <= r <= fps / lo)
        if near and (len(near) == 1 or near[0][0] <= RECORDING_RATE_CLEAR * near[1][0]):
            return near[0][1]
        return round(real, 1)


def _not_real_time(rate: tuple[float, float, float]) -> bool:
    """Whether a clock's rate (and its 95 % interval) lies further than :data:`CLOCK_RATE_TOL` from 1."""
    return rate[2] < 1.0 - CLOCK_RATE_TOL or rate[1] > 1.0 + CLOCK_RATE_TOL


@dataclass(frozen=True)
class _Place:
    """Where a field is written: the band's first row (px of the frame) and the field's box in the band."""

    band_y0: int
    box: tuple[int, int, int, int]

    def frame_box(self) -> tuple[int, int, int, int]:
        x1, y1, x2, y2 = self.box
        return x1, self.band_y0 + y1, x2, self.band_y0 + y2


@dataclass
class _Field:
    """One field of the overlay being read: how it is found in a line (``match``: group 1 starts the value) and
    parsed, until when (``until_s``, video s), where it was last found, and its readings."""

    match: Callable[[str], re.Match[str] | None]
    parse: Callable[[str], tuple[float, str] | None]
    until_s: float = math.inf
    room: float = 1.0
    """Glyphs of room after the value's word in its box read again (a speed may grow a digit; a clock never does,
    and a glyph of the text after it, ``07:53:27 -V`` read as ``07:53:27-1``, is no clock)."""
    place: _Place | None = None
    misses: int = 0
    readings: list[tuple[int, float, float, str, _Place]] = field(default_factory=list)
    texts: dict[_Place, str] = field(default_factory=dict)

    def active(self, samples: int, time_s: float) -> bool:
        """Still to be read at ``time_s``: searched for (the first samples) or found and reading."""
        if time_s > self.until_s or self.misses > MAX_MISSES:
            return False
        return self.place is not None or samples < SEARCH_SAMPLES

    def best(self) -> list[tuple[int, float, float, str, _Place]]:
        """The readings at the place read most often (the first found of those), in its unit of most readings."""
        if not self.readings:
            return []
        places = [r[4] for r in self.readings]
        place = max(dict.fromkeys(places), key=places.count)
        rows = [r for r in self.readings if r[4] == place]
        units = [r[3] for r in rows]
        unit = max(dict.fromkeys(units), key=units.count)
        return [r for r in rows if r[3] == unit]


@dataclass
class OverlayReader:
    """Reads a clip's overlay speed and clock from frames offered in order (see the module docstring).

    Call :meth:`wants` with each frame's time and :meth:`offer` the frames it wants, then :meth:`speed` and
    :meth:`clock`. Where a field's place reads nothing, the bands are searched again (a flash, a wiper); after
    :data:`MAX_MISSES` misses in a row that field is no longer read (the text found was no overlay: a sign the camera
    passed)."""

    reader: TextReader
    sample_s: float = SAMPLE_S
    _next_s: float | None = None
    _samples: int = 0
    _speed: _Field = field(default_factory=lambda: _Field(_speed_match, parse_speed))
    _clock: _Field = field(default_factory=lambda: _Field(_clock_match, parse_clock, CLOCK_MAX_S, room=0.25))
    #: the clock's crops of the frames seen since its last reading (frame, time s, crop), where a tick is looked for
    _between: list[tuple[int, float, np.ndarray]] = field(default_factory=list)
    _ticks: list[tuple[float, float, float]] = field(default_factory=list)  # time s, clock s, time uncertainty s
    _misreads: int = 0
    #: why the text reader stopped (None: it did not): nothing is read after a failure, and no result is given
    failed: str | None = None

    def see(self, frame: int, time_s: float, image: np.ndarray) -> None:
        """A frame not read (:meth:`wants` said no): kept as the clock's crop while the clock is read, so that the
        frame its second changes on can be found."""
        place = self._clock.place
        if self.failed is None and place is not None and self._clock.active(self._samples, time_s):
            x1, y1, x2, y2 = place.frame_box()
            crop = image[y1:y2, x1:x2]
            if crop.size:
                self._between.append((frame, time_s, crop.copy()))

    def wants(self, time_s: float) -> bool:
        """Whether the frame at ``time_s`` (s) is to be read (every :data:`SAMPLE_S` while a field is searched for
        or read)."""
        if self.failed is not None or not any(f.active(self._samples, time_s) for f in (self._speed, self._clock)):
            return False
        return self._next_s is None or time_s >= self._next_s - 1e-6

    def offer(self, frame: int, time_s: float, image: np.ndarray) -> None:
        """Read the overlay in ``image`` (BGR uint8, the whole frame) at video ``frame`` / ``time_s`` (s). Where the
        text reader fails (a model it cannot load or run), nothing more is read and :attr:`failed` says why: the
        overlay is an extra, and the extraction goes on without it."""
        try:
            self._offer(frame, time_s, image)
        except Exception as exc:  # a plug-in's failure: said, not raised
            self.failed = f"{type(exc).__name__}: {exc}"[:300]

    def _offer(self, frame: int, time_s: float, image: np.ndarray) -> None:
        fields = [f for f in (self._speed, self._clock) if f.active(self._samples, time_s)]
        self._next_s = time_s + self.sample_s
        self._samples += 1
        found = {id(f): self._read_place(image, f.place, f.parse) if f.place is not None else None for f in fields}
        # a field whose place read nothing is searched for again from its second miss in a row (one misread glyph
        # is not worth a search)
        missing = [f for f in fields if found[id(f)] is None and (f.place is None or f.misses >= 1)]
        if missing:
            found |= self._search(image, missing)
        clock_read = False
        for f in fields:
            value = found[id(f)]
            if value is None:
                f.misses += f.place is not None
                continue
            f.misses = 0
            assert f.place is not None
            if f is self._clock and not self._tick(frame, time_s, value[0]):
                continue  # a misread
            f.readings.append((frame, time_s, *value, f.place))
            if f is self._clock:
                self._between = []  # the next tick is looked for after this reading
                clock_read = True
        if self._clock in fields and not clock_read:
            self.see(frame, time_s, image)  # no clock reading here: a frame to look for its tick in

    def _tick(self, frame: int, time_s: float, seconds: float) -> bool:
        """The clock read ``seconds`` at ``frame`` / ``time_s``: where it moved on from the last reading, the first
        frame showing the new second is found among the frames seen between (bisection) and kept as a tick; a
        reading that no running clock gives (backwards, or ahead by more than 4x the time passed) is a misread
        (False)."""
        last = next((r for r in reversed(self._clock.readings) if r[4] == self._clock.place), None)
        if last is None or seconds == last[2]:
            return True
        if seconds < last[2] or seconds - last[2] > 4.0 * (time_s - last[1]) + 1.0:
            self._misreads += 1
            return False
        lo, hi = -1, len(self._between)  # frames [0, lo] show the old second, [hi, ...] (and now) the new one
        while hi - lo > 1:
            mid = (lo + hi) // 2
            text, score = self.reader.read(self._between[mid][2])
            read = parse_clock(text) if score >= MIN_SCORE else None
            if read is None:
                break  # the tick stays within what is known
            if read[0] >= seconds:
                hi = mid
            else:
                lo = mid
        before = self._between[lo][1] if lo >= 0 else last[1]
        at = self._between[hi][1] if hi < len(self._between) else time_s
        self._ticks.append((at, seconds, at - before))
        return True

    def _read_place(
        self, image: np.ndarray, place: _Place, parse: Callable[[str], tuple[float, str] | None]
    ) -> tuple[float, str] | None:
        x1, y1, x2, y2 = place.frame_box()
        crop = image[y1:y2, x1:x2]
        if crop.size == 0:
            return None
        text, score = self.reader.read(crop)
        return parse(text) if score >= MIN_SCORE else None

    def _search(self, image: np.ndarray, fields: list[_Field]) -> dict[int, tuple[float, str] | None]:
        """Each of ``fields`` looked for in the bands' lines (its place set where found)."""
        found: dict[int, tuple[float, str] | None] = {}
        h = image.shape[0]
        band_h = max(1, int(round(BAND * h)))
        for y0 in (h - band_h, 0):
            band = image[y0 : y0 + band_h]
            half = cv2.resize(band, (max(1, band.shape[1] // 2), max(1, band_h // 2)), interpolation=cv2.INTER_AREA)
            if not self.reader.detect(half):  # no text there: not worth reading
                continue
            for line in self.reader.find(band):
                for f in fields:
                    value = f.parse(line.text) if line.score >= MIN_SCORE and found.get(id(f)) is None else None
                    if value is not None:
                        f.place = _Place(y0, _value_box(line, f.match, image.shape[1], band_h, f.room))
                        f.texts.setdefault(f.place, line.text)
                        found[id(f)] = value
            if all(found.get(id(f)) is not None for f in fields):
                break
        return found

    def speed(self) -> OverlaySpeed | None:
        """The speed readings at the place read most often, in its unit of most readings, that agree with their
        neighbours; None where fewer than :data:`MIN_READINGS` are left."""
        rows = self._speed.best()
        if not rows or self.failed is not None:
            return None
        kmh = np.array([r[2] for r in rows])
        keep = np.array([abs(v - np.median(kmh[max(0, i - 2) : i + 3])) <= MAX_JUMP_KMH for i, v in enumerate(kmh)])
        if keep.sum() < MIN_READINGS:
            return None
        rows = [r for r, k in zip(rows, keep, strict=True) if k]
        place = rows[0][4]
        return OverlaySpeed(
            frames=np.array([r[0] for r in rows], dtype=int),
            times_s=np.array([r[1] for r in rows]),
            kmh=np.array([r[2] for r in rows]),
            unit=rows[0][3],
            box=place.frame_box(),
            sample=self._speed.texts[place],
        )

    def clock(self) -> OverlayClock | None:
        """The clock's ticks; None where it was read fewer than :data:`MIN_READINGS` times."""
        if len(self._clock.readings) < MIN_READINGS or self.failed is not None:
            return None
        t, sec, dt = (np.array([k[j] for k in self._ticks]) for j in range(3))
        return OverlayClock(t, sec, dt, self._misreads, self._clock.texts[self._clock.readings[0][4]])


def _value_box(
    line: TextLine, match: Callable[[str], re.Match[str] | None], width: int, band_h: int, room: float = 1.0
) -> tuple[int, int, int, int]:
    """The box (px of the band) to read a field again: its line's rows (a few px more), from the end of the word
    before the field's value (the line's start where there is none) to ``room`` glyphs past the end of the word the
    value ends in (the line's end where the glyphs are not placed): a number that grows a digit stays inside."""
    x1, y1, x2, y2 = line.box
    pad = max(2, (y2 - y1) // 4)
    after = round(room * (y2 - y1))  # px past the value's last word
    words = line.text.split(" ")
    left, right = x1 - pad, x2 + after
    found = match(line.text)
    if found is not None and line.words and len(words) == len(line.words):
        first = line.text[: found.start(1)].count(" ")  # the word the value starts in
        last = line.text[: max(found.end() - 1, 0)].count(" ")  # and the one it ends in
        if first > 0:  # just after the word before: its last digits are not the value's
            left = line.words[first - 1][1] + 1
        right = line.words[last][1] + after
    return max(0, left), max(0, y1 - pad), min(width, right), min(band_h, y2 + pad)
