"""The camera height from parked vehicles seen along a metric ego path (external poses), free of class sizes.

The box line of :func:`deepcrashtest.geometry.selfcalib.horizon_and_height` takes its metric scale from
the class height prior: where the vehicles about are taller than it (KITTI tracking training sequence
0019: labelled cars 1.82 m tall on median against the prior 1.5 m), the camera height reads as low
(1.26 m against 1.65). A parked vehicle seen from a moving ego gives its depth without any size: its
world position ``P`` and ``B = fy H`` solve ``P . f_k - B / h_k = c_k . f_k`` (the ego at ``c_k``
heading ``f_k``, box height ``h_k``; the same rows as the parked-vehicle focal length) and its depth
``Z_k = (P - c_k) . f_k`` comes from the ego's travel, not from ``H``. Its bottom row then lies at
``v_b = v_h + fy hc / Z_k``: per track ``hc = (v_b - v_h) Z / fy`` (``v_h``: the box line's horizon,
``fy``: the calibrated focal length). Parked vehicles agree on ``hc`` whatever their size; moving ones
scatter (a car driving ahead at the ego's speed looks infinitely far), so the weighted mode of
``log hc`` over tracks is kept and one Huber line ``v_b`` against ``1 / Z`` through the agreeing
tracks' boxes gives ``fy hc``; its 1-sigma is a bootstrap over those tracks.
"""

from __future__ import annotations

import numpy as np
import pandas as pd

from deepcrashtest.geometry.egomotion import EgoMotion
from deepcrashtest.geometry.selfcalib_moving import MODE_BAND, parked_fit, pose_tracks, sightings, weighted_log_mode

#: A track needs this many boxes (and the ego this much travel over it, m) to place a parked vehicle;
#: boxes nearer or further than the depth range (m) are not used (the near face's bottom cut or hidden,
#: far rows' pixel noise).
MIN_TRACK_BOXES = 8
MIN_TRAVEL_M = 4.0
DEPTH_RANGE_M = (3.0, 60.0)
#: The fewest agreeing tracks (within ``MODE_BAND`` of the mode, in log).
MIN_TRACKS = 5
BOOTSTRAP = 30
SEED = 0


def _fit(parts: list[tuple[np.ndarray, np.ndarray]]) -> tuple[float, float]:
    """(horizon row px, slope ``fy hc`` px m) of the Huber line ``v_b = v_h + fy hc / Z`` over the parts' boxes."""
    from deepcrashtest.geometry.selfcalib import _huber_line

    return _huber_line(np.concatenate([p[0] for p in parts]), np.concatenate([p[1] for p in parts]))


def _parked_rows(g: pd.DataFrame, ego: EgoMotion, idx: np.ndarray, cx: float) -> tuple[np.ndarray, np.ndarray] | None:
    """(1 / depth 1/m, bottom row px) of one track's boxes, its depth from the ego's travel as a parked
    vehicle; None when the ego barely moved, the fit is degenerate or too few boxes lie in range."""
    s = sightings(g, ego, idx, cx)
    if s.travel_m < MIN_TRAVEL_M:
        return None
    px, py, b = parked_fit(s)
    if not b > 0:
        return None
    cam = np.column_stack([ego.x[idx], ego.y[idx]])
    z = np.sum((np.array([px, py])[None, :] - cam) * s.fwd, axis=1)
    ok = (z > DEPTH_RANGE_M[0]) & (z < DEPTH_RANGE_M[1])
    if ok.sum() < MIN_TRACK_BOXES // 2:
        return None
    return 1.0 / z[ok], g["y2"].to_numpy(float)[ok]


def height_from_parked(
    boxes: pd.DataFrame,
    cx: float,
    ego: EgoMotion,
    fy: float,
    horizon_v: float,
    prior: tuple[float, float] | None = None,
) -> tuple[float, float, int] | None:
    """(camera height m, its 1-sigma m, agreeing tracks) from parked vehicles (see the module docstring).

    ``boxes``: detected, uncut vehicle boxes of the image tracker; ``cx``, ``fy``: the forward-axis
    column and the focal length (px); ``ego``: metric external poses; ``horizon_v``: the horizon row (px)
    the tracks' heights are read against to find the parked ones; ``prior``: (height m, 1-sigma m) that
    weights the mode (cars moving in step with the ego make a mode of their own far below it). None with
    fewer than :data:`MIN_TRACKS` agreeing tracks."""
    parts = []
    for g, idx in pose_tracks(boxes, ego, MIN_TRACK_BOXES):
        one = _parked_rows(g, ego, idx, cx)
        if one is not None:
            parts.append(one)
    hc = np.array([np.median((vb - horizon_v) / iz) / fy for iz, vb in parts])
    keep = [k for k in range(len(parts)) if hc[k] > 0]
    if len(keep) < MIN_TRACKS:
        return None
    e = np.log(hc[keep])
    w = np.array([len(parts[k][1]) for k in keep], float)
    mode = weighted_log_mode(e, w, prior)
    agree = [parts[k] for k, ek in zip(keep, e, strict=True) if abs(ek - mode) < MODE_BAND]
    if len(agree) < MIN_TRACKS:
        return None
    slope = _fit(agree)[1]
    rng = np.random.default_rng(SEED)
    boots = [_fit([agree[i] for i in rng.integers(0, len(agree), len(agree))])[1] for _ in range(BOOTSTRAP)]
    return slope / fy, float(np.std(boots)) / fy, len(agree)
