"""The focal length from vehicles driving along the road while the ego's speed changes (external poses).

:func:`deepcrashtest.geometry.selfcalib.focal_from_motion` needs parked vehicles: a car at rest at
``P`` is at depth ``Z_k = (P - c_k) . f_k = fy H / h_k`` from the camera at ``c_k`` (heading ``f_k``),
linear in ``(P, B = fy H)``. A car driving along the road at a steady speed ``v`` is at
``P + v tau_k d`` (``d``: the road's direction, the ego's mean heading over the track; ``tau_k``:
seconds since its first box): still linear, in ``(P, v, B)``. When the ego drives at a steady speed
on a straight road too, the gap closes at a steady rate and ``B`` is not measurable (depth and closing
speed scale together); every change of the ego's speed or heading that the other car does not share
measures it. Each track gives ``log B`` with its 1-sigma from the least-squares covariance (rows
weighted by the depth noise, ``~ Z`` for a box-height depth); the estimates are combined by inverse
variance about their weighted mode (cars that change speed themselves are the outliers). Parked
vehicles are the special case ``v = 0``.
"""

from __future__ import annotations

import math
from collections.abc import Iterator
from dataclasses import dataclass

import numpy as np
import pandas as pd

from deepcrashtest.geometry.egomotion import EgoMotion
from deepcrashtest.geometry.mono_config import class_size

MIN_TRACK_FRAMES = 10
#: Least ego travel (m) over a track.
MIN_TRAVEL_M = 4.0
#: Tracks whose own 1-sigma (log) exceeds this are not used; fewer usable than MIN_TRACKS: None.
MAX_TRACK_REL = 0.05
MIN_TRACKS = 1
#: Kernel width (log) of the weighted mode, and the band about it whose tracks are combined.
MODE_BW = 0.05
MODE_BAND = 0.1


@dataclass(frozen=True)
class Sightings:
    """One track's boxes seen from the ego's poses, as rows of the ground-vehicle model.

    A vehicle of class height ``H`` whose box is ``h`` px tall lies at depth ``fy H / h`` and lateral offset
    ``(u - cx) H / h`` (m) from the camera at ``c`` (world m) heading ``fwd`` (right ``right``): along ``fwd``
    its position satisfies ``P . fwd - B / h = c . fwd`` with ``B = fy H``, across ``P . right = c . right + u H
    / h``; ``rhs`` holds those right-hand sides (forward rows, then lateral rows)."""

    fwd: np.ndarray  # (n, 2) the ego's heading per box
    right: np.ndarray  # (n, 2) its right-hand side
    h: np.ndarray  # (n,) box height (px)
    H: float  # the class's height (m)
    rhs: np.ndarray  # (2n,)
    travel_m: float  # the ego's straight-line travel over the track (m)


def sightings(g: pd.DataFrame, ego: EgoMotion, idx: np.ndarray, cx: float) -> Sightings:
    """:class:`Sightings` of the track ``g`` (image-tracker rows) at the ego's states ``idx``; ``cx``: the
    forward-axis column (px)."""
    c = np.column_stack([ego.x[idx], ego.y[idx]])
    yaw = ego.yaw[idx]
    fwd = np.column_stack([np.cos(yaw), np.sin(yaw)])
    right = np.column_stack([np.sin(yaw), -np.cos(yaw)])
    H = class_size(str(g["category"].iloc[0]))[2]
    h = (g["y2"] - g["y1"]).to_numpy(float)
    u = 0.5 * (g["x1"] + g["x2"]).to_numpy(float) - cx
    rhs = np.r_[np.sum(c * fwd, axis=1), np.sum(c * right, axis=1) + u * H / h]
    return Sightings(fwd, right, h, H, rhs, float(np.hypot(*(c[-1] - c[0]))))


def pose_tracks(boxes: pd.DataFrame, ego: EgoMotion, min_boxes: int) -> Iterator[tuple[pd.DataFrame, np.ndarray]]:
    """Each track of ``boxes`` (image-tracker rows) with ``min_boxes`` or more boxes in frames the ego's poses
    cover, in frame order, with the indices of those poses."""
    frame_to_i = {int(f): i for i, f in enumerate(ego.frame)}
    for _, g in boxes[boxes["frame"].isin(frame_to_i.keys())].groupby("track_id"):
        if len(g) >= min_boxes:
            g = g.sort_values("frame")
            yield g, np.array([frame_to_i[int(f)] for f in g["frame"]])


def parked_fit(s: Sightings) -> np.ndarray:
    """``(Px, Py, B)`` of a parked vehicle from its :class:`Sightings`: least squares of the forward rows
    ``P . fwd - B / h`` and the lateral rows ``P . right`` against ``s.rhs`` (world m; ``B = fy H``, px m)."""
    n = len(s.h)
    rows = np.vstack([np.column_stack([s.fwd, -1.0 / s.h]), np.column_stack([s.right, np.zeros(n)])])
    sol, *_ = np.linalg.lstsq(rows, s.rhs, rcond=None)
    return sol


