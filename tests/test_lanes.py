"""Lane detection and tracking on the real Udacity highway clips."""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from conftest import DATA, need
from deepcrashtest.geometry.camera import calibrate_chessboard, scale_camera, vanishing_point_from_lines, with_horizon
from deepcrashtest.perception.lanes import ClassicalLaneDetector, LaneDetector, draw_lanes

UDACITY = DATA / "dashcam_udacity"


@pytest.fixture(scope="module")
def chessboard_camera():
    cam, _, _ = calibrate_chessboard(need(UDACITY / "camera_calibration"), max_images=8)
    return cam


def _frames(name: str, count: int) -> list[np.ndarray]:
    cap = cv2.VideoCapture(str(need(UDACITY / name)))
    out = []
    while len(out) < count:
        ok, f = cap.read()
        if not ok:
            break
        out.append(f)
    cap.release()
    return out


def _run(frames, cam, dashboard_rows):
    h, w = frames[0].shape[:2]
    cam = scale_camera(cam, w / 1280.0).model_copy(update={"height_m": 1.3})
    probe = ClassicalLaneDetector(cam, mask_bottom_rows=dashboard_rows)
    segs = [
        [float(ln.u_at(ln.v_top)), ln.v_top, float(ln.u_at(ln.v_bottom)), ln.v_bottom]
        for f in frames[:10]
        for ln in probe.detect(f)
    ]
    vp = vanishing_point_from_lines(np.array(segs), w, h)
    assert vp is not None and abs(vp[1] - cam.cy) < 0.1 * h  # a level camera: horizon near the centre
    det: LaneDetector = ClassicalLaneDetector(with_horizon(cam, vp[1], "vanishing_point"), dashboard_rows)
    states = [det.update(f, i / 25.0) for i, f in enumerate(frames)]
    assert isinstance(det, ClassicalLaneDetector)
    return det.timeline(), states


@pytest.mark.parametrize(
    ("name", "dashboard_rows", "min_found"),
    [("highway_solid_white_right.mp4", 0, 0.9), ("highway_lane_challenge.mp4", 60, 0.8)],
)
def test_ego_lane_found_with_plausible_width(chessboard_camera, name, dashboard_rows, min_found):
    tl, states = _run(_frames(name, 120), chessboard_camera, dashboard_rows)
    # measured (full clips): both boundaries in 100 % / 94 % of frames, median width 3.80 / 3.90 m
    assert tl.both_found.mean() >= min_found
    width = tl.median_lane_width()
    assert width is not None and 3.0 <= width <= 4.2
    assert not tl.warnings
    assert np.nanpercentile(np.abs(tl.lateral_offset), 95) < 0.8  # the car keeps to its lane in these clips
    assert (np.diff(tl.lane_index) == 0).all()
    # tracked ids persist: the ego boundaries keep their ids through most frames
    left_ids = [s.left.track_id for s in states if s.left is not None]
    assert max(left_ids.count(i) for i in set(left_ids)) > 0.6 * len(left_ids)
    frame = _frames(name, 1)[0]
    over = draw_lanes(frame, states[-1])
    assert over.shape == frame.shape and (over != frame).any()
    # copy=False (extract draws onto the annotator's copy): the same pixels, drawn into the frame itself
    same = frame.copy()
    assert draw_lanes(same, states[-1], copy=False) is same and np.array_equal(same, over)


def test_a_line_inside_the_lane_is_not_taken_for_its_boundary(chessboard_camera):
    """The challenge clip's concrete has seams and tar lines between its markings: the nearest line left of the image
    centre was the ego lane's left boundary even when it ran through the lane's middle (a 2.2-3.0 m lane in 10 of the
    first 120 frames, drawn so in the annotated video, the lateral offset off by a metre). A pair whose width is
    off the lane's median so far by more than 20 % gives way to one that fits: 2 such frames are left (on the whole
    clip 16 -> 2, the project video's 1,260 frames 22 -> 3, the solid-white clip 2 -> 0)."""
    tl, states = _run(_frames("highway_lane_challenge.mp4", 120), chessboard_camera, 60)
    width = tl.lane_width[tl.both_found]
    assert ((width < 3.0) | (width > 4.6)).sum() <= 2  # main: 10
    assert tl.both_found.mean() >= 0.85  # 0.89 as before: the pair is chosen among the lines found
    assert np.nanpercentile(np.abs(tl.lateral_offset), 95) < 0.6


