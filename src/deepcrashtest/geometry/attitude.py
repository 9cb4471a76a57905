"""The camera's pitch and roll frame by frame, from the background's rotation between frames.

A dashcam's car pitches when it brakes or accelerates, bounces and rolls on the road, and the crash itself
jolts the camera; the road users' road changes grade. The extraction's camera has one pitch for the clip
(the horizon of its first seconds, or the self-calibration's), so a box's bottom edge, read against that
horizon, misplaces the road user by the pitch change: a 1-degree nod moves the image ~11 px at 640 px focal
length, as much as a car's distance changes from 20 to 23 m at 1.3 m camera height.

The ego-motion estimator measures the camera's rotation between keyframes from the static scene (the
essential matrix; :attr:`~deepcrashtest.geometry.egomotion.EgoMotion.tilt` is its pitch and roll summed
over the clip). Summed rotations drift (each pair's error adds up), and the clip's mean pitch is already the
calibrated one: :func:`camera_wobble` keeps the fast part, the tilt minus its running mean over
``window_s``, as the change of the camera's downward pitch and of its roll at each frame (radians, the
conventions of :class:`~deepcrashtest.scenario.Camera`). Slow changes (a road's grade building up over many
seconds) stay with the clip's mean pitch and the per-frame horizon the road users' boxes give
(:func:`~deepcrashtest.geometry.mono3d.frame_horizon`).
"""

from __future__ import annotations

import numpy as np

from deepcrashtest.geometry.egomotion import EgoMotion

#: Running-mean window (s) whose residual is the camera's wobble. Chosen on six dashcam fidelity clips
#: (dad_000478/487/493, ccd_000080/330/882; fresh extracts, mean processed IoU): main 0.473, 2 s 0.509, 3 s 0.531;
#: projected raw boxes shifted by the wobble alone (no re-localisation): 1 s 0.509, 2 s 0.525, 3 s 0.531, 5 s 0.508.
WOBBLE_WINDOW_S = 3.0
#: Largest pitch/roll change kept (rad, ~8.6 deg): beyond it the rotation is a mis-solved pair, not the car.
MAX_WOBBLE_RAD = 0.15


def camera_wobble(ego: EgoMotion, window_s: float = WOBBLE_WINDOW_S, roll: bool = True) -> np.ndarray | None:
    """(N, 2) change of the camera's downward pitch and of its roll (rad) at each of ``ego``'s frames,
    the fast part of ``ego.tilt`` (see the module docstring); None when the tilt was not measured.

    ``roll`` False: the roll column is 0."""
    if ego.tilt is None or len(ego.t) < 3:
        return None
    tilt = np.asarray(ego.tilt, dtype=float).reshape(-1, 2)
    fast = tilt - _running_mean(ego.t, tilt, window_s)
    out = np.column_stack([-fast[:, 0], -fast[:, 1] if roll else np.zeros(len(fast))])  # nose up = less downward
    return np.clip(out, -MAX_WOBBLE_RAD, MAX_WOBBLE_RAD)


def _running_mean(t: np.ndarray, v: np.ndarray, window_s: float) -> np.ndarray:
    """Mean of ``v`` (N, k) over the samples within ``window_s / 2`` of each time ``t`` (s)."""
    t = np.asarray(t, dtype=float)
    lo = np.searchsorted(t, t - 0.5 * window_s, side="left")
    hi = np.searchsorted(t, t + 0.5 * window_s, side="right")
    csum = np.vstack([np.zeros((1, v.shape[1])), np.cumsum(v, axis=0)])
    return (csum[hi] - csum[lo]) / np.maximum(hi - lo, 1)[:, None]
