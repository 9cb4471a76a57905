"""yolo26n's fine pass without the sky rows (``sky``), on real frames: the rows it keeps are the pixels the whole
image's input has there, the boxes stay, and a road user the coarse pass sees reaching up into the band gets the whole
image; without the coarse pass nothing is left out."""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from conftest import DATA, need
from deepcrashtest.perception.boxes import iou_matrix
from deepcrashtest.perception.detect import make_detector
from deepcrashtest.video.source import open_video

HIGHWAY = DATA / "dashcam_udacity" / "highway_lane_challenge.mp4"
QUEUE = DATA / "kitti_raw_highway_queue" / "image_02" / "data"


def _highway_frame(index: int) -> np.ndarray:
    with open_video(need(HIGHWAY)) as src:
        for fr in src:
            if fr.index == index:
                return fr.image
    raise AssertionError(f"no frame {index}")


@pytest.fixture(scope="module")
def sky(yolo_ok):
    return make_detector("yolo26n:sky=0.2")


def test_kept_rows_see_the_whole_images_pixels(sky):
    """1280x720: 864x480 -> 864x384, the top 144 rows left out, the same scale and the same input pixels below."""
    image = _highway_frame(100)
    whole = make_detector("yolo26n:sky=0")
    near = sky._coarse_pass(image)[0]
    hw, top = sky._fine_input(720, 1280, near)
    assert (hw, top) == ((384, 864), 144)
    assert whole._fine_input(720, 1280, near) == ((480, 864), 0)
    assert sky._fine_input(720, 1280, None) == ((480, 864), 0)  # no coarse pass: the whole image
    full, r0, px0, py0 = whole._letterbox(image, (480, 864))
    kept, r1, px1, py1 = sky._letterbox(image[top:], hw)
    assert (r0, px0, py0) == (r1, px1, py1)
    assert np.array_equal(full[:, :, 96:], kept)


def test_boxes_stay_without_the_sky(sky):
    """The highway clip's cars sit below the band: the same boxes (score >= 0.5) with and without it."""
    whole = make_detector("yolo26n:sky=0")
    for index in (0, 100, 200):
        image = _highway_frame(index)
        assert sky._fine_input(720, 1280, sky._coarse_pass(image)[0])[1] == 144
        a, b = whole(image), sky(image)
        a, b = a.boxes[a.scores >= 0.5], b.boxes[b.scores >= 0.5]
        assert len(a) == len(b) >= 1
        assert iou_matrix(a.astype(float), b.astype(float)).max(axis=1).min() > 0.9


def test_a_road_user_in_the_band_gets_the_whole_image(yolo_ok):
    """KITTI raw highway queue frame 36: a truck beside the ego reaches 90 px from the top of 375; cutting the
    band (69 rows) always lost it. The coarse pass sees it up there, so the fine pass takes the whole image."""
    sky = make_detector("yolo26n:sky=0.2")
    image = cv2.imread(str(need(QUEUE / "0000000036.png")))
    near = sky._coarse_pass(image)[0]
    assert sky._fine_input(375, 1242, near)[1] == 0
    assert sky._fine_input(375, 1242, near[near[:, 1] > 200])[1] == 69  # without it the band would be cut
    truck = np.array([[730.0, 90.0, 837.0, 284.0]])
    assert iou_matrix(truck, sky(image).boxes.astype(float)).max() >= 0.7
    _out, pred, r, px, py = sky._run(image[69:], (288, 1152))  # the fine pass with the band cut: no truck
    boxes, score, _cls, _keep = sky._candidates(pred, r, px, py - 69 * r, (375, 1242))
    assert iou_matrix(truck, boxes[score >= 0.5].astype(float)).max(initial=0.0) < 0.5
