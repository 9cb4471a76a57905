"""Replay control: Stanley steering and a PID speed controller with station feedback, vectorised.

Each row (a vehicle in one variant) follows one reference of a :class:`PathSet` (``q[row]``),
optionally translated by ``offset[row]`` (metres, world frame). Per step:

* the front axle (centre + wheelbase/2 ahead) is projected onto the path (searching a short window
  ahead of the previous projection, so following is O(rows));
* steering (Stanley with curvature feed-forward):
  ``delta = atan(wheelbase * kappa) + (path_heading - yaw) - atan(K_E * e / (v + V_SOFT))``,
  ``e`` = lateral offset of the front axle, left positive;
* speed: the commanded speed is the time-indexed reference speed plus a station correction,
  ``v_cmd = v_ref(t) + clip(K_S * (s_ref(t) - s), +-V_CORR)``, and the acceleration is
  ``a = a_ref(t) + K_P * (v_cmd - v) + K_I * integral(v_cmd - v)`` (PID, derivative from ``a_ref``).
  The station term makes a replay reproduce positions in time, not only the speed profile.
"""

from __future__ import annotations

import numpy as np

from deepcrashtest.sim.reference import PATH_DS_M, PathSet

K_E = 2.0  # 1/s, Stanley cross-track gain
V_SOFT = 1.0  # m/s
K_S = 1.0  # 1/s, station -> speed
V_CORR = 3.0  # m/s, largest station correction
K_P = 3.0  # 1/s
K_I = 0.5  # 1/s^2
WINDOW = np.arange(-2, 14)  # path points searched around the previous projection


class Follower:
    """Path and speed tracking for ``R`` rows over a :class:`PathSet`."""

    def __init__(self, paths: PathSet, q: np.ndarray, offset: np.ndarray, wheelbase: np.ndarray) -> None:
        self.paths = paths
        self.q = np.asarray(q, dtype=np.intp)
        self.offset = np.asarray(offset, dtype=float)
        self.wheelbase = np.asarray(wheelbase, dtype=float)
        self.idx = np.zeros(len(self.q), dtype=np.intp)
        self.integral = np.zeros(len(self.q))
        self.n_points = paths.path.shape[1]

    def select(self, keep: np.ndarray) -> None:
        """Keep only the rows ``keep`` (boolean or index array)."""
        self.q, self.offset, self.wheelbase = self.q[keep], self.offset[keep], self.wheelbase[keep]
        self.idx, self.integral = self.idx[keep], self.integral[keep]

    def command(self, state: np.ndarray, k: int, dt: float) -> tuple[np.ndarray, np.ndarray]:
        """Acceleration (m/s^2) and steering angle (rad) for each row at grid step ``k``."""
        x, y, yaw, v = state[:, 0], state[:, 1], state[:, 2], state[:, 3]
        half = 0.5 * self.wheelbase
        cy, sy = np.cos(yaw), np.sin(yaw)
        fx = x + half * cy - self.offset[:, 0]
        fy = y + half * sy - self.offset[:, 1]
        win = np.clip(self.idx[:, None] + WINDOW, 0, self.n_points - 2)
        qq = self.q[:, None]
        pts = self.paths.path[qq, win]
        d2 = (pts[..., 0] - fx[:, None]) ** 2 + (pts[..., 1] - fy[:, None]) ** 2
        i = win[np.arange(len(win)), d2.argmin(axis=1)]
        self.idx = i
        q = self.q
        h = self.paths.heading[q, i]
        ch, sh = np.cos(h), np.sin(h)
        px, py = self.paths.path[q, i, 0], self.paths.path[q, i, 1]
        dx, dy = fx - px, fy - py
        along = dx * ch + dy * sh
        lateral = -dx * sh + dy * ch
        kappa = self.paths.curvature[q, i]
        head_err = np.angle(np.exp(1j * (h - yaw)))
        steer = np.arctan(self.wheelbase * kappa) + head_err - np.arctan(K_E * lateral / (v + V_SOFT))
        s_centre = i * PATH_DS_M + along - half
        s_ref = self.paths.s_ref[q, k]
        v_cmd = self.paths.v_ref[q, k] + np.clip(K_S * (s_ref - s_centre), -V_CORR, V_CORR)
        err = np.maximum(v_cmd, 0.0) - v
        self.integral = np.clip(self.integral + err * dt, -2.0, 2.0)
        accel = self.paths.a_ref[q, k] + K_P * err + K_I * self.integral
        return accel, steer