def weighted_log_mode(e: np.ndarray, w: np.ndarray, prior: tuple[float, float] | None = None) -> float:
    """The mode of the logs ``e`` (one per track, weights ``w``): the peak of their Gaussian kernel density
    (width :data:`MODE_BW`) over 400 points between their extremes, times a log-normal ``prior`` (value,
    1-sigma) when given."""
    grid = np.linspace(e.min(), e.max(), 400)
    density = (w[None, :] * np.exp(-0.5 * ((grid[:, None] - e[None, :]) / MODE_BW) ** 2)).sum(axis=1)
    if prior is not None:
        density = density * np.exp(-0.5 * ((grid - np.log(prior[0])) / (prior[1] / prior[0])) ** 2)
    return float(grid[density.argmax()])


def _track_estimate(
    g: pd.DataFrame, ego: EgoMotion, idx: np.ndarray, cx: float, fy0: float, excess: float
) -> tuple[float, float] | None:
    """(log focal length, its 1-sigma) of one track, or None (too little leverage)."""
    s = sightings(g, ego, idx, cx)
    if s.travel_m < MIN_TRAVEL_M:
        return None
    fwd, right, h, H, rhs = s.fwd, s.right, s.h, s.H, s.rhs
    yaw = ego.yaw[idx]
    ybar = math.atan2(float(np.mean(np.sin(yaw))), float(np.mean(np.cos(yaw))))
    d = np.array([math.cos(ybar), math.sin(ybar)])
    tau = ego.t[idx] - ego.t[idx][0]
    n = len(h)
    # unknowns (Px, Py, v, B): the parked vehicle's rows with the steady speed's column (v tau (d.f), v tau (d.r))
    A = np.vstack(
        [
            np.column_stack([fwd, tau * (fwd @ d), -1.0 / h]),
            np.column_stack([right, tau * (right @ d), np.zeros(n)]),
        ]
    )
    z = fy0 * H / h  # depth at the starting focal length: the depth noise grows with it
    w = np.r_[1.0 / z, 1.0 / z]
    Aw, bw = A * w[:, None], rhs * w
    sol, *_ = np.linalg.lstsq(Aw, bw, rcond=None)
    if not sol[3] > 0 or 2 * n <= 4:
        return None
    r = bw - Aw @ sol
    s2 = float(r @ r) / (2 * n - 4)
    try:
        cov = s2 * np.linalg.inv(Aw.T @ Aw)
    except np.linalg.LinAlgError:
        return None
    rel = math.sqrt(max(float(cov[3, 3]), 0.0)) / sol[3]
    return math.log(sol[3] / (H * excess)), rel


def focal_from_moving(
    tracks: pd.DataFrame, cx: float, ego: EgoMotion, fy0: float, excess: float
) -> tuple[float, float, int] | None:
    """(focal length px, relative 1-sigma, tracks used) from parked and steadily moving vehicles.

    ``tracks``: usable boxes (detected, uncut vehicles) of the image tracker; ``cx``: the forward-axis
    column (px); ``ego``: external metric poses; ``fy0``: the starting focal length (weights only);
    ``excess``: the box height over ``fy H / Z`` (see ``selfcalib.BOX_HEIGHT_EXCESS``)."""
    est, sig = [], []
    for g, idx in pose_tracks(tracks, ego, MIN_TRACK_FRAMES):
        one = _track_estimate(g, ego, idx, cx, fy0, excess)
        if one is not None and one[1] < MAX_TRACK_REL:
            est.append(one[0])
            sig.append(one[1])
    if len(est) < MIN_TRACKS:
        return None
    e, s = np.array(est), np.maximum(np.array(sig), 0.01)
    w = 1.0 / s**2
    grid = np.linspace(e.min() - 0.1, e.max() + 0.1, 400)
    z = (grid[:, None] - e[None, :]) / np.hypot(MODE_BW, s[None, :])
    density = (w[None, :] * np.exp(-0.5 * z**2)).sum(axis=1)
    mode = float(grid[density.argmax()])
    near = np.abs(e - mode) < np.maximum(MODE_BAND, 2 * s)
    if near.sum() < MIN_TRACKS:
        return None
    wn = w[near]
    mean = float(np.sum(wn * e[near]) / np.sum(wn))
    se = 1.0 / math.sqrt(float(np.sum(wn)))
    chi = float(np.sum(wn * (e[near] - mean) ** 2)) / max(int(near.sum()) - 1, 1)
    return math.exp(mean), se * math.sqrt(max(chi, 1.0)), int(near.sum())
