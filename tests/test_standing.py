"""The standing-vehicle model (``geometry/standing.py``) on exact projections: a car standing beside a straight
path, seen from a camera driving past it, is placed where it stands, its column offset recovered, and views
without values give no fit instead of an error."""

from __future__ import annotations

import math

import numpy as np

from deepcrashtest.geometry.standing import StandingNoise, Views, fit_standing

FX = 700.0
LENGTH, WIDTH, HEIGHT = 4.4, 1.8, 1.5
NOISE = StandingNoise(3.0 / FX, 0.4, 0.05, 0.15)


def _views(point: np.ndarray, offset: float = 0.0, scale: float = 1.0) -> Views:
    """Views of a car of ``scale`` times the class size standing at ``point`` (world m) from a camera driving
    along world x at 10 m/s for 2 s (10 Hz), its bearings shifted by ``offset`` (tan)."""
    x = np.arange(20) * 1.0
    fwd, left = point[0] - x, point[1] - np.zeros_like(x)
    a = np.arctan2(-left, fwd)
    near = fwd - 0.5 * scale * (LENGTH * np.abs(np.cos(a)) + WIDTH * np.abs(np.sin(a))) * np.cos(a)
    return Views(x, np.zeros_like(x), np.zeros_like(x), -left / fwd - offset, FX * scale * HEIGHT / near)


def test_a_standing_car_is_placed_by_the_parallax_whatever_its_size():
    point = np.array([40.0, -4.0])
    views = _views(point, scale=1.15)  # 15 % larger than the class: the size prior alone would read it 15 % near
    fit = fit_standing(views, (LENGTH, WIDTH), math.log(FX * HEIGHT), np.array([32.0, -3.0]), NOISE)
    assert fit is not None
    assert np.hypot(*(fit.xy - point)) < 0.3, fit.xy
    assert abs(fit.log_scale - math.log(1.15)) < 0.03 and fit.chi2 < 0.05
    assert abs(fit.parallax_rad - (math.atan2(4.0, 21.0) - math.atan2(4.0, 40.0))) < 0.01  # the line of sight's turn


def test_a_column_offset_is_recovered_with_the_point():
    point = np.array([35.0, 5.0])
    views = _views(point, offset=12.0 / FX)  # a principal column 12 px off
    start = np.array([30.0, 4.0])
    fixed = fit_standing(views, (LENGTH, WIDTH), math.log(FX * HEIGHT), start, NOISE)
    free = fit_standing(views, (LENGTH, WIDTH), math.log(FX * HEIGHT), start, NOISE, free_offset=True)
    assert fixed is not None and free is not None
    assert abs(free.offset * FX - 12.0) < 1.0 and np.hypot(*(free.xy - point)) < 0.3
    assert free.chi2 < 0.1 * fixed.chi2  # the offset explains what a standing point alone cannot


def test_views_without_values_give_no_fit():
    views = _views(np.array([40.0, -4.0]))
    broken = Views(np.r_[np.nan, views.x[1:]], views.y, views.yaw, views.bearing, views.box_h)
    assert fit_standing(broken, (LENGTH, WIDTH), math.log(FX * HEIGHT), np.array([32.0, -3.0]), NOISE) is None
