"""YOLO26n int8 (``--detector yolo26n:int8``, built by ``make models`` with ``tools/quantize_yolo.py``) on real
KITTI frames against the float model.

Calibrated on training frames only (highway_solid_white_right.mp4, KITTI odometry seq00); the KITTI tracking
frames here (sequences 0001, 0016) were not used to build it.
"""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from conftest import KITTI_TRACKING, need
from deepcrashtest.datasets.kitti.detection_eval import MatchCounts, match_frame, split_kitti_cars
from deepcrashtest.datasets.kitti.files import read_labels
from deepcrashtest.errors import UserError
from deepcrashtest.perception.detect import make_detector
from deepcrashtest.perception.models import yolo26n_path

VEHICLES = ["car", "truck", "bus"]


@pytest.fixture(scope="module")
def pair(yolo_ok):
    try:
        yolo26n_path(int8=True)
    except UserError as exc:
        pytest.skip(f"{exc} (make test builds it)")
    return make_detector("yolo26n"), make_detector("yolo26n:int8")


def _iou(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    lo, hi = np.maximum(a[:, None, :2], b[None, :, :2]), np.minimum(a[:, None, 2:], b[None, :, 2:])
    inter = np.prod(np.clip(hi - lo, 0, None), axis=2)
    area = lambda z: np.prod(z[:, 2:] - z[:, :2], axis=1)  # noqa: E731
    return inter / (area(a)[:, None] + area(b)[None, :] - inter)


def _frames():
    root = need(KITTI_TRACKING)
    for seq in ("0001", "0016"):
        labels = read_labels(root / "label_02" / f"{seq}.txt")
        for f in sorted((root / "image_02" / seq).glob("*.png")):
            yield cv2.imread(str(f)), labels[labels["frame"] == int(f.stem)]


def test_int8_boxes_match_the_float_model(pair):
    fp, q = pair
    assert q.name.startswith("yolo26n(int8,") and fp.name.startswith("yolo26n(area")
    close = total = 0
    for image, _ in _frames():
        a, b = fp(image), q(image)
        cars = a.boxes[np.isin(a.categories, VEHICLES)]
        assert len(cars) and len(b)
        best = _iou(cars, b.boxes).max(axis=1)
        close, total = close + int((best >= 0.9).sum()), total + len(cars)
    assert close >= 0.75 * total  # measured: 55 of the float model's 67 boxes (all classes) at IoU >= 0.9


def test_int8_finds_kitti_cars(pair):
    total = MatchCounts()
    for image, labels in _frames():
        det = pair[1](image)
        cars = det.subset(np.flatnonzero(np.isin(det.categories, VEHICLES)))
        total += match_frame(cars.boxes, *split_kitti_cars(labels))
    assert total.tp + total.fn == 27
    assert total.recall >= 0.8 and total.precision >= 0.6
