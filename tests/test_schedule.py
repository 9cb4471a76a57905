"""extract's need-driven detector schedule on a real highway clip: fewer calls while the road users stay put."""

from __future__ import annotations

import itertools

import numpy as np
import pytest

from conftest import DATA, need
from deepcrashtest.perception.detect import make_detector
from deepcrashtest.perception.detections import Detections
from deepcrashtest.perception.schedule import detect_stable, same_road_users
from deepcrashtest.video.source import open_video

CLIP = DATA / "dashcam_udacity" / "highway_lane_challenge.mp4"


@pytest.fixture(scope="module")
def scheduled():
    """The clip's first 80 frames through the schedule (every 5th frame), with the real detector."""
    with open_video(need(CLIP)) as src:
        frames = list(itertools.islice(src, 80))
    det = make_detector("yolo26n")
    calls: list[int] = []

    def counted(image: np.ndarray) -> Detections:
        calls.append(next(k for k, f in enumerate(frames) if f.image is image))
        return det(image)

    out = list(detect_stable(frames, counted, 5))
    return frames, out, calls


def test_calls_only_on_scheduled_frames_never_two_skipped_in_a_row(scheduled):
    frames, out, calls = scheduled
    assert [f.index for f, _ in out] == [f.index for f in frames]
    assert calls == [k for k, (_f, d) in enumerate(out) if d is not None]
    assert set(calls) <= set(range(0, 80, 5)) and calls[:2] == [0, 5]
    assert max(np.diff(calls)) <= 10  # a skipped call is followed by a call
    # the highway's road users stay the same for seconds: calls are skipped (measured: 10 of 16 made)
    assert len(calls) < 16


def test_a_skipped_call_follows_two_calls_that_agree(scheduled):
    _frames, out, calls = scheduled
    dets = {k: d for k, (_f, d) in enumerate(out) if d is not None}
    for k in range(10, 80, 5):
        before = [c for c in calls if c < k][-2:]
        skipped = k not in dets
        if skipped:
            assert same_road_users(dets[before[0]], dets[before[1]])
        elif before[-1] == k - 5:  # the call before was made: the last two calls differed
            assert not same_road_users(dets[before[0]], dets[before[1]])


def test_same_road_users_needs_as_many_matched(scheduled):
    _frames, out, _calls = scheduled
    d = next(d for _f, d in out if d is not None and len(d) >= 2)
    assert same_road_users(d, d)
    fewer = d.subset(np.arange(1, len(d)))
    strong = (d.scores >= 0.5).sum() != (fewer.scores >= 0.5).sum()
    assert same_road_users(d, fewer) is not strong
    moved = Detections(d.boxes + np.array([200.0, 0.0, 200.0, 0.0], np.float32), d.scores, d.categories)
    assert not same_road_users(d, moved) or not (d.scores >= 0.5).any()
