"""The crash of a video into its raw Scenario: detected automatically, or given by the user.

``extract --crash FRAME[:ID,ID]`` (frame = 0-based decoded frame, ids as in ``tracks.csv`` and the
annotated video, ``ego`` allowed; ``--crash 95`` = the most likely pair at that frame) overrides
the automatic detection (:func:`deepcrashtest.perception.crash_detect.detect_crash`). Either way
the raw Scenario gets ``collision`` (scenario time, the two participants, ``source`` video-auto or
user, confidence) and ``provenance.parameters["crash_detection"]`` (what was found, or
``found: false``: stage 2 then keeps every road user apart).
"""

from __future__ import annotations

import re
from dataclasses import dataclass
from typing import Any

import numpy as np
import pandas as pd

from deepcrashtest.errors import UserError
from deepcrashtest.perception.crash_detect import (
    EGO,
    MIN_CRASH_SCORE,
    CrashFinding,
    WorldTrack,
    crash_candidates,
    detect_crash,
    finding,
)
from deepcrashtest.scenario import Collision, CollisionSource, Scenario

_SPEC = re.compile(r"^\s*(\d+)\s*(?::\s*([A-Za-z0-9]+)\s*,\s*([A-Za-z0-9]+)\s*)?$")
AUTO_PAIR_WINDOW_S = 0.3  # --crash FRAME without ids: the best pair within this of the frame
GRID_MAX_RATE = 4.0  # EvenGrid's rate is at most this many times a variable-rate video's mean rate


@dataclass(frozen=True)
class CrashSpec:
    """The user's ``--crash``: a frame and optionally the two participants (0 = ego)."""

    frame: int
    pair: tuple[int, int] | None
    text: str


def parse_crash(text: str) -> CrashSpec:
    """Parse ``FRAME[:ID,ID]`` (``ego`` allowed as an id); bad syntax -> one-line UserError."""
    m = _SPEC.match(text or "")
    if m is None:
        raise UserError(f"--crash {text!r}: expected FRAME or FRAME:ID,ID (e.g. 95:ego,7 or 95:3,7)")
    frame = int(m.group(1))
    if m.group(2) is None:
        return CrashSpec(frame, None, text)
    ids = []
    for tok in (m.group(2), m.group(3)):
        if tok.lower() == "ego":
            ids.append(EGO)
        elif tok.isdigit() and int(tok) > 0:
            ids.append(int(tok))
        else:
            raise UserError(f"--crash {text!r}: {tok!r} is not a track id (a positive integer) or 'ego'")
    if ids[0] == ids[1]:
        raise UserError(f"--crash {text!r}: the two participants must differ")
    return CrashSpec(frame, (ids[0], ids[1]), text)


def crash_for_raw(
    raw: Scenario,
    tracks: pd.DataFrame,
    motion: tuple[np.ndarray, np.ndarray] | None,
    spec: CrashSpec | None = None,
    picture: tuple[int, int, int, int] | None = None,
) -> tuple[Scenario, dict[str, Any]]:
    """The raw scenario with its crash (see the module docstring) and the provenance record;
    ``picture``: the picture ``(x0, y0, x1, y1)`` (px) inside black bars, if any
    (:func:`deepcrashtest.video.bars.video_picture_area`)."""
    fps = float(raw.source.fps)
    w, h = raw.source.width, raw.source.height
    grid = EvenGrid.of(raw)
    source: CollisionSource = "user" if spec is not None else "video-auto"
    if grid is None:
        finding = _find(raw, tracks, motion, spec, picture)
    else:  # a variable frame rate: found on an even grid of frames (every rate and window of the cues is per frame)
        if spec is not None:
            _check_crash_frame(spec, raw)
        found = _find(grid.raw(raw), grid.tracks(tracks), grid.motion(motion), grid.spec(spec), picture)
        finding = None if found is None else grid.back(found, raw)
    if finding is None:
        record: dict[str, Any] = {
            "found": False,
            "source": source,
            "method": "image evidence (perception.crash_detect)",
        }
        return _with_record(raw, _bars(record, picture, w, h), None), record
    t_video = float(raw.video_time(raw.frame_time(finding.frame)))  # frame / fps, or a variable rate's frame time
    t = float(raw.scenario_time(t_video))
    t_ego = raw.ego.trajectory.t
    t = float(np.clip(t, t_ego[0] + 1.0 / fps, t_ego[-1]))
    a, b = finding.pair
    record = {
        "found": True,
        "source": source,
        "frame": finding.frame,
        "video_time_s": round(t_video, 4),
        "pair": ["ego" if i == EGO else i for i in finding.pair],
        "confidence": round(finding.confidence, 3),
        "evidence": finding.evidence,
    }
    if spec is not None:
        record["user_spec"] = spec.text
    _bars(record, picture, w, h)
    conf = None if source == "user" else finding.confidence
    collision = Collision(time_s=t, other_id=a, agent_id=b, source=source, confidence=conf)
    return _with_record(raw, record, collision), record