def test_the_ego_lane_is_drawn_only_where_measured_with_a_plausible_width():
    """Green boundaries and the width / offset text only for a measured lane of a plausible width; a pair of lines
    1.1 m apart (dad_000487's lines up a building front) is drawn as other lines, thin yellow."""
    from deepcrashtest.perception.lanes import LaneLine, LaneState

    frame = np.zeros((720, 1280, 3), np.uint8)
    left, right = LaneLine(-1.2, 1100.0, 400.0, 719.0), LaneLine(1.2, 180.0, 400.0, 719.0)

    def drawn(width):
        state = LaneState(0, 0.0, [left, right], left, right, lane_width=width, lateral_offset=0.1, roi_top=400.0)
        out = draw_lanes(frame, state)
        green = (out[..., 1] == 255) & (out[..., 0] == 0) & (out[..., 2] == 0)
        yellow = (out[..., 2] == 255) & (out[..., 1] == 220)
        return int(green.sum()), int(yellow.sum())

    assert drawn(3.6)[0] > 1000 and drawn(3.6)[1] == 0
    assert drawn(1.1) == (0, drawn(1.1)[1]) and drawn(1.1)[1] > 1000
    assert drawn(None)[0] == 0


def test_dark_frames_give_a_warning(chessboard_camera):
    frames = [(f * 0.08).astype(np.uint8) for f in _frames("highway_solid_white_right.mp4", 15)]
    cam = scale_camera(chessboard_camera, 0.75)
    det = ClassicalLaneDetector(cam)
    for i, f in enumerate(frames):
        det.update(f, i / 25.0)
    tl = det.timeline()
    assert tl.warnings and "found in only" in tl.warnings[0]


def test_dbscan_gives_scikit_learns_labels_on_real_marking_pixels():
    """The lane clustering (SciPy k-d tree + components) labels real marking pixels exactly as
    scikit-learn's DBSCAN does, numbering and border points included."""
    from sklearn.cluster import DBSCAN

    from deepcrashtest.geometry.camera import default_camera
    from deepcrashtest.perception.lanes import dbscan

    det = ClassicalLaneDetector(default_camera(1280, 720), mask_bottom_rows=132)
    checked = 0
    for frame in _frames("highway_lane_challenge.mp4", 60)[::15]:
        mask, _, r0 = det.marking_mask(frame)
        vs, us = np.nonzero(mask)
        pts = np.column_stack([us, (vs + r0) * 0.35]).astype(float)
        expected = DBSCAN(eps=4.0, min_samples=6).fit_predict(pts)
        assert expected.max() >= 1  # several clusters: the numbering is tested too
        np.testing.assert_array_equal(dbscan(pts, eps=4.0, min_samples=6), expected)
        checked += 1
    assert checked == 4
    assert len(dbscan(np.zeros((0, 2)), 4.0, 6)) == 0
    np.testing.assert_array_equal(dbscan(np.array([[0.0, 0.0], [100.0, 0.0]]), 4.0, 2), [-1, -1])


def test_hausdorff_matrix_matches_scipy():
    from scipy.spatial.distance import directed_hausdorff

    from deepcrashtest.perception.lanes import hausdorff_matrix

    rng = np.random.default_rng(3)
    a, b = rng.normal(size=(4, 12, 2)) * 40, rng.normal(size=(3, 12, 2)) * 40
    ref = [[max(directed_hausdorff(x, y)[0], directed_hausdorff(y, x)[0]) for y in b] for x in a]
    np.testing.assert_allclose(hausdorff_matrix(a, b), ref, rtol=1e-12)
