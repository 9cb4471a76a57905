"""The search space: where a variant's ego starts and how its path is bent.

A variant is one parameter vector ``theta`` (metres throughout)::

    theta = [d_lon, d_lat, ex_1, ey_1, ..., ex_{M-1}, ey_{M-1}]

* ``d_lon, d_lat``: start offset in the ego's initial frame (forward, left), inside the box
  ``|d_lon| <= box_longitudinal / 2``, ``|d_lat| <= box_lateral / 2``. The whole reference path
  moves with the start (the ego drives the same manoeuvre from another place).
* ``ex_k, ey_k``: world-frame displacement of control point k of the ego's B-spline (k >= 1; the
  first control point is the start itself and only moves with the offset). Random variants
  draw these from N(0, noise_sigma^2).

The "change" of a variant, the size the adaptive search minimises, is
``sqrt(d_lon^2 + d_lat^2 + mean_k(ex_k^2 + ey_k^2))`` metres: the start displacement and the RMS
control-point displacement, combined.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from deepcrashtest.errors import UserError
from deepcrashtest.scenario import Scenario, SplineParams, Trajectory
from deepcrashtest.search.spline import (
    control_points,
    ego_spline,
    evaluate_paths,
    path_kinematics,
    trajectory_from_path,
)


@dataclass(frozen=True)
class SearchSpace:
    """Box of start offsets + control-point noise around one scenario's ego (metres)."""

    spline: SplineParams
    yaw0: float  # ego heading at t=0, radians (world)
    t: tuple[float, ...]  # the ego trajectory's sample times, seconds
    box_lateral: float = 4.0
    box_longitudinal: float = 8.0
    noise_sigma: float = 0.3

    def __post_init__(self) -> None:
        for name in ("box_lateral", "box_longitudinal", "noise_sigma"):
            v = getattr(self, name)
            if not np.isfinite(v) or v < 0:
                raise UserError(f"--{name.replace('_', '-')} must be a finite number >= 0 (got {v})")

    @classmethod
    def for_scenario(
        cls, scenario: Scenario, box_lateral: float = 4.0, box_longitudinal: float = 8.0, noise_sigma: float = 0.3
    ) -> SearchSpace:
        ego = scenario.ego.trajectory
        return cls(
            spline=ego_spline(scenario.ego),
            yaw0=float(ego.yaw[0]),
            t=tuple(float(v) for v in ego.t),
            box_lateral=box_lateral,
            box_longitudinal=box_longitudinal,
            noise_sigma=noise_sigma,
        )

    # ------------------------------------------------------------------ layout
    @property
    def n_ctrl(self) -> int:
        return len(self.spline.cx)

    @property
    def dim(self) -> int:
        return 2 + 2 * (self.n_ctrl - 1)

    @property
    def half_box(self) -> np.ndarray:
        """(2,) half extents of the start box: longitudinal, lateral (metres)."""
        return np.array([self.box_longitudinal / 2.0, self.box_lateral / 2.0])

    def scale(self) -> np.ndarray:
        """(D,) natural spread of each parameter: the half box for starts, sigma for the noise."""
        return np.concatenate([self.half_box, np.full(self.dim - 2, self.noise_sigma)])

    def clip(self, theta: np.ndarray) -> np.ndarray:
        """Keep start offsets inside the box (noise is unbounded)."""
        out = np.array(theta, dtype=float, copy=True)
        out[..., :2] = np.clip(out[..., :2], -self.half_box, self.half_box)
        return out

    # ------------------------------------------------------------------ sampling
    def sample_starts(self, rng: np.random.Generator, n: int) -> np.ndarray:
        """(n, 2) start offsets drawn uniformly in the box."""
        return rng.uniform(-self.half_box, self.half_box, size=(n, 2))

    def sample_noise(self, rng: np.random.Generator, n: int) -> np.ndarray:
        """(n, D-2) control-point displacements drawn from N(0, noise_sigma^2)."""
        return rng.normal(0.0, 1.0, size=(n, self.dim - 2)) * self.noise_sigma

    def reference_grid(self, rng: np.random.Generator, starts: int, noise_variants: int) -> np.ndarray:
        """The reference experiment: ``starts`` box samples x ``noise_variants`` noisy paths each.

        Returns (starts * noise_variants, D), start-major (rows 0..noise_variants-1 share a start).
        """
        if starts < 1 or noise_variants < 1:
            raise UserError(f"--starts and --noise-variants must be >= 1 (got {starts}, {noise_variants})")
        s = np.repeat(self.sample_starts(rng, starts), noise_variants, axis=0)
        return np.hstack([s, self.sample_noise(rng, starts * noise_variants)])

    # ------------------------------------------------------------------ geometry
    def change(self, theta: np.ndarray) -> np.ndarray:
        """Size of each variant's change to the original (metres, see the module docstring)."""
        th = np.atleast_2d(theta)
        start2 = (th[:, :2] ** 2).sum(axis=1)
        noise2 = (th[:, 2:] ** 2).reshape(len(th), -1, 2).sum(axis=2).mean(axis=1) if self.dim > 2 else 0.0
        return np.sqrt(start2 + noise2)

    def offsets_world(self, theta: np.ndarray) -> np.ndarray:
        """(B, 2) start offsets rotated into the world frame."""
        th = np.atleast_2d(theta)
        c, s = np.cos(self.yaw0), np.sin(self.yaw0)
        return np.column_stack([c * th[:, 0] - s * th[:, 1], s * th[:, 0] + c * th[:, 1]])

    def control_points(self, theta: np.ndarray) -> np.ndarray:
        """(B, M, 2) control points of each variant's ego spline (world frame)."""
        th = np.atleast_2d(theta)
        base = control_points(self.spline)
        noise = np.zeros((len(th), self.n_ctrl, 2))
        noise[:, 1:, :] = th[:, 2:].reshape(len(th), self.n_ctrl - 1, 2)
        return base[None] + self.offsets_world(th)[:, None, :] + noise

    def sim_times(self) -> np.ndarray:
        """(K,) times of the waypoints handed to the simulator: K equally spaced over the ego's span."""
        return np.linspace(self.t[0], self.t[-1], len(self.t))

    def paths(self, theta: np.ndarray) -> np.ndarray:
        """(B, K, 2) reference waypoints of each variant (start offset included) at ``sim_times()``."""
        return evaluate_paths(self.spline, self.control_points(theta), self.sim_times())

    def variant_spline(self, theta: np.ndarray) -> SplineParams:
        """The spline of one variant (for its Scenario file)."""
        c = self.control_points(theta)[0]
        return SplineParams(
            knots=list(self.spline.knots), cx=c[:, 0].tolist(), cy=c[:, 1].tolist(), degree=self.spline.degree
        )

    def variant_trajectory(self, theta: np.ndarray) -> Trajectory:
        """The ego trajectory of one variant (x, y, yaw, speed at the original sample times)."""
        return trajectory_from_path(self.spline, self.control_points(theta)[0], np.asarray(self.t))

    def variant_kinematics(self, theta: np.ndarray) -> list[tuple[np.ndarray, ...]]:
        """Per variant of ``theta`` (B, D): its trajectory's arrays t, x, y (m), yaw (rad), speed (m/s), as
        :meth:`variant_trajectory` builds them, computed for all at once (``Trajectory.from_arrays(*arrays)``)."""
        t = np.asarray(self.t, dtype=float)
        xy, yaw, speed = path_kinematics(self.spline, self.control_points(theta), t)
        return [(t, xy[b, :, 0], xy[b, :, 1], yaw[b], speed[b]) for b in range(len(xy))]

    def names(self) -> list[str]:
        """Column names of theta, for results.csv."""
        cols = ["d_lon", "d_lat"]
        for k in range(1, self.n_ctrl):
            cols += [f"ex_{k}", f"ey_{k}"]
        return cols