def weak_pair_note(record: dict[str, Any] | None) -> list[str]:
    """The warning for a ``--crash FRAME`` whose likeliest pair there scores below what the automatic detection
    calls a crash (:data:`MIN_CRASH_SCORE`): no two road users close in at that frame, so the pair named may not be
    the one the user sees (none for a named pair, a crash found automatically or a likely pair)."""
    spec = (record or {}).get("user_spec")
    if record is None or record.get("source") != "user" or spec is None or ":" in spec:  # no spec, or a pair named
        return []
    confidence = float(record.get("confidence", 0.0))
    if confidence >= MIN_CRASH_SCORE:
        return []
    a, b = record["pair"]
    frame = record["frame"]
    return [
        f"--crash {spec}: the likeliest pair at frame {frame}, {a} and {b}, scores {confidence:.2f} "
        f"(a crash found automatically scores >= {MIN_CRASH_SCORE}); check them in annotated.mp4 or name the pair "
        f"(--crash {frame}:ID,ID)"
    ]


def _bars(record: dict[str, Any], picture: tuple[int, int, int, int] | None, w: int, h: int) -> dict[str, Any]:
    """``record`` with the picture inside black bars (``picture_area``, px), when there are bars."""
    if picture is not None and tuple(picture) != (0, 0, w, h):
        record["picture_area"] = [int(v) for v in picture]
    return record


def _find(
    raw: Scenario,
    tracks: pd.DataFrame,
    motion: tuple[np.ndarray, np.ndarray] | None,
    spec: CrashSpec | None,
    picture: tuple[int, int, int, int] | None,
) -> CrashFinding | None:
    """The user's crash (``spec``) or the one the video shows (None: none found)."""
    agents = {a.id for a in raw.agents}
    if spec is not None:
        return _user_crash(spec, raw, tracks, motion, agents, picture)
    w, h = raw.source.width, raw.source.height
    fps = float(raw.source.fps)
    return detect_crash(tracks, w, h, fps, motion, allowed=agents, world=world_tracks(raw), picture=picture)


@dataclass(frozen=True)
class EvenGrid:
    """A variable-frame-rate video's frames placed on an even grid of ``fps`` (its most common interval): frame k
    at ``index[k]`` = its time x ``fps`` (rounded, kept increasing), dropped frames leaving gaps. The crash cues
    (box growth, motion change, the camera's jolt) are rates per frame and windows of frames: on the video's own
    frame numbers a dropped frame doubles a step's motion, which reads as a jolt (a phone recording with 30 % of its
    frames dropped: dad_000487's crash found 0.58 s early)."""

    fps: float
    index: np.ndarray

    @classmethod
    def of(cls, raw: Scenario) -> EvenGrid | None:
        """The grid of ``raw``'s frames, or None at a constant frame rate (``source.frame_times`` None)."""
        times = raw.source.frame_times
        if times is None or len(times) < 2:
            return None
        t = np.asarray(times, dtype=float)
        # at most GRID_MAX_RATE x the mean rate: a burst of frames milliseconds apart would make a grid of millions
        fps = min(1.0 / float(np.median(np.diff(t))), GRID_MAX_RATE * float(raw.source.fps))
        k = np.arange(len(t))
        index = np.maximum.accumulate(np.round(t * fps).astype(int) - k) + k  # increasing by at least 1
        return cls(fps, index)

    def at(self, frames: Any) -> np.ndarray:
        """Grid indices of video frames (beyond the listed ones: one grid step each)."""
        f = np.asarray(frames, dtype=int)
        last = len(self.index) - 1
        return np.where(f <= last, self.index[np.clip(f, 0, last)], self.index[last] + f - last)

    def raw(self, raw: Scenario) -> Scenario:
        """``raw`` as if filmed at the grid's constant rate (its road users' times unchanged)."""
        count = int(self.at(raw.source.frame_count - 1)) + 1 if raw.source.frame_count else 0
        src = raw.source.model_copy(update={"fps": self.fps, "frame_times": None, "frame_count": count})
        return raw.evolve(source=src)

    def tracks(self, tracks: pd.DataFrame) -> pd.DataFrame:
        return tracks.assign(frame=self.at(tracks["frame"].to_numpy(int))) if len(tracks) else tracks

    def motion(self, motion: tuple[np.ndarray, np.ndarray] | None) -> tuple[np.ndarray, np.ndarray] | None:
        """The camera's per-frame shift on the grid: a step over a gap of n grid frames moved n frames' worth."""
        if motion is None or not len(motion[0]):
            return motion
        frames, shifts = motion
        grid = self.at(frames)
        gap = np.maximum(np.diff(np.r_[grid[0] - 1, grid]), 1)
        return grid, shifts / gap[:, None]

    def spec(self, spec: CrashSpec | None) -> CrashSpec | None:
        return None if spec is None else CrashSpec(int(self.at(spec.frame)), spec.pair, spec.text)

    def back(self, found: CrashFinding, raw: Scenario) -> CrashFinding:
        """``found`` at the video frame nearest its grid frame, at that frame's own time."""
        frame = int(np.argmin(np.abs(self.index - found.frame)))
        return CrashFinding(frame, float(raw.video_time(raw.frame_time(frame))), found.pair, found.confidence,
                            found.evidence)  # fmt: skip


