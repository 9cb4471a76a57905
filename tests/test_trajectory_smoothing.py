"""Smoothing: error against the real KITTI tracks stays small while jerk drops; manoeuvres survive."""

from __future__ import annotations

import numpy as np
import pytest

from deepcrashtest.datasets.kitti.scenario import scenario_from_kitti
from deepcrashtest.trajectory.params import Stage2Params
from deepcrashtest.trajectory.pipeline import process_scenario
from deepcrashtest.trajectory.smoothing import smooth_track

FPS = 10.0


def rms_jerk(t: np.ndarray, xy: np.ndarray) -> float:
    """RMS magnitude of the third finite difference of positions (m/s^3), uniform steps."""
    dt = float(np.mean(np.diff(t)))
    j = np.diff(xy, n=3, axis=0) / dt**3
    return float(np.sqrt((j**2).sum(axis=1).mean()))


@pytest.fixture(scope="module", params=[3, 8, 10])
def kitti_pair(request, kitti_root):
    raw = scenario_from_kitti(kitti_root, request.param)
    return raw, process_scenario(raw)


def test_smoothing_error_small_and_jerk_drops_on_kitti(kitti_pair):
    """Processed (final) positions at the observed frames vs the raw KITTI positions: RMS < 0.3 m for
    every vehicle and overall; RMS jerk drops by more than 10x over all tracks."""
    raw, sc = kitti_pair
    t_max = sc.provenance.parameters["t_max_s"]
    sq_err, n, jerk_raw, jerk_smooth = 0.0, 0, [], []
    for v in sc.vehicles():
        r = raw.vehicle(v.id).trajectory.arrays()
        a = v.trajectory.arrays()
        obs = np.asarray(v.trajectory.observed)
        if v.trajectory_class is not None and np.all(a["speed"] == 0):  # parked: held at its mean position
            continue
        assert obs.sum() == len(r["t"]) or sc.collision is not None
        assert np.allclose(a["t"][obs] - t_max, r["t"], atol=1e-9)
        xy_raw = np.column_stack([r["x"], r["y"]])
        xy = np.column_stack([a["x"][obs], a["y"][obs]])
        e2 = ((xy - xy_raw) ** 2).sum(axis=1)
        assert np.sqrt(e2.mean()) < 0.3, v.id
        sq_err += e2.sum()
        n += len(e2)
        if len(r["t"]) >= 10:
            jerk_raw.append(rms_jerk(r["t"], xy_raw))
            jerk_smooth.append(rms_jerk(r["t"], xy))
    assert np.sqrt(sq_err / n) < 0.15
    assert np.median(jerk_smooth) < np.median(jerk_raw) / 10
    assert all(s < r for s, r in zip(jerk_smooth, jerk_raw, strict=True))


def test_parked_agents_held_near_their_labels(kitti_pair):
    raw, sc = kitti_pair
    for v in sc.agents:
        a = v.trajectory.arrays()
        if np.all(a["speed"] == 0):
            assert np.ptp(a["x"]) < 1e-6 and np.ptp(a["y"]) < 1e-6
            r = raw.vehicle(v.id).trajectory.arrays()
            # labelled positions of a parked car drift by up to ~2.5 m as the ego passes (see test_from_kitti)
            assert np.sqrt(((r["x"] - a["x"][0]) ** 2 + (r["y"] - a["y"][0]) ** 2).mean()) < 1.0


def _noisy(t: np.ndarray, x: np.ndarray, y: np.ndarray, sigma: float, seed: int) -> tuple[np.ndarray, np.ndarray]:
    rng = np.random.default_rng(seed)
    return x + rng.normal(0, sigma, len(t)), y + rng.normal(0, sigma, len(t))


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_sudden_swerve_survives(seed):
    """A 1.5 m swerve within 1 s (at 15 m/s) right before the end, noise 0.1 m: kept (RMS error 0.15 m)."""
    t = np.arange(0, 8.01, 1 / FPS)
    x_true = 15 * t
    s = np.clip((t - 6.0) / 1.0, 0, 1)
    y_true = 1.5 * s * s * (3 - 2 * s)
    x, y = _noisy(t, x_true, y_true, 0.1, seed)
    sm = smooth_track(t, x, y, FPS, Stage2Params())
    q = sm.pos(t)
    window = (t >= 5.5) & (t <= 7.3)
    assert np.sqrt(((q[window, 1] - y_true[window]) ** 2).mean()) < 0.15
    assert np.abs(q[:, 1] - y_true).max() < 0.3
    assert q[t >= 7.0, 1].mean() == pytest.approx(1.5, abs=0.1)
    # the lateral speed peak of the swerve (2.25 m/s) is kept to within 30 %
    vy = sm.vel(t)[:, 1]
    assert vy.max() == pytest.approx(1.5 * 1.5 / 1.0, rel=0.3)


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_hard_brake_survives(seed):
    """15 -> 5 m/s at 10 m/s^2 (1 s) at t = 5 s, noise 0.1 m: speed after the brake within 0.7 m/s."""
    t = np.arange(0, 8.01, 1 / FPS)
    v = np.where(t < 5, 15.0, np.where(t < 6, 15 - 10 * (t - 5), 5.0))
    x_true = np.concatenate([[0.0], np.cumsum(0.5 * (v[1:] + v[:-1]) / FPS)])
    x, y = _noisy(t, x_true, np.zeros_like(t), 0.1, seed)
    sm = smooth_track(t, x, y, FPS, Stage2Params())
    speed = np.hypot(*sm.vel(t).T)
    assert np.abs(speed[(t >= 6.5) & (t <= 7.5)] - 5.0).max() < 0.7
    assert np.abs(speed[(t >= 1.0) & (t <= 4.5)] - 15.0).max() < 0.7
    assert np.abs(sm.pos(t)[:, 0] - x_true).max() < 0.3


def test_window_is_in_seconds_not_samples():
    """The same motion sampled at 10 and 30 fps gives the same smoothed curve (to noise level)."""
    curves = []
    for fps in (10.0, 30.0):
        t = np.arange(0, 6.0 + 1e-9, 1 / fps)
        x, y = 12 * t, 2.0 * np.sin(t)
        sm = smooth_track(t, x, y, fps, Stage2Params())
        curves.append(sm.pos(np.linspace(0.5, 5.5, 50)))
    assert np.abs(curves[0] - curves[1]).max() < 0.05
