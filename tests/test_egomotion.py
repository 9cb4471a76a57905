"""Ego-motion on real dashcam clips: a stopped ego is a measurement (speed 0), a moving one moves."""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np

from conftest import DATA, need
from deepcrashtest.geometry.camera import default_camera, detect_dashboard_rows
from deepcrashtest.geometry.egomotion import EgoMotionEstimator

DAD = DATA / "crash_dad"


def _frames(path: Path, count: int) -> list[np.ndarray]:
    cap = cv2.VideoCapture(str(need(path)))
    out = []
    while len(out) < count:
        ok, img = cap.read()
        if not ok:
            break
        out.append(img)
    cap.release()
    return out


def _run(path: Path, count: int, fps: float = 20.0) -> tuple[EgoMotionEstimator, np.ndarray]:
    imgs = _frames(path, count)
    h, w = imgs[0].shape[:2]
    est = EgoMotionEstimator(default_camera(w, h), mask_bottom_rows=detect_dashboard_rows(imgs[::4]))
    for i, img in enumerate(imgs):
        est.update(img, i / fps)
    return est, est.result().speed


def test_stopped_dashcam_ego_is_a_measurement_not_a_failure():
    """DAD 512: the ego waits behind an SUV (the scene is still, a scooter passes)."""
    est, speed = _run(DAD / "dad_000512.mp4", 30)
    res = est.result()
    assert res.static and np.all(speed == 0.0) and res.valid.all()
    assert not any("too few" in w for w in res.warnings)


def test_moving_dashcam_ego_is_not_stopped():
    """DAD 478: the ego drives down a street lined with parked cars (measured 2.5-5.6 m/s, default camera)."""
    est, speed = _run(DAD / "dad_000478.mp4", 30)
    res = est.result()
    assert not res.static and res.valid[1:].mean() >= 0.8  # measured 26 of 29 pairs
    assert 1.0 < float(np.median(speed[5:])) < 15.0
