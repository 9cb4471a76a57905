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
