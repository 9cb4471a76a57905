"""The ego's speed from sparse road-scale readings: a Kalman filter with a decaying acceleration and a
Rauch-Tung-Striebel smoother (step 5 of :mod:`deepcrashtest.geometry.egomotion`). Speeds in m/s, times in s."""

from __future__ import annotations

import math

import numpy as np


class SpeedFilter:
    """Kalman filter on speed (m/s) and acceleration with gating, and an RTS smoother.

    ``jerk`` (m/s^3): white-noise jerk density of the process. ``accel_tau_s``: the acceleration decays
    towards 0 with this time constant (a Singer model; 0 = constant acceleration). A car brakes or
    speeds up for a second or two, not for a whole clip: without the decay, a few scattered road-scale
    measurements on a dashcam clip were extrapolated into ramps over the whole clip (CCD clips: 10 ->
    27 m/s in a city street over 5 s; 1.5 s, a vehicle-dynamics prior not tuned on any clip, ends
    those ramps at 15 m/s and leaves the KITTI odometry errors as they were). Measurements whose innovation is
    beyond ``gate`` standard deviations are ignored, unless ``max_rejects`` come in a row (then the
    filter re-starts from the measurement: a real change, not an outlier). After ``hold_s`` seconds
    without a measurement the acceleration is dropped and the speed held: on ccd_000882 (no road scale
    after frame 11) the last, noisy deceleration was extrapolated to 0 m/s, and 27 of 49 frames read
    "stopped" while the ego drove. ``hold_accel`` (m/s^2; 0 = off): while held, the speed's
    variance grows by ``hold_accel^2 dt`` a step (a car's speed unmeasured for t seconds is uncertain by about
    ``hold_accel sqrt(t)``); without it the held speed's variance hardly grows and the next sparse reading is
    gated however right it is (KITTI odometry seq00 with every 10th reading kept: 5 of 16 gated while the
    readings err 2.8 % median; ``bench/road_scale_scatter.py --keep 10``).
    """

    def __init__(
        self,
        jerk: float = 3.0,
        gate: float = 3.0,
        max_rejects: int = 3,
        accel_tau_s: float = 0.0,
        hold_s: float = 0.5,
        hold_accel: float = 0.0,
    ) -> None:
        self.hold_s = hold_s
        self.hold_accel = hold_accel
        self.q = jerk**2
        self.tau = accel_tau_s
        self.gate = gate
        self.max_rejects = max_rejects
        self.x = np.zeros(2)
        self.P = np.diag([100.0, 25.0])
        self.rejects = 0
        self.started = False
        self.since = 0.0  # seconds since the last measurement
        self.first = 0  # the step of the first measurement: earlier steps take its smoothed speed
        self.log: list[tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray]] = []
        self.readings: list[tuple[int, float, float, str]] = []  # (step, m/s, variance, start/restart/gated/fused)

    def step(self, dt: float, z: float | None, var: float) -> float:
        """Advance by ``dt`` seconds, fuse the speed measurement ``z`` (variance ``var``); returns speed."""
        self.since += dt
        decay = math.exp(-dt / self.tau) if self.tau > 0 else 1.0
        if self.since > self.hold_s:
            decay = 0.0  # no speed measured for a while: keep the speed, forget the acceleration
        F = np.array([[1.0, dt], [0.0, decay]])
        Q = self.q * np.array([[dt**3 / 3, dt**2 / 2], [dt**2 / 2, dt]])
        if self.since > self.hold_s:  # held: the speed drifts as a random walk of hold_accel (m/s^2) density
            Q[0, 0] += self.hold_accel**2 * dt
        xp, Pp = F @ self.x, F @ self.P @ F.T + Q
        x, P = xp, Pp
        if z is not None:
            self.since = 0.0
            S = Pp[0, 0] + var
            innov = z - xp[0]
            if not self.started or self.rejects >= self.max_rejects:
                x, P = np.array([z, 0.0]), np.diag([var, 4.0])
                outcome = "restart" if self.started else "start"
                if not self.started:
                    self.first = len(self.log)
                self.started, self.rejects = True, 0
            elif innov * innov > self.gate**2 * S:
                self.rejects += 1
                outcome = "gated"
            else:
                Kg = Pp[:, 0] / S
                x = xp + Kg * innov
                P = Pp - np.outer(Kg, Pp[0])
                self.rejects, outcome = 0, "fused"
            self.readings.append((len(self.log), float(z), float(var), outcome))
        self.x, self.P = x, P
        self.log.append((F, xp, Pp, x, P))
        return max(0.0, float(x[0]))

    def taken(self, step: float = math.inf) -> int:
        """How many readings (not gated) were taken up to filter step ``step``."""
        return sum(1 for k, _, _, outcome in self.readings if k <= step and outcome != "gated")

    def confirmed(self, step: int) -> bool:
        """Whether two readings or more (not gated) were taken up to filter step ``step``."""
        return self.taken(step) >= 2

    def smoothed(self, cut: int | None = None) -> np.ndarray:
        """RTS-smoothed speeds of every step so far (m/s, >= 0). ``cut``: a step after which the
        smoother starts afresh, so that no later reading moves the speeds up to that step (a crash's
        readings after it do not spread the crash's slowing to before it)."""
        if not self.log:
            return np.zeros(0)
        xs = [self.log[-1][3]]
        Ps = [self.log[-1][4]]
        for k in range(len(self.log) - 2, -1, -1):
            if k == cut:
                xs.append(self.log[k][3])
                Ps.append(self.log[k][4])
                continue
            F1, xp1, Pp1 = self.log[k + 1][:3]
            xk, Pk = self.log[k][3], self.log[k][4]
            C = Pk @ F1.T @ np.linalg.pinv(Pp1)
            xs.append(xk + C @ (xs[-1] - xp1))
            Ps.append(Pk + C @ (Ps[-1] - Pp1) @ C.T)
        out = np.maximum(0.0, np.array([x[0] for x in reversed(xs)]))
        out[: self.first] = out[self.first]  # before any measurement: no evidence of another speed
        return out