def world_tracks(raw: Scenario) -> dict[int, WorldTrack]:
    """Every agent's ground footprint (world x, y m, heading rad, half width and length m) per video frame
    (fractional), for closeness in 3D."""
    fps = float(raw.source.fps)
    out = {}
    for a in raw.agents:
        tr = a.trajectory
        frames = np.asarray([raw.video_time(t) for t in tr.t], float) * fps
        xy = np.asarray(tr.x, float), np.asarray(tr.y, float)
        out[a.id] = WorldTrack(frames, *xy, a.width / 2, a.length / 2, np.asarray(tr.yaw, float))
    return out


def _with_record(raw: Scenario, record: dict[str, Any], collision: Collision | None) -> Scenario:
    params = dict(raw.provenance.parameters)
    params["crash_detection"] = record
    prov = raw.provenance.model_copy(update={"parameters": params})
    return raw.evolve(collision=collision, provenance=prov)


def _likeliest_pair_near(
    frame: int,
    raw: Scenario,
    tracks: pd.DataFrame,
    motion: tuple[np.ndarray, np.ndarray] | None,
    agents: set[int],
    picture: tuple[int, int, int, int] | None,
) -> CrashFinding | None:
    """The likeliest crash within :data:`AUTO_PAIR_WINDOW_S` of ``frame`` (``--crash FRAME``, any score): the best
    of the whole video's candidates whose contact falls there, else the best found on those frames alone.

    The search on the window alone scores each pair without what came before it (the ego's approach, the jolt's
    baseline): on ccd_000132, whose crash the automatic detection finds at frame 30 (ego and the car it rear-ends,
    0.64), ``--crash 30`` named two other cars (0.08)."""
    fps = float(raw.source.fps)
    w, h = raw.source.width, raw.source.height
    win = int(np.ceil(AUTO_PAIR_WINDOW_S * fps))
    world = world_tracks(raw)
    cands = crash_candidates(tracks, w, h, fps, motion, agents, world=world, picture=picture)
    close = [c for c in cands if abs(c[1] - frame) <= win]
    if close:
        return finding(close[0], fps)
    return detect_crash(
        tracks, w, h, fps, motion, allowed=agents, min_score=0.0, frames=(frame - win, frame + win), world=world,
        picture=picture,
    )  # fmt: skip


def _check_crash_frame(spec: CrashSpec, raw: Scenario) -> None:
    """Refuse a ``--crash`` frame outside the video (or its first frame) in one line."""
    fps = float(raw.source.fps)
    last = (
        raw.source.frame_count - 1
        if raw.source.frame_count
        else int(round(raw.video_time(raw.ego.trajectory.t[-1]) * fps))
    )
    if not 0 < spec.frame <= last:
        where = "is the first frame (a crash needs one before it)" if spec.frame == 0 else "is outside the video"
        raise UserError(f"--crash {spec.text!r}: frame {spec.frame} {where}; give 1..{last}")


def _user_crash(
    spec: CrashSpec,
    raw: Scenario,
    tracks: pd.DataFrame,
    motion: tuple[np.ndarray, np.ndarray] | None,
    agents: set[int],
    picture: tuple[int, int, int, int] | None = None,
) -> CrashFinding:
    _check_crash_frame(spec, raw)
    if spec.pair is not None:
        seen = set(int(v) for v in tracks["track_id"].unique()) if len(tracks) else set()
        for vid in spec.pair:
            if vid != EGO and vid not in seen:
                raise UserError(f"--crash {spec.text!r}: there is no track {vid} in tracks.csv")
            if vid != EGO and vid not in agents:
                raise UserError(f"--crash {spec.text!r}: track {vid} is too short or could not be placed in 3D")
        return CrashFinding(spec.frame, float(raw.video_time(raw.frame_time(spec.frame))), spec.pair, 1.0, {})
    found = _likeliest_pair_near(spec.frame, raw, tracks, motion, agents, picture)
    if found is None:
        raise UserError(f"--crash {spec.text!r}: no road user is near frame {spec.frame}; name the pair (FRAME:ID,ID)")
    t_video = float(raw.video_time(raw.frame_time(spec.frame)))
    return CrashFinding(spec.frame, t_video, found.pair, found.confidence, found.evidence)
