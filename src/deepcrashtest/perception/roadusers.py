"""Road users from per-class detections: a two-wheeler and its rider are ONE road user.

Detectors report a person on a scooter as two boxes (``pedestrian`` + ``motorcycle``). The scenario
needs one road user of the two-wheeler's category whose box covers both (its height is the rider's
head to the wheels, which is what the size prior of ``motorcycle``/``bicycle`` in
:mod:`deepcrashtest.geometry.localize` describes). A person box is a rider of a two-wheeler box when

* most of the person's width lies over the two-wheeler (``RIDER_X_OVERLAP`` of the person's width),
* the person's lower part overlaps the two-wheeler vertically (the person's bottom is below the top
  of the two-wheeler's box and not far below its bottom: ``RIDER_BOTTOM_BELOW`` of its height), and
* the person's top is above the two-wheeler's top (a rider sits on it, a walker behind it is taller
  and reaches lower).

Thresholds were chosen by looking at DAD clips 000478/000487 (scooters with riders, annotated frames).
Each person joins at most one two-wheeler (the best overlap); a two-wheeler may carry two (a passenger).
People inside cars (drivers seen through a windscreen) are not road users of their own
(:func:`occupants`); :func:`road_users` applies both.
"""

from __future__ import annotations

import numpy as np

from deepcrashtest.perception.boxes import intersection_over_smaller, nms
from deepcrashtest.perception.detections import Detections

TWO_WHEELERS = ("motorcycle", "bicycle")
MOTOR_VEHICLES = ("car", "van", "truck", "bus")
OCCUPANT_INSIDE = 0.9
RIDER_X_OVERLAP = 0.5
RIDER_BOTTOM_BELOW = 0.25


def rider_pairs(det: Detections) -> list[tuple[int, int]]:
    """(person index, two-wheeler index) for every person riding a two-wheeler of ``det``."""
    cats = np.asarray(det.categories).astype(str)
    persons = np.nonzero(cats == "pedestrian")[0]
    wheels = np.nonzero(np.isin(cats, TWO_WHEELERS))[0]
    if not len(persons) or not len(wheels):
        return []
    p, w = det.boxes[persons].astype(float), det.boxes[wheels].astype(float)
    ix = np.clip(np.minimum(p[:, None, 2], w[None, :, 2]) - np.maximum(p[:, None, 0], w[None, :, 0]), 0, None)
    x_share = ix / np.maximum(p[:, 2] - p[:, 0], 1.0)[:, None]
    wh = np.maximum(w[:, 3] - w[:, 1], 1.0)[None, :]
    bottom_ok = (p[:, None, 3] > w[None, :, 1]) & (p[:, None, 3] <= w[None, :, 3] + RIDER_BOTTOM_BELOW * wh)
    top_ok = p[:, None, 1] < w[None, :, 1]
    ok = (x_share >= RIDER_X_OVERLAP) & bottom_ok & top_ok
    pairs = []
    for i in range(len(persons)):
        if ok[i].any():
            j = int(np.argmax(np.where(ok[i], x_share[i], -1.0)))
            pairs.append((int(persons[i]), int(wheels[j])))
    return pairs


def occupants(det: Detections) -> np.ndarray:
    """Indices of person boxes that are people inside a car, van, truck or bus (seen through its windows).

    A person box lying (``OCCUPANT_INSIDE``) within a motor vehicle's box whose bottom is above the
    lower quarter of that box: a pedestrian in front of a vehicle stands on the road, nearer the camera,
    so its feet are at or below the vehicle's bottom edge in the image.
    """
    cats = np.asarray(det.categories).astype(str)
    persons = np.nonzero(cats == "pedestrian")[0]
    cars = np.nonzero(np.isin(cats, MOTOR_VEHICLES))[0]
    if not len(persons) or not len(cars):
        return np.zeros(0, np.int64)
    p, c = det.boxes[persons].astype(float), det.boxes[cars].astype(float)
    inside = intersection_over_smaller(p, c) >= OCCUPANT_INSIDE
    high = p[:, None, 3] < c[None, :, 3] - 0.25 * (c[None, :, 3] - c[None, :, 1])
    return persons[(inside & high).any(axis=1)]


def road_users(det: Detections) -> Detections:
    """Detections as road users: occupants of vehicles dropped, riders joined to their two-wheelers.

    A two-wheeler that grew by its rider may now cover a part-box of itself (the scooter without the
    rider, detected too): two-wheelers go through NMS again (IoU 0.5, or 80 % inside a better box).
    """
    gone = occupants(det)
    if len(gone):
        det = det.subset(np.setdiff1d(np.arange(len(det)), gone))
    n_before = len(det)
    det = merge_riders(det)
    if len(det) == n_before:
        return det
    wheels = np.flatnonzero(np.isin(det.categories, TWO_WHEELERS))
    kept = wheels[nms(det.boxes[wheels], det.scores[wheels], 0.5, contain_threshold=0.8)]
    return det.subset(np.sort(np.concatenate([np.setdiff1d(np.arange(len(det)), wheels), kept])))


def merge_riders(det: Detections) -> Detections:
    """``det`` with every rider joined to its two-wheeler: the union box, the higher score, one road user.

    Masks (when present) are joined the same way. Persons not riding stay ``pedestrian``.
    """
    pairs = rider_pairs(det)
    if not pairs:
        return det
    boxes, scores = det.boxes.copy(), det.scores.copy()
    masks = None if det.masks is None else det.masks.copy()
    for person, wheel in pairs:
        b, q = boxes[wheel], det.boxes[person]
        boxes[wheel] = [min(b[0], q[0]), min(b[1], q[1]), max(b[2], q[2]), max(b[3], q[3])]
        scores[wheel] = max(scores[wheel], det.scores[person])
        if masks is not None:
            masks[wheel] |= det.masks[person]  # type: ignore[index]
    riders = {person for person, _ in pairs}
    keep = np.array([i for i in range(len(det)) if i not in riders], dtype=np.int64)
    return Detections(boxes, scores, det.categories, masks).subset(keep)
