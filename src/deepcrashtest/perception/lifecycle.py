"""A generic multi-object tracker core: cost matrix in, assignment + track lifecycle out.

Nothing here knows about images or coordinates, so an image-plane tracker (IoU costs, see
:mod:`deepcrashtest.perception.track`) and a world-frame tracker (distance costs in metres) share it::

    core = TrackCore(min_hits=3, max_misses=5)
    result = core.step(cost, max_cost=0.7)          # cost: (len(core.tracks), n_detections)
    for track, det in result.matched: ...           # update the matched tracks' own state
    for det in result.unmatched_detections:
        core.spawn(MyTrack(...))                    # id, state and counters are filled in by spawn
    core.prune()                                    # drop deleted tracks (also returned)

Lifecycle: a new track is TENTATIVE; after ``min_hits`` detections (counting the first) whose
scores (``step(..., scores=)``, ``spawn(track, score)``; 1 each when not given) add up to
``min_evidence`` or more it is CONFIRMED: a run of weak boxes needs more rounds than one of strong
ones. A TENTATIVE track that misses one detection round is DELETED; a CONFIRMED one is DELETED after
more than ``max_misses`` consecutive missed rounds. Ids are given at confirmation
(1, 2, 3 ... in that order, never reused), so short-lived false detections use up no ids;
a TENTATIVE track has id 0 (``ids_at_birth=True``: every track gets its id when spawned, for owners
that report tentative tracks too).

This one lifecycle serves the image tracker (:mod:`deepcrashtest.perception.track`, and so the
monocular 3D path), and the LiDAR world tracker (``deepcrashtest.datasets.kitti.world_tracker``).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field
from enum import Enum
from typing import Generic, TypeVar

import numpy as np


class TrackState(str, Enum):
    TENTATIVE = "tentative"
    CONFIRMED = "confirmed"
    DELETED = "deleted"


@dataclass
class TrackBase:
    """Bookkeeping every track carries; subclass it with the tracker's own state (box, position...)."""

    track_id: int = 0
    state: TrackState = TrackState.TENTATIVE
    hits: int = 0  # detection rounds with a matched detection
    misses: int = 0  # consecutive detection rounds without one
    rounds: int = 0  # detection rounds since creation
    evidence: float = 0.0  # sum of the matched detections' scores (counting the first)

    @property
    def confirmed(self) -> bool:
        return self.state is TrackState.CONFIRMED


T = TypeVar("T", bound=TrackBase)


@dataclass
class Assignment:
    """Result of one optimal assignment: (row, col) pairs and the rows/cols left over."""

    pairs: list[tuple[int, int]]
    unmatched_rows: list[int]
    unmatched_cols: list[int]


def assign(cost: np.ndarray, max_cost: float) -> Assignment:
    """Minimum-cost one-to-one assignment (SciPy Hungarian); pairs costing more than ``max_cost`` are refused.

    Non-finite costs mean "never match". Rows are tracks, columns detections.
    """
    cost = np.asarray(cost, dtype=np.float64)
    n_rows, n_cols = cost.shape
    pairs: list[tuple[int, int]] = []
    if n_rows and n_cols:
        big = max_cost + 1.0 + (np.nanmax(np.abs(cost[np.isfinite(cost)])) if np.isfinite(cost).any() else 0.0)
        safe = np.where(np.isfinite(cost), cost, big)
        from scipy.optimize import linear_sum_assignment  # SciPy loads while the first frames decode

        rows, cols = linear_sum_assignment(safe)
        pairs = [(int(r), int(c)) for r, c in zip(rows, cols, strict=True) if safe[r, c] <= max_cost]
    used_r = {r for r, _ in pairs}
    used_c = {c for _, c in pairs}
    return Assignment(
        pairs, [r for r in range(n_rows) if r not in used_r], [c for c in range(n_cols) if c not in used_c]
    )


