"""Replay control: Stanley steering and a PID speed controller with station feedback, vectorised.

Each row (a vehicle in one variant) follows one reference of a :class:`PathSet` (``q[row]``),
optionally translated by ``offset[row]`` (metres, world frame). Per step:

* the front axle (centre + wheelbase/2 ahead) is projected onto the path, starting from the previous
  projection and moving the index by the along-track offset (two updates; O(rows), no search);
* steering (Stanley): ``delta = (path_heading - yaw) - atan(K_E * e / (v + V_SOFT))``, ``e`` = lateral offset
  of the front axle from the path, left positive. The heading error already holds the road-wheel angle a
  bend needs (the path's direction at the front axle less the body's yaw); a curvature feed-forward
  ``atan(wheelbase * kappa)`` on top of it (until branch replay10) asked for twice that angle: the replayed
  centre ran up to 0.34 m inside a swerve (the phone-filmed ccd_000053's ego missed its crash by 0.12 m;
  KITTI training egos 0.113 -> 0.058 m RMS). The front axle stays on the centre's path, so in a steady
  bend the centre runs ``sqrt(R^2 - 3 L^2 / 4)`` from the bend's centre instead of ``R`` (0.23 m inside at
  R = 12 m, L = 2.7 m). Holding the front axle on its own wider path instead puts the centre on its path
  (0.01 m) but turns the body further from the camera's measured yaw (ccd_001135's turns ~2 deg ahead
  of its motion): replay IoU on the 20 fidelity clips 0.625 -> 0.617, against 0.627 this way;
* speed: the commanded speed is the time-indexed reference speed plus a station correction,
  ``v_cmd = v_ref(t) + clip(K_S * (s_ref(t) - s), +-V_CORR)``, and the acceleration is
  ``a = a_ref(t) + K_P * (v_cmd - v) + K_I * integral(v_cmd - v)`` (PID, derivative from ``a_ref``).
  The station term makes a replay reproduce positions in time, not only the speed profile.
"""

from __future__ import annotations

import numpy as np

from deepcrashtest.sim.reference import PATH_DS_M, PathSet

K_E = 4.0  # 1/s, Stanley cross-track gain (2 -> 4: ego replay RMS on KITTI 0001/0004 -25..40%)
V_SOFT = 1.0  # m/s
K_S = 1.0  # 1/s, station -> speed
V_CORR = 3.0  # m/s, largest station correction
K_P = 3.0  # 1/s
K_I = 0.5  # 1/s^2


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
        self._px, self._py = paths.path[..., 0].ravel(), paths.path[..., 1].ravel()
        self._h = paths.heading.ravel()
        self._ch, self._sh = np.cos(self._h), np.sin(self._h)

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
        # projection: two updates of the path index from the along-track offset (flat gathers)
        base = self.q * self.n_points
        last = self.n_points - 2
        i = self.idx
        px, py, ch, sh = self._px, self._py, self._ch, self._sh
        for _ in range(2):
            f = base + i
            along = (fx - px[f]) * ch[f] + (fy - py[f]) * sh[f]
            i = np.minimum(np.maximum(i + np.rint(along / PATH_DS_M).astype(np.intp), 0), last)
        self.idx = i
        f = base + i
        dx, dy, c, s = fx - px[f], fy - py[f], ch[f], sh[f]
        along = dx * c + dy * s
        lateral = -dx * s + dy * c
        h = self._h[f]
        q = self.q
        head_err = (h - yaw + np.pi) % (2 * np.pi) - np.pi
        steer = head_err - np.arctan(K_E * lateral / (v + V_SOFT))
        s_centre = i * PATH_DS_M + along - half
        s_ref = self.paths.s_ref[:, k][q]
        v_cmd = self.paths.v_ref[:, k][q] + np.minimum(np.maximum(K_S * (s_ref - s_centre), -V_CORR), V_CORR)
        err = np.maximum(v_cmd, 0.0) - v
        self.integral = np.minimum(np.maximum(self.integral + err * dt, -2.0), 2.0)
        accel = self.paths.a_ref[:, k][q] + K_P * err + K_I * self.integral
        return accel, steer
