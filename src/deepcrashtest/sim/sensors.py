"""Ego sensors, vectorised over variants: front radar, camera, GNSS/IMU. All noise is seeded.

Targets are the other vehicles' boxes. For every (variant, target) pair a sensor reports the point
of the target's box nearest to the sensor (range, azimuth in the ego frame, left positive) when it
is inside the field of view and the detection range; association is ideal (by vehicle).

* radar (middle of the front bumper): range, range-rate (line-of-sight relative speed, negative when closing),
  azimuth; Gaussian noise; field of view and range as configured;
* camera (modelled at the radar's position, so both see the same nearest point): detection with a
  per-frame probability, azimuth (accurate) and a monocular range estimate (noise proportional to range);
* GNSS/IMU: position, heading, speed, yaw rate and longitudinal acceleration with noise.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True)
class SensorConfig:
    """Sensor parameters (SI units, angles in radians)."""

    radar_fov: float = np.deg2rad(30.0)  # full horizontal field of view
    radar_range: float = 160.0
    radar_range_sigma: float = 0.10
    radar_range_rate_sigma: float = 0.10
    radar_azimuth_sigma: float = np.deg2rad(0.3)
    camera_fov: float = np.deg2rad(60.0)
    camera_range: float = 80.0
    camera_p_detect: float = 0.98
    camera_azimuth_sigma: float = np.deg2rad(0.2)
    camera_range_rel_sigma: float = 0.05
    gnss_sigma: float = 0.5
    heading_sigma: float = np.deg2rad(0.5)
    speed_sigma: float = 0.05
    yaw_rate_sigma: float = 0.005
    accel_sigma: float = 0.05


@dataclass
class Truth:
    """Ground truth at the current step (for oracle controllers, analysis and tests)."""

    ego: np.ndarray  # (B, 4) x, y, yaw, speed
    agents: np.ndarray  # (M, 4)
    agent_present: np.ndarray  # (M,) bool
    agent_ids: list[int]


@dataclass
class Observation:
    """What a controller sees at time ``t`` for ``n`` variants (arrays are (n,) or (n, M)).

    Radar and camera arrays have one column per other vehicle of the scenario (``truth.agent_ids``);
    ``*_valid`` says whether that vehicle is detected this step (other entries are NaN).
    ``replay_accel`` / ``replay_steer`` are what the replay driver would command (the "driver"
    of the ego, following its recorded path and speed).
    """

    t: float
    dt: float
    n: int
    ego_length: float
    ego_width: float
    gnss_xy: np.ndarray
    gnss_yaw: np.ndarray
    speed: np.ndarray
    yaw_rate: np.ndarray
    accel: np.ndarray
    radar_valid: np.ndarray
    radar_range: np.ndarray
    radar_range_rate: np.ndarray
    radar_azimuth: np.ndarray
    camera_valid: np.ndarray
    camera_range: np.ndarray
    camera_azimuth: np.ndarray
    replay_accel: np.ndarray
    replay_steer: np.ndarray
    truth: Truth


def _nearest_point(sensor: np.ndarray, agents: np.ndarray, half: np.ndarray) -> np.ndarray:
    """(B, M, 2) point of each agent box (M, 4 with yaw at 2; half (M, 2)) nearest to ``sensor`` (B, 2)."""
    c, s = np.cos(agents[:, 2]), np.sin(agents[:, 2])
    dx = sensor[:, None, 0] - agents[None, :, 0]
    dy = sensor[:, None, 1] - agents[None, :, 1]
    lx = np.minimum(np.maximum(dx * c + dy * s, -half[:, 0]), half[:, 0])
    ly = np.minimum(np.maximum(-dx * s + dy * c, -half[:, 1]), half[:, 1])
    return np.stack([agents[None, :, 0] + lx * c - ly * s, agents[None, :, 1] + lx * s + ly * c], axis=-1)


def _polar(sensor: np.ndarray, yaw: np.ndarray, pts: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    d = pts - sensor[:, None, :]
    rng = np.hypot(d[..., 0], d[..., 1])
    az = np.arctan2(d[..., 1], d[..., 0]) - yaw[:, None]
    az = (az + np.pi) % (2 * np.pi) - np.pi
    return rng, az, d


def sense(
    cfg: SensorConfig,
    rng: np.random.Generator,
    t: float,
    dt: float,
    ego: np.ndarray,
    ego_vel: np.ndarray,
    ego_yaw_rate: np.ndarray,
    ego_accel: np.ndarray,
    ego_size: tuple[float, float],
    agents: np.ndarray,
    agent_vel: np.ndarray,
    agent_half: np.ndarray,
    present: np.ndarray,
    replay: tuple[np.ndarray, np.ndarray],
    agent_ids: list[int],
) -> Observation:
    """One noisy observation for ``B`` ego variants (ego (B, 4), ego_vel (B, 2)) of ``M`` agents.

    Radar and camera both sit at the middle of the front bumper. Only present agents are measured
    (absent ones are invalid columns).
    """
    B, M = len(ego), len(agents)
    yaw = ego[:, 2]
    sensor = ego[:, :2] + 0.5 * ego_size[0] * np.stack([np.cos(yaw), np.sin(yaw)], axis=-1)
    cols = np.nonzero(present)[0]
    P = len(cols)
    noise = rng.standard_normal((5, B, P))
    det = rng.random((B, P))
    pts = _nearest_point(sensor, agents[cols], agent_half[cols])
    rng_, az, d = _polar(sensor, yaw, pts)
    rel_v = agent_vel[None, cols, :] - ego_vel[:, None, :]
    rate = np.sum(rel_v * d, axis=-1) / np.maximum(rng_, 1e-6)
    in_fov = np.abs(az)
    r_ok = (in_fov <= cfg.radar_fov / 2) & (rng_ <= cfg.radar_range)
    c_ok = (in_fov <= cfg.camera_fov / 2) & (rng_ <= cfg.camera_range) & (det < cfg.camera_p_detect)

    def full(values: np.ndarray, ok: np.ndarray) -> np.ndarray:
        out = np.full((B, M), np.nan)
        out[:, cols] = np.where(ok, values, np.nan)
        return out

    def mask(ok: np.ndarray) -> np.ndarray:
        out = np.zeros((B, M), dtype=bool)
        out[:, cols] = ok
        return out

    e = rng.standard_normal((7, B))
    return Observation(
        t=t,
        dt=dt,
        n=B,
        ego_length=ego_size[0],
        ego_width=ego_size[1],
        gnss_xy=ego[:, :2] + cfg.gnss_sigma * e[:2].T,
        gnss_yaw=yaw + cfg.heading_sigma * e[2],
        speed=np.maximum(ego[:, 3] + cfg.speed_sigma * e[3], 0.0),
        yaw_rate=ego_yaw_rate + cfg.yaw_rate_sigma * e[4],
        accel=ego_accel + cfg.accel_sigma * e[5],
        radar_valid=mask(r_ok),
        radar_range=full(rng_ + cfg.radar_range_sigma * noise[0], r_ok),
        radar_range_rate=full(rate + cfg.radar_range_rate_sigma * noise[1], r_ok),
        radar_azimuth=full(az + cfg.radar_azimuth_sigma * noise[2], r_ok),
        camera_valid=mask(c_ok),
        camera_range=full(rng_ * (1.0 + cfg.camera_range_rel_sigma * noise[3]), c_ok),
        camera_azimuth=full(az + cfg.camera_azimuth_sigma * noise[4], c_ok),
        replay_accel=replay[0],
        replay_steer=replay[1],
        truth=Truth(ego=ego, agents=agents, agent_present=present, agent_ids=agent_ids),
    )