def _joined(first: Assignment, more: list[tuple[int, int]]) -> Assignment:
    """``first`` with the pairs ``more`` (among its unmatched rows and columns) added."""
    if not more:
        return first
    rows, cols = {r for r, _ in more}, {c for _, c in more}
    if not rows <= set(first.unmatched_rows) or not cols <= set(first.unmatched_cols):
        raise ValueError("a second matching may only pair rows and columns the first left unmatched")
    return Assignment(
        sorted(first.pairs + more),
        [r for r in first.unmatched_rows if r not in rows],
        [c for c in first.unmatched_cols if c not in cols],
    )


@dataclass
class StepResult(Generic[T]):
    """One detection round: matched (track, detection index) pairs, the detections left unmatched,
    and the tracks that missed."""

    matched: list[tuple[T, int]]
    unmatched_detections: list[int]
    missed: list[T]


@dataclass
class TrackCore(Generic[T]):
    """Track list, id counter and lifecycle rules; the owner supplies costs and per-track state."""

    min_hits: int = 3
    max_misses: int = 5
    tracks: list[T] = field(default_factory=list)
    next_id: int = 1
    ids_at_birth: bool = False
    min_evidence: float = 0.0

    def _met(self, track: T) -> bool:
        return track.hits >= self.min_hits and track.evidence >= self.min_evidence

    def step(
        self,
        cost: np.ndarray,
        max_cost: float,
        scores: np.ndarray | None = None,
        second: Callable[[Assignment], list[tuple[int, int]]] | None = None,
    ) -> StepResult[T]:
        """Assign detections to the current tracks and advance every track's lifecycle by one round
        (``scores``: the detections' scores, added to a matched track's evidence; None: 1 each). ``second``: the
        owner's second matching, given the first assignment, returns more (track row, detection column) pairs
        among the rows and columns it left unmatched."""
        cost = np.asarray(cost, dtype=np.float64)
        if cost.shape[0] != len(self.tracks):
            raise ValueError(f"cost has {cost.shape[0]} rows for {len(self.tracks)} tracks")
        a = assign(cost, max_cost)
        if second is not None:
            a = _joined(a, second(a))
        matched = [(self.tracks[r], c) for r, c in a.pairs]
        missed = [self.tracks[r] for r in a.unmatched_rows]
        for t, c in matched:
            self.hit(t, 1.0 if scores is None else float(scores[c]))
        for t in missed:
            self.miss(t)
        return StepResult(matched, a.unmatched_cols, missed)

    def spawn(self, track: T, score: float = 1.0) -> T:
        """Register a new track from a detection (of ``score``): TENTATIVE, or CONFIRMED with an id when
        one detection meets ``min_hits`` and ``min_evidence``."""
        track.track_id = 0
        track.hits, track.misses, track.rounds, track.evidence = 1, 0, 1, float(score)
        track.state = TrackState.TENTATIVE
        if self.ids_at_birth:
            track.track_id = self._new_id()
        if self._met(track):
            self._confirm(track)
        self.tracks.append(track)
        return track

    def _new_id(self) -> int:
        self.next_id += 1
        return self.next_id - 1

    def _confirm(self, track: T) -> None:
        track.state = TrackState.CONFIRMED
        if not track.track_id:
            track.track_id = self._new_id()

    def hit(self, track: T, score: float = 1.0) -> None:
        track.hits += 1
        track.rounds += 1
        track.misses = 0
        track.evidence += score
        if track.state is TrackState.TENTATIVE and self._met(track):
            self._confirm(track)

    def miss(self, track: T) -> None:
        track.rounds += 1
        track.misses += 1
        if track.state is TrackState.TENTATIVE or track.misses > self.max_misses:
            track.state = TrackState.DELETED

    def delete(self, track: T) -> None:
        """Delete a track for a reason of the owner's (left the image, degenerate state...)."""
        track.state = TrackState.DELETED

    def prune(self) -> list[T]:
        """Remove DELETED tracks from the list and return them."""
        gone = [t for t in self.tracks if t.state is TrackState.DELETED]
        self.tracks = [t for t in self.tracks if t.state is not TrackState.DELETED]
        return gone

    @property
    def confirmed(self) -> list[T]:
        return [t for t in self.tracks if t.state is TrackState.CONFIRMED]
