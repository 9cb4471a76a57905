"""The default detector (YOLO26n, AGPL-3.0 weights, exported once by `make models`) on real KITTI frames.

The 6 labelled KITTI tracking frames (sequences 0001, 0016; 27 moderate cars) chose the input size
(an input of the frame's aspect holding 640x640 pixels): car recall 0.81 (22/27), precision 0.81, at
1152x352; 0.59 at 640x192; 1248-1472 wide inputs gave 0.74-0.96 with no trend (bench/detector_compare.py).
"""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from conftest import KITTI_TRACKING, need
from deepcrashtest.datasets.kitti.detection_eval import MatchCounts, match_frame, split_kitti_cars
from deepcrashtest.datasets.kitti.files import read_labels
from deepcrashtest.errors import UserError
from deepcrashtest.perception.detect import DEFAULT_DETECTOR, make_detector
from deepcrashtest.perception.models import model_dir


@pytest.fixture(scope="module")
def yolo(yolo_ok):
    return make_detector(DEFAULT_DETECTOR)


def test_default_detector_finds_kitti_cars(yolo):
    root = need(KITTI_TRACKING)
    total = MatchCounts()
    for seq in ("0001", "0016"):
        labels = read_labels(root / "label_02" / f"{seq}.txt")
        for f in sorted((root / "image_02" / seq).glob("*.png")):
            det = yolo(cv2.imread(str(f)))
            cars = det.subset(np.flatnonzero(np.isin(det.categories, ["car", "truck", "bus"])))
            total += match_frame(cars.boxes, *split_kitti_cars(labels[labels["frame"] == int(f.stem)]))
    assert total.tp + total.fn == 27
    assert total.recall >= 0.8 and total.precision >= 0.6


def test_input_keeps_the_frame_aspect_at_640x640_pixels(yolo):
    assert yolo.input_size(720, 1280) == (480, 864)
    assert yolo.input_size(375, 1242) == (352, 1152)


def test_missing_model_and_bad_options_are_user_errors(tmp_path, monkeypatch):
    monkeypatch.setenv("DEEPCRASHTEST_MODELS", str(tmp_path))
    assert model_dir() == tmp_path
    with pytest.raises(UserError, match="make models"):
        make_detector("yolo26n")
    with pytest.raises(UserError, match="unknown yolo26n option"):
        make_detector("yolo26n:colour=1")
    assert make_detector("ssd:tiles=0").name.startswith("ssd-mobilenet")


def test_letterbox_blob_is_the_plain_rgb_float_formula(yolo):
    """The one-pass blob (rows, channel order, scaling) equals the plain formula bit for bit, on a real frame."""
    img = cv2.imread(str(sorted((need(KITTI_TRACKING) / "image_02" / "0001").glob("*.png"))[0]))
    for hw in (yolo.input_size(*img.shape[:2]), (192, 320)):
        blob, r, px, py = yolo._letterbox(img, hw)
        assert blob.shape == (1, 3, *hw) and blob.dtype == np.float32 and blob.flags.c_contiguous
        nw, nh = int(round(img.shape[1] * r)), int(round(img.shape[0] * r))
        canvas = np.full((*hw, 3), 114, np.uint8)
        canvas[int(py) : int(py) + nh, int(px) : int(px) + nw] = cv2.resize(img, (nw, nh))
        assert np.array_equal(blob, canvas[:, :, ::-1].transpose(2, 0, 1)[None].astype(np.float32) / 255.0)
