"""extract's detector schedule on a real highway clip: fewer calls while the scene stays calm, from 24 fps only."""

from __future__ import annotations

import itertools

import numpy as np
import pytest

from conftest import DATA, need
from deepcrashtest.perception.detections import Detections
from deepcrashtest.perception.schedule import calm, detect_stable
from deepcrashtest.video.source import open_video

CLIP = DATA / "dashcam_udacity" / "highway_lane_challenge.mp4"


@pytest.fixture(scope="module")
def detected(yolo_ok):
    """The clip's first 80 frames (25 fps) and the real detector's boxes on every 5th."""
    from deepcrashtest.perception.detect import make_detector

    with open_video(need(CLIP)) as src:
        frames = list(itertools.islice(src, 80))
    det = make_detector("yolo26n")
    return frames, {k: det(frames[k].image) for k in range(0, 80, 5)}


def _run(frames, dets, fps):
    calls: list[int] = []
    by_image = {id(f.image): k for k, f in enumerate(frames)}

    def counted(image: np.ndarray) -> Detections:
        calls.append(by_image[id(image)])
        return dets[calls[-1]]

    out = list(detect_stable(frames, counted, 5, fps))
    assert [f.index for f, _ in out] == [f.index for f in frames]
    assert calls == [k for k, (_f, d) in enumerate(out) if d is not None]
    return calls


def test_calm_highway_skips_calls_at_25_fps_never_two_in_a_row(detected):
    frames, dets = detected
    calls = _run(frames, dets, 25.0)
    assert set(calls) <= set(range(0, 80, 5)) and calls[:2] == [0, 5]
    assert max(np.diff(calls)) <= 10  # a skipped call is followed by a call
    assert len(calls) < 16  # the highway's road users stay the same for seconds: calls are skipped
    h = frames[0].image.shape[0]
    for k in range(10, 80, 5):
        before = [c for c in calls if c < k][-2:]
        if k not in calls:
            assert calm(dets[before[0]], dets[before[1]], h)
        elif before[-1] == k - 5:  # the call before was made: the last two calls were not calm
            assert not calm(dets[before[0]], dets[before[1]], h)


def test_every_call_below_24_fps(detected):
    """The 10 fps CCD and 20 fps DAD crash clips get every scheduled call (the same frames read as 20 fps)."""
    frames, dets = detected
    assert _run(frames, dets, 20.0) == list(range(0, 80, 5))


def _cars(*boxes: tuple[int, int, int, int]) -> Detections:
    n = len(boxes)
    return Detections(np.array(boxes, np.float32), np.full(n, 0.8, np.float32), np.array(["car"] * n, dtype="<U10"))


def test_calm_needs_the_same_road_users_apart_and_far():
    h = 720
    a = _cars((100, 300, 160, 340), (600, 320, 660, 360))
    assert calm(a, a, h)
    assert calm(a, _cars((104, 300, 164, 341), (598, 321, 659, 362)), h)  # moved a little
    assert not calm(a, _cars((100, 300, 160, 340)), h)  # one left
    assert not calm(a, _cars((300, 300, 360, 340), (800, 320, 860, 360)), h)  # moved fast
    touching = _cars((100, 300, 160, 340), (150, 300, 210, 340))
    assert not calm(touching, touching, h)  # one passing the other
    near = _cars((100, 300, 160, 340), (500, 300, 900, 700))
    assert not calm(near, near, h)  # a road user at the ego's bumper
