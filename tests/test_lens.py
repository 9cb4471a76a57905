"""The lens's radial distortion read from a video's straight edges (geometry/lens.py), on real frames."""

from __future__ import annotations

from pathlib import Path

import av
import cv2
import numpy as np
import pytest

from conftest import DATA, need
from deepcrashtest.geometry.camera import undistort_points
from deepcrashtest.geometry.lens import estimate_lens, opencv_coefficients, refocused
from deepcrashtest.scenario import Camera


def _frames(path: Path, count: int = 20) -> list[np.ndarray]:
    with av.open(str(path)) as c:
        out = []
        for f in c.decode(video=0):
            out.append(f.to_ndarray(format="bgr24"))
            if len(out) >= count:
                return out
    return out


def _through_division_lens(images: list[np.ndarray], lam: float) -> list[np.ndarray]:
    """The frames as a lens of division-model coefficient ``lam`` (radius over the half diagonal) films them:
    each output pixel at radius r_d shows the scene at r_d / (1 + lam (r_d / s)^2); the corners keep theirs
    when the frame is zoomed by that much at the corners (the picture fills the frame)."""
    h, w = images[0].shape[:2]
    s = np.hypot(w / 2, h / 2)
    v, u = np.mgrid[0:h, 0:w].astype(np.float64)
    du, dv = u - w / 2, v - h / 2
    fill = 1.0 + lam  # the corner's undistorted radius over its distorted one
    scale = fill / (1.0 + lam * (np.hypot(du, dv) / s) ** 2)
    map_x = (w / 2 + du * scale).astype(np.float32)
    map_y = (h / 2 + dv * scale).astype(np.float32)
    return [cv2.remap(im, map_x, map_y, cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE) for im in images]


def test_a_wide_angle_lens_is_read_from_a_street_s_straight_edges():
    """ccd_000053 (a street with buildings and poles, no visible distortion) reads no lens; the same frames
    through a barrel lens of coefficient -0.3 read -0.42, clearly (used): the clip's own mild lens (about -0.13,
    which alone the method does not tell from zero) adds to it."""
    frames = _frames(need(DATA / "crash_ccd" / "ccd_000053.mp4"))
    plain = estimate_lens(frames)
    assert not plain.used and abs(plain.lam) < 0.1
    lensed = estimate_lens(_through_division_lens(frames, -0.3))
    assert lensed.used
    assert -0.45 <= lensed.lam <= -0.2
    assert lensed.gain > 0.1


def test_drawn_straight_lines_through_a_lens_read_that_lens():
    """Frames of drawn straight lines (random, anti-aliased, 3 px) through lenses of -0.15 / -0.3 / -0.45 read
    each within 0.03; without a lens, no lens is used."""
    rng = np.random.default_rng(0)
    frames = []
    for _ in range(8):
        img = np.full((720, 1280, 3), 128, np.uint8)
        for _ in range(40):
            a, b = rng.uniform([0, 0], [1280, 720], size=(2, 2)).astype(int)
            grey = int(rng.integers(0, 60))
            cv2.line(img, (int(a[0]), int(a[1])), (int(b[0]), int(b[1])), (grey, grey, grey), 3, cv2.LINE_AA)
        frames.append(img)
    assert not estimate_lens(frames).used
    for lam in (-0.15, -0.3, -0.45):
        est = estimate_lens(_through_division_lens(frames, lam))
        assert est.used and abs(est.lam - lam) <= 0.03


def test_rectified_kitti_frames_read_no_lens():
    """KITTI's frames are rectified (no distortion left): no lens is used on them."""
    folder = need(DATA / "kitti_raw_highway_queue" / "image_02" / "data")
    images = [cv2.imread(str(p)) for p in sorted(folder.glob("*.png"))[:20]]
    assert not estimate_lens(images).used


@pytest.mark.parametrize("lam", [-0.4, -0.15, 0.1])
def test_the_opencv_model_distorts_as_the_division_model_at_any_focal_length(lam):
    """The camera's OpenCV coefficients undo the division model within 5 px over a 1280x720 frame (its corners
    ~730 px from the centre), also after the focal length is self-calibrated to another value (``refocused``)."""
    w, h = 1280, 720
    s = np.hypot(w / 2, h / 2)
    r = np.linspace(0.05, 1.0, 25) * s
    pts = np.column_stack([w / 2 + r * 0.8, h / 2 + r * 0.6])
    want = r / (1 + lam * (r / s) ** 2)
    for fx in (640.0, 1100.0):
        dist = refocused(opencv_coefficients(lam, (w, h), 640.0), 640.0, fx)
        cam = Camera(fx=fx, fy=fx, cx=w / 2, cy=h / 2, distortion=dist)
        u = undistort_points(pts, cam)
        assert np.abs(np.hypot(u[:, 0] - w / 2, u[:, 1] - h / 2) - want).max() < 5.0


def test_extract_with_lens_auto_reads_the_lens_and_places_boxes_in_its_pinhole_image(tmp_path):
    """``extract --lens auto`` on ccd_000053 filmed through a barrel lens (-0.3): the scenario's camera carries
    the lens (OpenCV coefficients that push the frame's corners outwards when undistorted) and the provenance says
    what was read; by default (``none``) the frames are taken as a pinhole camera's. A wrong mode is one clear
    error."""
    from deepcrashtest.errors import UserError
    from deepcrashtest.pipeline.extract import run_extract
    from deepcrashtest.scenario import Scenario
    from deepcrashtest.video.writer import VideoWriter

    frames = _through_division_lens(_frames(need(DATA / "crash_ccd" / "ccd_000053.mp4"), 50), -0.3)
    video = tmp_path / "wide.mp4"
    with VideoWriter(video, 10.0, frames[0].shape[1], frames[0].shape[0]) as writer:
        for f in frames:
            writer.write(f)
    run_extract(video, tmp_path / "auto", report=False, annotate=False, lens="auto")
    raw = Scenario.load(tmp_path / "auto" / "scenario_raw.json")
    read = raw.provenance.parameters["lens_distortion"]
    assert read["used"] and read["lambda"] < -0.15
    corner = undistort_points(np.array([[0.0, 0.0]]), raw.camera)[0]  # barrel: the corner moves outwards
    assert raw.camera.distortion and corner[0] < -50 and corner[1] < -25
    assert raw.provenance.parameters.get("boxes_undistorted") is True
    run_extract(video, tmp_path / "none", report=False, annotate=False)
    plain = Scenario.load(tmp_path / "none" / "scenario_raw.json")
    assert not plain.camera.distortion and "lens_distortion" not in plain.provenance.parameters
    with pytest.raises(UserError, match="--lens"):
        run_extract(video, tmp_path / "bad", lens="fisheye")
