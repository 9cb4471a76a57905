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
Two more cases, chosen on DAD clips 000487 and 000512 (frames 85-90, the contact frames' boxes):

* **Two two-wheelers in one box** (:func:`split_two_wheelers`): the detector sometimes reports two
  scooters side by side as one box. A two-wheeler seen side-on is at most ~2x as wide as tall (1.7-2.2 m
  long, ~1.1 m tall); a box wider than ``SPLIT_ASPECT`` x its height whose riders sit side by side
  (centres more than ``SPLIT_RIDER_GAP`` of their mean width apart) is cut between the riders: one
  two-wheeler per rider (dad_000512: 424x148 px over the two colliding scooters).
* **Riders whose two-wheeler is hidden** (:func:`rider_groups`): a scooter with two riders seen from
  behind at the ego's bumper is two person boxes and no two-wheeler (the riders hide it). Two persons
  standing at the same distance (bottoms within ``GROUP_BOTTOM`` of their height, heights within
  ``GROUP_HEIGHT_RATIO``) whose boxes overlap horizontally (``GROUP_X_OVERLAP`` of the narrower) and
  whose union is no taller than ``GROUP_MAX_ASPECT`` x its width (two walkers side by side are taller:
  a walker's box is ~3x as tall as wide), and where the detector boxed both riders in one squat box or both
  are at the ego's bumper (``GROUP_COVER``, ``GROUP_AT_BOTTOM``, ``GROUP_NEAR_WIDTH``), are riders of one
  two-wheeler: one ``motorcycle``.

People inside cars (drivers seen through a windscreen) are not road users of their own
(:func:`occupants`), and one vehicle reported as two classes (a pickup as ``car`` and ``truck``, boxes
almost the same) is one road user (:func:`one_vehicle_per_box`); :func:`road_users` applies all of these.
"""

from __future__ import annotations

from collections.abc import Mapping

import numpy as np

from deepcrashtest.perception.boxes import intersection_over_smaller, nms
from deepcrashtest.perception.detections import Detections

TWO_WHEELERS = ("motorcycle", "bicycle")
MOTOR_VEHICLES = ("car", "van", "truck", "bus")
OCCUPANT_INSIDE = 0.9
RIDER_X_OVERLAP = 0.5
RIDER_BOTTOM_BELOW = 0.25
SPLIT_ASPECT = 2.5
SPLIT_RIDER_GAP = 0.5
GROUP_BOTTOM = 0.1
GROUP_HEIGHT_RATIO = 1.3
GROUP_X_OVERLAP = 0.3
GROUP_MAX_ASPECT = 1.6
#: ... and either one of their boxes is squat (no taller than GROUP_MAX_ASPECT x its width: the detector's one box
#: over both riders) and covers the other across GROUP_COVER of the narrower's width, or both are at the ego's bumper
#: (bottoms below GROUP_AT_BOTTOM of the picture's height, the two-wheeler under them out of view, and together at
#: least GROUP_NEAR_WIDTH of its width: within ~3 m). Two walkers side by side, upright and with their feet in view,
#: are two pedestrians: on the pedestrian labels of the 16 KITTI training sequences other than 3, 8, 10, 13, 16 the
#: rule without these conditions joined 3.03 % of the boxes (in crossings among cyclists the walkers' tracks became
#: motorcycles), with them 0.87 % (the covering box alone 0.66 %; the bottom rows without the width 1.45 %: KITTI's
#: 375-row frames reach the feet of walkers ~7 m away). dad_000487's riders at the ego's bumper (frames 84-88: a
#: 1.3-1.4 box over both, covering 0.93-0.99 of the other; frame 90: two upright boxes overlapping 0.44, bottoms at
#: 694-698 of 720 rows, together 25 % of the width) stay one motorcycle.
GROUP_COVER = 0.9
GROUP_AT_BOTTOM = 0.93
GROUP_NEAR_WIDTH = 0.2
#: Two motor-vehicle boxes of different classes overlapping this much (IoU) are one vehicle reported twice
#: by a detector whose NMS runs per class (YOLO's): the better-scored box stays. A car in front of a truck
#: overlaps it less (its box lies inside the truck's: IoU = area ratio). dad_000550 re-encoded at crf 35 and
#: at 1.5x focal length: its pickup tracked twice, as ``car`` and ``truck`` (IoU 0.96-0.99), two crash pairs
#: with the scooter.
SAME_VEHICLE_IOU = 0.8
#: A track seen as a two-wheeler in at least this share of its two-wheeler + person frames (or votes) is a
#: two-wheeler: a rider whose scooter is hidden is detected as a person, a walker seldom as a two-wheeler (joined with
#: a bicycle box beside it now and then: ``perception.track.WHEEL_LATCH_HITS``).
#: dad_000487: the two riders at the ego's bumper are a two-wheeler in 2 of their 7 detection rounds.
RIDER_TRACK_SHARE = 0.25


def track_category(votes: Mapping[str, float]) -> str:
    """A track's category from its class ``votes`` (class -> summed scores, or frame counts): the class with
    most votes, except that a two-wheeler wins over ``pedestrian`` with ``RIDER_TRACK_SHARE`` of their votes
    (one road user: the two-wheeler and its riders)."""
    best = min(votes, key=lambda k: (-votes[k], k))  # ties: the first name, as pandas' mode
    wheels = {k: v for k, v in votes.items() if k in TWO_WHEELERS and v > 0}
    if best == "pedestrian" and wheels:
        wheel = max(wheels, key=lambda k: wheels[k])
        if sum(wheels.values()) >= RIDER_TRACK_SHARE * (sum(wheels.values()) + votes[best]):
            return wheel
    return best


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


def road_users(det: Detections, picture: tuple[float, float, float, float] | None = None) -> Detections:
    """Detections as road users: occupants of vehicles dropped, riders joined to their two-wheelers
    (``picture``: the picture's ``(x0, y0, x1, y1)`` in the frame, px, inside any black bars, for :func:`rider_groups`).

    A two-wheeler that grew by its rider may now cover a part-box of itself (the scooter without the
    rider, detected too): two-wheelers go through NMS again (IoU 0.5, or 80 % inside a better box).
    """
    det = one_vehicle_per_box(det)
    gone = occupants(det)
    if len(gone):
        det = det.subset(np.setdiff1d(np.arange(len(det)), gone))
    n_before = len(det)
    det = rider_groups(merge_riders(split_two_wheelers(det)), picture)
    if len(det) == n_before:
        return det
    return _suppressed_within(det, np.flatnonzero(np.isin(det.categories, TWO_WHEELERS)), 0.5, contain_threshold=0.8)


def one_vehicle_per_box(det: Detections) -> Detections:
    """``det`` without the motor-vehicle boxes that repeat a better-scored one of another class
    (IoU >= ``SAME_VEHICLE_IOU``): one road user per vehicle whatever the detector's NMS did across classes."""
    cats = np.asarray(det.categories).astype(str)
    cars = np.flatnonzero(np.isin(cats, MOTOR_VEHICLES))
    if len(cars) < 2 or len(np.unique(cats[cars])) < 2:
        return det
    return _suppressed_within(det, cars, SAME_VEHICLE_IOU)


def _suppressed_within(det: Detections, which: np.ndarray, iou: float, contain_threshold: float = 1.01) -> Detections:
    """``det`` with NMS (:func:`~deepcrashtest.perception.boxes.nms`) run among the boxes ``which`` (indices) only,
    every other box kept; ``det`` itself when nothing is suppressed."""
    kept = which[nms(det.boxes[which], det.scores[which], iou, contain_threshold=contain_threshold)]
    if len(kept) == len(which):
        return det
    return det.subset(np.sort(np.concatenate([np.setdiff1d(np.arange(len(det)), which), kept])))


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


def split_two_wheelers(det: Detections) -> Detections:
    """``det`` with every too-wide two-wheeler box that carries riders side by side cut into one box per rider.

    The cut lies halfway between neighbouring riders' centres; each part keeps the two-wheeler's rows,
    score and category (masks are cut the same way)."""
    pairs = rider_pairs(det)
    by_wheel: dict[int, list[int]] = {}
    for person, wheel in pairs:
        by_wheel.setdefault(wheel, []).append(person)
    boxes, scores, cats = list(det.boxes), list(det.scores), list(det.categories)
    masks = None if det.masks is None else list(det.masks)
    drop = []
    for wheel, persons in by_wheel.items():
        b = det.boxes[wheel].astype(float)
        if len(persons) < 2 or (b[2] - b[0]) <= SPLIT_ASPECT * (b[3] - b[1]):
            continue
        p = det.boxes[persons].astype(float)
        inside = intersection_over_smaller(p, p) >= OCCUPANT_INSIDE
        area = (p[:, 2] - p[:, 0]) * (p[:, 3] - p[:, 1])
        part = (inside & (area[:, None] < area[None, :])).any(axis=1)  # a part-box of a rider: not a rider
        p = p[~part]
        if len(p) < 2:
            continue
        centres = np.sort(0.5 * (p[:, 0] + p[:, 2]))
        if np.diff(centres).min() < SPLIT_RIDER_GAP * float(np.mean(p[:, 2] - p[:, 0])):
            continue  # a rider and a passenger, one behind the other
        cuts = np.r_[b[0], 0.5 * (centres[1:] + centres[:-1]), b[2]]
        drop.append(wheel)
        for x0, x1 in zip(cuts[:-1], cuts[1:], strict=True):
            boxes.append(np.array([x0, b[1], x1, b[3]], dtype=det.boxes.dtype))
            scores.append(det.scores[wheel])
            cats.append(det.categories[wheel])
            if masks is not None:
                m = np.zeros_like(det.masks[wheel])  # type: ignore[index]
                m[:, int(round(x0)) : int(round(x1))] = det.masks[wheel][:, int(round(x0)) : int(round(x1))]  # type: ignore[index]
                masks.append(m)
    if not drop:
        return det
    keep = np.array([i for i in range(len(boxes)) if i not in drop], dtype=np.int64)
    out = Detections(
        np.asarray(boxes, dtype=det.boxes.dtype), np.asarray(scores, dtype=det.scores.dtype),
        np.asarray(cats, dtype=det.categories.dtype), None if masks is None else np.asarray(masks),
    )  # fmt: skip
    return out.subset(keep)


def rider_groups(det: Detections, picture: tuple[float, float, float, float] | None = None) -> Detections:
    """``det`` with every group of persons riding one hidden two-wheeler (see the module docstring) joined
    into one ``motorcycle`` box (the union, the highest score); ``picture``: the picture's ``(x0, y0, x1, y1)``, px
    (None: unknown, only a box over both riders groups them). Call after :func:`merge_riders`."""
    persons = np.flatnonzero(np.asarray(det.categories).astype(str) == "pedestrian")
    if len(persons) < 2:
        return det
    p = det.boxes[persons].astype(float)
    h = np.maximum(p[:, 3] - p[:, 1], 1.0)
    w = np.maximum(p[:, 2] - p[:, 0], 1.0)
    ix = np.clip(np.minimum(p[:, None, 2], p[None, :, 2]) - np.maximum(p[:, None, 0], p[None, :, 0]), 0, None)
    hmin = np.minimum(h[:, None], h[None, :])
    lo, hi = np.minimum(p[:, None, :2], p[None, :, :2]), np.maximum(p[:, None, 2:], p[None, :, 2:])
    union = np.concatenate([lo, hi], axis=-1)
    squat = h <= GROUP_MAX_ASPECT * w
    narrower = np.minimum(w[:, None], w[None, :])
    covered = (ix >= GROUP_COVER * narrower) & (squat[:, None] | squat[None, :])  # one box over both riders
    if picture is None:
        at_bumper = np.zeros((len(p), len(p)), bool)
    else:
        x0, y0, x1, y1 = picture
        low = p[:, 3] >= y0 + GROUP_AT_BOTTOM * (y1 - y0)
        at_bumper = low[:, None] & low[None, :] & ((union[..., 2] - union[..., 0]) >= GROUP_NEAR_WIDTH * (x1 - x0))
    ok = (
        (np.abs(p[:, None, 3] - p[None, :, 3]) <= GROUP_BOTTOM * hmin)
        & (np.maximum(h[:, None], h[None, :]) <= GROUP_HEIGHT_RATIO * hmin)
        & (ix >= GROUP_X_OVERLAP * narrower)
        & (union[..., 3] - union[..., 1] <= GROUP_MAX_ASPECT * (union[..., 2] - union[..., 0]))
        & (covered | at_bumper)
    )
    np.fill_diagonal(ok, False)
    boxes, scores, cats = det.boxes.copy(), det.scores.copy(), np.asarray(det.categories).copy()
    masks = None if det.masks is None else det.masks.copy()
    gone: set[int] = set()
    for i, j in zip(*np.nonzero(np.triu(ok)), strict=True):
        a, b = int(persons[i]), int(persons[j])
        if a in gone or b in gone:
            continue
        keep, other = (a, b) if det.scores[a] >= det.scores[b] else (b, a)
        boxes[keep] = union[i, j]
        cats[keep] = "motorcycle"
        if masks is not None:
            masks[keep] |= det.masks[other]  # type: ignore[index]
        gone.add(other)
    if not gone:
        return det
    idx = np.array([k for k in range(len(det)) if k not in gone], dtype=np.int64)
    return Detections(boxes, scores, cats, masks).subset(idx)
