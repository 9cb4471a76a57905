"""Rolling shutter under shake (geometry.rolling_shutter): real frames of a global-shutter camera (KITTI odometry)
against a shaking 10 fps dashcam (ccd_000014)."""

from __future__ import annotations

import cv2
import numpy as np

from conftest import DATA, need
from deepcrashtest.geometry.rolling_shutter import rolling_shutter_fit


def _pairs(images: list[np.ndarray], rows: slice) -> list[tuple[np.ndarray, np.ndarray]]:
    """Corners of each frame (in ``rows``) tracked into the next one (LK, forward-backward checked), static
    points only in the sense of moving more than 0.3 px (burned-in text and dashboard stay put)."""
    out = []
    for a, b in zip(images, images[1:], strict=False):
        mask = np.zeros_like(a)
        mask[rows] = 255
        p0 = cv2.goodFeaturesToTrack(a, 400, 0.01, 8, mask=mask).reshape(-1, 2)
        p1, st, _ = cv2.calcOpticalFlowPyrLK(a, b, p0, None, winSize=(15, 15), maxLevel=3)
        back, st2, _ = cv2.calcOpticalFlowPyrLK(b, a, p1, None, winSize=(15, 15), maxLevel=3)
        ok = (st.ravel() == 1) & (st2.ravel() == 1) & (np.linalg.norm(back - p0, axis=1) < 0.5)
        ok &= np.linalg.norm(p1 - p0, axis=1) > 0.3
        out.append((p0[ok], p1[ok]))
    return out


def _ratios(pairs: list[tuple[np.ndarray, np.ndarray]], K: np.ndarray, foe: tuple[float, float], h: int):
    fits = [rolling_shutter_fit(p0, p1, K, foe, h, search_px=80.0) for p0, p1 in pairs]
    fits = [f for f in fits if f is not None]
    assert len(fits) >= 4
    return np.median([f.rolling_px / f.global_px for f in fits]), np.median([f.change_px(K) for f in fits])


def test_global_shutter_shows_no_row_varying_rotation():
    """KITTI's cameras expose all rows at once: a rotation varying with the row explains nothing more."""
    folder = need(DATA / "kitti_odometry" / "seq06_frames0000-0050" / "image_0")
    images = [cv2.imread(str(p), cv2.IMREAD_GRAYSCALE) for p in sorted(folder.glob("*.png"))[10:17]]
    K = np.array([[707.09, 0.0, 601.89], [0.0, 707.09, 183.11], [0.0, 0.0, 1.0]])  # seq06 calib_P0_P1 (P0)
    ratio, change = _ratios(_pairs(images, slice(0, 376)), K, (601.89, 183.11), images[0].shape[0])
    assert ratio > 0.9  # the row-varying fit's residual within 10 % of one rotation's (0.95 measured)
    assert change < 4.0  # px: noise (1.5 measured)


def test_shaking_dashcam_shows_a_row_varying_rotation():
    """ccd_000014 (10 fps, a camera shaking 5-20 px a frame): the rotation changes from top to bottom rows."""
    cap = cv2.VideoCapture(str(need(DATA / "crash_ccd" / "ccd_000014.mp4")))
    images = []
    while len(images) < 22:
        ok, img = cap.read()
        assert ok
        images.append(cv2.cvtColor(img, cv2.COLOR_BGR2GRAY))
    cap.release()
    K = np.array([[640.0, 0.0, 640.0], [0.0, 640.0, 360.0], [0.0, 0.0, 1.0]])  # the unknown-dashcam default
    # scene above the lead cars' rows; the focus of expansion searched around the travel the ego-motion learns
    ratio, change = _ratios(_pairs(images[14:22], slice(0, 560)), K, (640.0, 520.0), 720)
    assert ratio < 0.8  # 0.71 measured
    assert change > 8.0  # px at 640 px focal length (17 measured)
