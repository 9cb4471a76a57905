"""Road-aligned (Frenet-like) coordinates along a polyline: station s and lateral offset d.

World frame (x forward, y left, metres). ``s`` is the arc length along the centre line from its
first point, ``d`` the signed distance to the left of it. Beyond both ends the centre line is
continued straight along its end tangents, so every point has coordinates and every (s, d) has
a point.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.interpolate import splev, splprep
from scipy.spatial import cKDTree

from deepcrashtest.trajectory.alongpath import arc_length

_EPS = 1e-9


@dataclass(frozen=True)
class RoadFrame:
    """A dense centre-line polyline ``pts`` (N >= 2, metres) and its stations ``s`` (metres)."""

    pts: np.ndarray
    s: np.ndarray

    @classmethod
    def from_polyline(cls, pts: np.ndarray) -> RoadFrame:
        p = np.asarray(pts, dtype=float)
        keep = np.r_[True, np.hypot(*np.diff(p, axis=0).T) > 1e-6]
        p = p[keep]
        if len(p) < 2:
            raise ValueError("a road frame needs two distinct points")
        s = arc_length(p)
        return cls(p, s)

    @classmethod
    def from_path(
        cls, xy: np.ndarray, sigma_m: float, spacing_m: float = 1.0, heading: float = 0.0, min_length_m: float = 20.0
    ) -> RoadFrame:
        """Heavily smoothed centre line through a path (metres), resampled every ``spacing_m``.

        The path is parameterised by arc length and fitted with a parametric smoothing spline whose
        RMS deviation from the path is ``sigma_m``. A path shorter than 1 m (a vehicle at rest)
        gives a straight line of ``min_length_m`` along ``heading`` (radians).
        """
        p = np.asarray(xy, dtype=float)
        p = p[np.r_[True, np.hypot(*np.diff(p, axis=0).T) > 1e-3]] if len(p) > 1 else p
        u = arc_length(p)
        if u[-1] < 1.0:
            d = np.array([np.cos(heading), np.sin(heading)])
            return cls.from_polyline(np.vstack([p[0], p[0] + min_length_m * d]))
        k = min(3, len(p) - 1)
        tck, _ = splprep([p[:, 0], p[:, 1]], u=u, s=len(p) * sigma_m**2, k=k)
        n = max(2, int(np.ceil(u[-1] / spacing_m)) + 1)
        ug = np.linspace(0.0, u[-1], n)
        x, y = splev(ug, tck)
        return cls.from_polyline(np.column_stack([x, y]))

    @property
    def length(self) -> float:
        return float(self.s[-1])

    def _segment(self, s: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        i = np.clip(np.searchsorted(self.s, s, side="right") - 1, 0, len(self.s) - 2)
        return i, s - self.s[i]

    def _unit(self, i: np.ndarray) -> np.ndarray:
        seg = self.pts[i + 1] - self.pts[i]
        return seg / np.hypot(seg[..., 0], seg[..., 1])[..., None]

    def tangent(self, s: np.ndarray | float) -> np.ndarray:
        """Heading of the centre line at station(s) ``s``, radians."""
        i, _ = self._segment(np.atleast_1d(np.asarray(s, dtype=float)))
        u = self._unit(i)
        return np.arctan2(u[:, 1], u[:, 0])

    def point(self, s: np.ndarray | float, d: np.ndarray | float = 0.0) -> np.ndarray:
        """World points (N, 2) at stations ``s`` and lateral offsets ``d`` (metres, left positive)."""
        s_arr = np.atleast_1d(np.asarray(s, dtype=float))
        d_arr = np.broadcast_to(np.asarray(d, dtype=float), s_arr.shape)
        i, ds = self._segment(s_arr)
        u = self._unit(i)
        normal = np.column_stack([-u[:, 1], u[:, 0]])
        return self.pts[i] + ds[:, None] * u + d_arr[:, None] * normal

    def project(self, xy: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Stations and lateral offsets (metres) of world points ``xy`` (N, 2): nearest point of the line.

        Candidates are the segments next to the 4 nearest vertices (KD-tree), enough for a dense,
        smooth centre line."""
        q = np.atleast_2d(np.asarray(xy, dtype=float))
        m = len(self.pts) - 1  # segments
        _, near = self._tree().query(q, k=min(4, len(self.pts)))
        near = np.atleast_2d(near).reshape(len(q), -1)
        cand = np.clip(np.concatenate([near - 1, near], axis=1), 0, m - 1)  # (N, C) segment indices
        a = self.pts[cand]
        seg = self.pts[cand + 1] - a
        seg_len = np.hypot(seg[..., 0], seg[..., 1])
        u = seg / seg_len[..., None]
        rel = q[:, None, :] - a
        along = np.einsum("nck,nck->nc", rel, u)
        lo = np.where(cand == 0, -np.inf, 0.0)  # straight continuation beyond the ends
        hi = np.where(cand == m - 1, np.inf, seg_len)
        along_c = np.clip(along, lo, hi)
        foot = a + along_c[..., None] * u
        dist = np.hypot(*(q[:, None, :] - foot).transpose(2, 0, 1))
        j = dist.argmin(axis=1)
        rows = np.arange(len(q))
        s = self.s[cand[rows, j]] + along_c[rows, j]
        uj, rj = u[rows, j], rel[rows, j]
        cross = uj[:, 0] * rj[:, 1] - uj[:, 1] * rj[:, 0]
        return s, cross

    def _tree(self) -> cKDTree:
        tree = self.__dict__.get("_kdtree")
        if tree is None:
            tree = cKDTree(self.pts)
            object.__setattr__(self, "_kdtree", tree)
        return tree

    def resampled(self, s_from: float, s_to: float, spacing_m: float, d: float = 0.0) -> np.ndarray:
        """Waypoints (N, 2) every ``spacing_m`` from ``s_from`` to ``s_to`` (may reach past the ends), ``d`` metres
        left of the line (negative: right)."""
        n = max(2, int(np.ceil((s_to - s_from) / spacing_m)) + 1)
        return self.point(np.linspace(s_from, s_to, n), d)
