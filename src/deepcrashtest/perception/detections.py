"""The detector contract: :class:`Detections` (pixel boxes, scores, road-user categories) and the
:class:`Detector` protocol every backend (``perception.detect``, ``perception.yolo_onnx``, a user's) follows."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Protocol

import numpy as np

CATEGORIES = ("car", "truck", "bus", "motorcycle", "bicycle", "pedestrian")


@dataclass
class Detections:
    """Detections of one image, all in original-image pixels.

    ``boxes`` (N, 4) float32 x1, y1, x2, y2; ``scores`` (N,) float32 in [0, 1]; ``categories``
    (N,) str from :data:`CATEGORIES`; ``masks`` optional (N, H, W) bool instance masks.
    """

    boxes: np.ndarray
    scores: np.ndarray
    categories: np.ndarray
    masks: np.ndarray | None = None

    def __len__(self) -> int:
        return int(self.boxes.shape[0])

    @staticmethod
    def empty() -> Detections:
        return Detections(np.zeros((0, 4), np.float32), np.zeros(0, np.float32), np.zeros(0, dtype="<U10"))

    def subset(self, idx: np.ndarray) -> Detections:
        idx = np.asarray(idx, dtype=np.int64)
        masks = None if self.masks is None else self.masks[idx]
        return Detections(self.boxes[idx], self.scores[idx], self.categories[idx], masks)


class Detector(Protocol):
    """Anything that maps a BGR uint8 image to :class:`Detections`."""

    name: str

    def __call__(self, image: np.ndarray) -> Detections: ...


class InPicture:
    """``detector`` run on the picture ``area = (x0, y0, x1, y1)`` (px) inside black bars, its boxes
    (and masks) put back in frame pixels. The bars are no part of the scene, and a detector that
    scales the whole frame to its input sees the picture smaller than without them (letterboxed
    dad_000478: 1280x960 at 864x648 instead of 1280x720 at 864x480, the scooter missed at the crash)."""

    def __init__(self, detector: Detector, area: tuple[int, int, int, int]) -> None:
        self.detector = detector
        self.area = tuple(int(v) for v in area)
        self.name = detector.name

    def __call__(self, image: np.ndarray) -> Detections:
        x0, y0, x1, y1 = self.area
        h, w = image.shape[:2]
        if (x0, y0, x1, y1) == (0, 0, w, h):
            return self.detector(image)
        det = self.detector(np.ascontiguousarray(image[y0:y1, x0:x1]))
        boxes = (det.boxes + np.array([x0, y0, x0, y0], det.boxes.dtype)).astype(np.float32)
        masks = None
        if det.masks is not None:
            masks = np.zeros((len(det), h, w), bool)
            masks[:, y0:y1, x0:x1] = det.masks
        return Detections(boxes, det.scores, det.categories, masks)


def in_picture(detector: Detector, area: tuple[int, int, int, int] | None, width: int, height: int) -> Detector:
    """``detector`` on the picture inside black bars (:class:`InPicture`); itself without bars."""
    if area is None or tuple(area) == (0, 0, width, height):
        return detector
    return InPicture(detector, area)
