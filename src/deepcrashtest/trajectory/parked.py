"""Parked road users placed a few centimetres into each other: their sizes, not their places, give.

A parked vehicle's length (and, seen from behind, its width) is its class's prior scaled by its measured height
(:mod:`deepcrashtest.geometry.mono_size`): the least measured of its dimensions. Cars parked bumper to bumper or side
by side are then often placed a decimetre into each other (dad_000478, ccd_000031: 0.12-0.13 m all clip long). The
built-in simulator ignores boxes that overlap from their first common moment, but a scenario handed over
(OpenSCENARIO, CommonRoad) starts with two vehicles inside each other. Moving them apart moved them along the line of
sight, away from their boxes in the video (1-2 m: docs/fidelity.md); shortening them by the overlap keeps both where
the video placed them. Metres, radians, world frame.
"""

from __future__ import annotations

from dataclasses import replace
from typing import Any

import numpy as np

from deepcrashtest.trajectory.collision import BoxTrack
from deepcrashtest.trajectory.contact import separation
from deepcrashtest.trajectory.dense import Dense

#: Parked pairs are made this far apart (m) ...
PARKED_GAP_M = 0.05
#: ... by shortening both vehicles' length (or, failing that, width) by at most this share.
PARKED_MAX_SHRINK = 0.1


def parked_apart(agents: list[Dense], pair: tuple[int, ...], warnings: list[str]) -> list[dict[str, Any]]:
    """Shrink every pair of parked agents (``Dense.static``, not in the crash ``pair``: its contact was made with its
    size) whose boxes overlap, in place (their ``vehicle``'s length, else width, both alike, by at most
    ``PARKED_MAX_SHRINK``), until they are ``PARKED_GAP_M`` apart; a pair that needs more is left as it is (parked
    diagonally into each other: a depth error, not a size). Returns one record per shrunk pair."""
    parked = [d for d in agents if d.static and d.id not in pair]
    first = {d.id: {"length": d.vehicle.length, "width": d.vehicle.width} for d in parked}  # a car in two pairs
    records: list[dict[str, Any]] = []
    for i, a in enumerate(parked):
        for b in parked[i + 1 :]:
            t = max(a.t[0], b.t[0])
            if t > min(a.t[-1], b.t[-1]):
                continue
            boxes = (a.box_track(), b.box_track())
            overlap = -_separation(boxes, "length", 1.0, t)
            if overlap <= 0.0:
                continue
            for dim in ("length", "width"):
                least = max((1.0 - PARKED_MAX_SHRINK) * first[d.id][dim] / getattr(d.vehicle, dim) for d in (a, b))
                scale = _least_shrink(boxes, dim, t, least)
                if scale is None:
                    continue
                for d in (a, b):
                    d.vehicle = d.vehicle.model_copy(update={dim: float(getattr(d.vehicle, dim) * scale)})
                records.append({"agents": [a.id, b.id], dim: [round(getattr(d.vehicle, dim), 3) for d in (a, b)]})
                warnings.append(
                    f"agents {a.id} and {b.id}: parked {overlap:.2f} m into each other; their {dim}s shortened by "
                    f"{100 * (1 - scale):.1f} % to keep them {PARKED_GAP_M:g} m apart"
                )
                break
    return records


def _separation(boxes: tuple[BoxTrack, BoxTrack], dim: str, scale: float, t: float) -> float:
    """Separation (m) of the two parked boxes at ``t`` (s) with ``dim`` of both scaled by ``scale``."""
    a, b = (replace(box, **{dim: getattr(box, dim) * scale}) for box in boxes)
    return float(separation(a, b, np.array([t]))[0])


def _least_shrink(boxes: tuple[BoxTrack, BoxTrack], dim: str, t: float, least: float) -> float | None:
    """The largest scale (>= ``least``: no vehicle below ``1 - PARKED_MAX_SHRINK`` of its size, whatever pairs it is
    in) of ``dim`` that puts the pair ``PARKED_GAP_M`` apart, or None when even the smallest does not (bisection)."""
    lo, hi = least, 1.0
    if lo >= hi:
        return None
    if _separation(boxes, dim, lo, t) < PARKED_GAP_M:
        return None
    for _ in range(30):
        mid = 0.5 * (lo + hi)
        lo, hi = (mid, hi) if _separation(boxes, dim, mid, t) >= PARKED_GAP_M else (lo, mid)
    return lo
