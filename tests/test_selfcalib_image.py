"""The level-camera horizon term of the focal length (`geometry.selfcalib_image`) on real data."""

from __future__ import annotations

import math
from pathlib import Path

import pytest
from tests.conftest import KITTI_TRACKING as KITTI
from tests.conftest import need

from deepcrashtest.datasets.kitti.files import read_calib, read_labels
from deepcrashtest.geometry.selfcalib import FOCAL_PRIOR_REL, combine_focal, self_calibrate
from deepcrashtest.geometry.selfcalib_image import focal_from_level_horizon
from deepcrashtest.scenario import Camera, Scenario
from test_cli import run

ROOT = Path(__file__).resolve().parents[1]
SAMPLE = ROOT / "examples" / "highway_sample.mp4"
#: The Udacity camera's chessboard calibration (bench/labels: 20 photos of the same camera, 1280x720).
UDACITY_FY = 1154.0


def test_a_low_horizon_lengthens_the_unknown_cameras_focal_length(tmp_path):
    """The bundled Udacity highway clip (8 s; its first 3 s hold no track), no calibration given: its boxes
    put the horizon ~62 px below the image centre, a 5.5 deg pitch at the default 640 px but 3 deg at its
    chessboard 1154 px. The level-camera term moves the focal length from the default toward the
    chessboard's (measured 640 -> 842 px), with a sigma that still covers the truth, and says so in the
    calibration notes."""
    out = tmp_path / "hw"
    proc = run("extract", str(SAMPLE), "-o", str(out), "--json")
    assert proc.returncode == 0, proc.stderr
    raw = Scenario.load(out / "scenario_raw.json")
    cam = raw.camera
    assert cam.intrinsics_source == "self_calibration"
    assert 780.0 < cam.fy < UDACITY_FY  # main kept the default 640 px
    assert cam.focal_sigma_px is not None and abs(math.log(UDACITY_FY / cam.fy)) < 2.0 * cam.focal_sigma_px / cam.fy
    notes = raw.provenance.parameters["self_calibration"]["notes"]
    assert any("a level camera says" in n for n in notes)


def test_a_level_horizon_leaves_the_prior_alone():
    """KITTI tracking sequence 0001's labelled cars (a level camera): its horizon lies within a few pixels of
    cy, so the term adds nothing and the focal length keeps its prior (here the default, 14 % short)."""
    lab = read_labels(need(KITTI / "label_02" / "0001.txt"))
    k = read_calib(KITTI / "calib" / "0001.txt").K
    cars = lab[lab["type"].isin(["Car", "Van"])].assign(category="car")
    size = (1242, 375)
    start = Camera(fx=621.0, fy=621.0, cx=size[0] / 2, cy=k[1, 2], height_m=1.3)
    cal = self_calibrate(cars, start, size)
    assert abs(cal.horizon_v - k[1, 2]) < 20.0
    assert cal.camera.fy == start.fy and not any("a level camera says" in n for n in cal.notes)
    assert focal_from_level_horizon(cal.horizon_v - k[1, 2], cal.horizon_sigma_px, 621.0, FOCAL_PRIOR_REL) is None


def test_the_term_only_pushes_longer_and_fuses_as_a_soft_prior():
    """A horizon far from the centre row weighs longer focal lengths (never shorter ones), as one more
    inverse-variance term: the fused focal length lies between the prior and the term."""
    term = focal_from_level_horizon(180.0, 8.0, 640.0, FOCAL_PRIOR_REL)
    assert term is not None and term[0] > 640.0 and term[1] > 0.1
    fused = combine_focal(640.0, None, None, level=term)
    assert fused is not None and 640.0 < fused[0] < term[0] and fused[1] < FOCAL_PRIOR_REL
    above = focal_from_level_horizon(-180.0, 8.0, 640.0, FOCAL_PRIOR_REL)
    assert above is not None and above[0] == pytest.approx(term[0])
