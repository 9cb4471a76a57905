"""The focal length from vehicles driving along the road (external poses), on real KITTI data.

KITTI tracking training sequence 0002 (233 frames; not one of the held-out 3, 8, 10): nearly every
car moves, the ego does not turn and its pitch bounce is weak; the parked-vehicle estimate has 2
agreeing tracks (536 px, true 721) and is not used, and the unknown camera read the focal length
12.5 % short (632 px). A car driving ahead while the ego slows down and speeds up again (5-12 m/s)
measures it."""

from __future__ import annotations

import numpy as np
import pytest

from deepcrashtest.eval.kitti_mono import DEFAULT_MONO, image_tracks, prepare_mono
from deepcrashtest.geometry.egomotion import EgoMotion
from deepcrashtest.geometry.selfcalib import BOX_HEIGHT_EXCESS, _usable, focal_from_motion, self_calibrate
from deepcrashtest.geometry.selfcalib_moving import focal_from_moving
from deepcrashtest.scenario import Camera


@pytest.fixture(scope="module")
def seq2(kitti_root):
    prep = prepare_mono(kitti_root, 2)
    return prep, image_tracks(prep, DEFAULT_MONO), EgoMotion.from_poses(prep.world.poses, 10.0)


def test_moving_cars_give_the_focal_length(seq2):
    prep, tracks, ego = seq2
    cx = prep.size[0] / 2
    parked = focal_from_motion(tracks, prep.size, cx, ego)
    assert parked is None or parked[2] < 3  # too few parked cars agree (measured 2)
    moving = focal_from_moving(_usable(tracks, prep.size), cx, ego, 621.0, BOX_HEIGHT_EXCESS)
    assert moving is not None and abs(moving[0] / prep.camera.fy - 1.0) < 0.08, moving  # measured -5.8 %
    assert moving[1] < 0.05
    # without the ego's speed changes (a steady straight drive) the depth scale is not measurable
    n = len(prep.world.poses)
    straight = np.tile(np.eye(4), (n, 1, 1))
    straight[:, 2, 3] = np.arange(n) * 1.0  # 10 m/s straight ahead
    steady = EgoMotion.from_poses(straight, 10.0)
    assert focal_from_moving(_usable(tracks, prep.size), cx, steady, 621.0, BOX_HEIGHT_EXCESS) is None


def test_self_calibration_uses_the_moving_cars(seq2):
    prep, tracks, ego = seq2
    start = Camera(fx=621.0, fy=621.0, cx=prep.size[0] / 2, cy=prep.size[1] / 2, height_m=1.3)
    cal = self_calibrate(tracks, start, prep.size, ego)
    assert abs(cal.fy / prep.camera.fy - 1.0) < 0.08, cal.fy  # was -12.5 % (632 px)
    assert cal.camera.intrinsics_source == "self_calibration"
    assert any(n.startswith("focal length estimates") and "moving" in n for n in cal.notes)
