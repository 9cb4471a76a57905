"""Per-track image cues of the crash detection (:mod:`deepcrashtest.perception.crash_detect`): each track's table by
frame with whether the detector saw it, its box growth, the camera's jolt, a box's sudden change of motion, and the
picture's borders. Time scales in seconds, sizes as shares of the picture's width (module docstring of
``crash_detect``)."""

from __future__ import annotations

import numpy as np
import pandas as pd

#: A road user's motion changes suddenly when its box centre's velocity over CHANGE_SPAN_S (s) after a
#: frame differs from that before by CHANGE_FULL box widths per second (a box at least CHANGE_MIN_WIDTH of
#: the image wide), and the change counts CHANGE_HOLD_S (s) either side. In seconds, not frames: the second
#: difference of the box centre from frame to frame (full at 0.25 box widths) saturated on every frame of a
#: clip resampled to 30 fps (its frames repeated) and on the tracker's corrections (upscaled dad_000550: a
#: stall of the optical flow 0.4 s before the contact). The span 0.1 s spans the 3-frame pattern of 20 ->
#: 30 fps; CHANGE_FULL chosen on the tune clips (5 as the old per-frame threshold at 20 fps: dad_000478
#: 0.29 under the cut; 3.5: 0.38; 3: 0.42, the wrong pair of dad_000512 0.41 -> 0.45 against its 0.75).
CHANGE_SPAN_S = 0.1


CHANGE_FULL = 3.0


CHANGE_MIN_WIDTH = 20 / 1280


CHANGE_HOLD_S = 0.1


#: Box sizes (px) divided by are at least this share of the picture's width (10 px at 1280).
MIN_BOX_SHARE = 10 / 1280


#: Box growth (closing) and nearness are smoothed over about this long (s; 3 frames at 10-20 fps, 1 at 5 fps).
SMOOTH_S = 0.15


#: A box whose width and height change at rates (d ln / dt, 1/s) further apart than this turns, is seen from a new
#: side or is boxed with another road user (a rider with the scooter under them); its growth is then its slower
#: side's (:func:`box_growth`). A car turning across the view changes its box's aspect at about 1/s; chosen on the
#: crash-detection bench's tune clips in the variant sets (dad_000512 through a longer lens: a scooter crossing in
#: front of the stopped ego, 6/s, read as closing in); 4/s gave the same crashes.
ASPECT_JUMP_PER_S = 2.0


#: A box edge within this share of the picture's width (4 px at 1280) of its border is cut off by it.
BORDER_SHARE = 4 / 1280


#: A road user's evidence counts where the detector saw it: fully within SEEN_GAP_S (s; at least the
#: detector's own interval) of a frame in which its track was detected (not carried on by the tracker's
#: prediction), fading to nothing over SEEN_FADE_S more (chosen on dad_000487: the wrong pairs were tracks
#: coasting on their prediction for 0.5-1 s behind the nearer scooter; dad_000478's fallen scooter, last
#: detected 0.2 s before the contact, keeps its score).
SEEN_GAP_S = 0.3


SEEN_FADE_S = 0.3


def jolt_score(frames: np.ndarray, shifts: np.ndarray, fps: float) -> dict[int, float]:
    """Per frame 0..1: how much the camera's image motion jumps there (robust z-score of the
    second difference of the shift, saturating at z = 8). A repeated frame (its shift NaN,
    :class:`GlobalMotion`) is left out: the motion between new frames is that of the next new frame."""
    new = np.isfinite(shifts).all(axis=1) if len(shifts) else np.zeros(0, bool)
    frames, shifts = frames[new], shifts[new]
    if len(frames) < 4:
        return {}
    acc = np.zeros(len(frames))
    acc[1:-1] = np.hypot(*(shifts[2:] - 2 * shifts[1:-1] + shifts[:-2]).T)
    acc = np.maximum(acc, np.abs(np.r_[0.0, np.hypot(*np.diff(shifts, axis=0).T)]))
    med = float(np.median(acc))
    mad = float(np.median(np.abs(acc - med))) + 0.5
    z = (acc - med) / (1.4826 * mad)
    return {int(f): float(np.clip((zz - 3) / 5, 0, 1)) for f, zz in zip(frames, z, strict=True)}


def _detector_frames(tracks: pd.DataFrame) -> np.ndarray | None:
    """The frames in which the detector ran (a track row with ``state`` == detected); None without a
    ``state`` column (every box then counts as seen)."""
    if "state" not in tracks.columns:
        return None
    return np.unique(tracks.loc[tracks["state"] == "detected", "frame"].to_numpy(int))


def observed(g: pd.DataFrame, det_frames: np.ndarray | None, fps: float) -> pd.Series:
    """0..1 per frame of one track: 1 within ``SEEN_GAP_S`` (or the detector's interval, if longer) of a
    frame where the detector saw it, 0 from ``SEEN_FADE_S`` beyond; 1 where nothing says how the box was
    made (no ``state`` column)."""
    if det_frames is None or "state" not in g.columns or len(det_frames) < 2:
        return pd.Series(1.0, index=g.index)
    frames = g.index.to_numpy(float)
    seen = frames[(g["state"] == "detected").to_numpy()]
    if not len(seen):
        return pd.Series(0.0, index=g.index)
    gap = np.abs(frames[:, None] - seen[None, :]).min(axis=1) / fps  # to the nearest detection, s
    allowed = _seen_gap(det_frames, fps)
    return pd.Series(np.clip(1 - (gap - allowed) / SEEN_FADE_S, 0, 1), index=g.index)


def _seen_gap(det_frames: np.ndarray, fps: float) -> float:
    """``SEEN_GAP_S`` or the detector's interval (s), whichever is longer."""
    return max(SEEN_GAP_S, float(np.median(np.diff(det_frames))) / fps) if len(det_frames) >= 2 else SEEN_GAP_S


def reacquired(g: pd.DataFrame, det_frames: np.ndarray | None, fps: float) -> pd.Series:
    """True at the frames where a track that coasted on the tracker's prediction for longer than
    ``SEEN_GAP_S`` (or the detector's interval) is detected again: its box jumps there."""
    if det_frames is None or "state" not in g.columns:
        return pd.Series(False, index=g.index)
    det = (g["state"] == "detected").to_numpy()
    frames = g.index.to_numpy(float)
    seen = frames[det]
    out = np.zeros(len(g), bool)
    out[np.flatnonzero(det)[1:]] = np.diff(seen) / fps > _seen_gap(det_frames, fps)
    return pd.Series(out, index=g.index)


def per_track(tracks: pd.DataFrame, fps: float) -> dict[int, pd.DataFrame]:
    """Each track (>= 3 frames) indexed by frame, with ``seen`` (:func:`observed`), ``reacquired`` and
    ``switched`` (:func:`switched_box`)."""
    det_frames = _detector_frames(tracks)
    out = {}
    for tid, g in tracks.sort_values("frame").groupby("track_id"):
        g = g.drop_duplicates("frame").set_index("frame")
        if len(g) >= 3:
            out[int(str(tid))] = g.assign(
                seen=observed(g, det_frames, fps), reacquired=reacquired(g, det_frames, fps), switched=switched_box(g)
            )
    return out


#: A detected box whose width differs from the track's detected boxes before and after it by more than SWITCH_JUMP
#: (log size) each, both the same way, at a height within SWITCH_SAME_HEIGHT (log) of theirs, took in a road user
#: beside it (or lost part of itself) for a detection round.
SWITCH_JUMP = 0.3


SWITCH_SAME_HEIGHT = 0.1


def switched_box(g: pd.DataFrame) -> pd.Series:
    """True from a track's detected box that is wider (or narrower) than both its previous and next detected boxes
    by more than ``SWITCH_JUMP`` in log size, at their height, to the next detected box: the detector's box took
    in a road user beside it for one round (KITTI odometry seq06: one box over two cars parked side by side,
    42 -> 91 -> 59 px wide at 34-36 px tall); its centre's jump, and the jump back, are no motion of the road user.
    A box that changes its height with its width (a rider thrown off a motorcycle, dad_000478) is left."""
    out = pd.Series(False, index=g.index)
    if "state" not in g.columns:
        return out
    det = g[g["state"] == "detected"]
    if len(det) < 3:
        return out
    dw = np.diff(np.log(np.maximum((det["x2"] - det["x1"]).to_numpy(float), 1.0)))
    dh = np.diff(np.log(np.maximum((det["y2"] - det["y1"]).to_numpy(float), 1.0)))
    up, down = dw[:-1], dw[1:]
    jump = ((up > SWITCH_JUMP) & (down < -SWITCH_JUMP)) | ((up < -SWITCH_JUMP) & (down > SWITCH_JUMP))
    jump &= (np.abs(dh[:-1]) < SWITCH_SAME_HEIGHT) & (np.abs(dh[1:]) < SWITCH_SAME_HEIGHT)
    frames = det.index.to_numpy(int)
    for k in np.flatnonzero(jump) + 1:  # the switched detection, the boxes carried from it, the next detection
        out.loc[int(frames[k]) : int(frames[k + 1])] = True
    return out


def box_growth(
    g: pd.DataFrame, fps: float, width: int | None = None, height: int | None = None, jumped: np.ndarray | None = None
) -> pd.Series:
    """d ln(box size)/dt (1/s), smoothed over :func:`smooth_frames`: 1/TTC when the track approaches.

    With the picture's ``width`` and ``height`` (px) a box's two sides are read apart: a road user that comes nearer
    grows in both, one that turns or is seen from its side as it crosses only widens (dad_000512 through a longer
    lens: a scooter crossing in front of the stopped ego, 184 -> 449 px wide at a steady 330 px height, read as
    closing in). Where the two sides' rates are more than ``ASPECT_JUMP_PER_S`` apart the growth is then the smaller
    one, else their mean (the area's); a box cut by the picture's border keeps the area's growth (a car at the bumper
    keeps widening while its box is cut at the bottom)."""
    w = np.maximum(g["x2"].to_numpy(float) - g["x1"].to_numpy(float), 1.0)
    h = np.maximum(g["y2"].to_numpy(float) - g["y1"].to_numpy(float), 1.0)
    dt = np.maximum(np.diff(g.index.to_numpy(float)) / fps, 1e-6)
    gw, gh = np.diff(np.log(w)) / dt, np.diff(np.log(h)) / dt
    if width is None or height is None:
        r = np.r_[0.0, 0.5 * (gw + gh)]
    else:
        m = border_margin(width)
        cut_h = on_side(g, width)
        cut_v = ((g["y1"] <= m) | (g["y2"] >= height - m)).to_numpy(bool)
        cut_h, cut_v = cut_h[1:] | cut_h[:-1], cut_v[1:] | cut_v[:-1]
        uncut = np.where(np.abs(gw - gh) > ASPECT_JUMP_PER_S, np.minimum(gw, gh), 0.5 * (gw + gh))
        r = np.r_[0.0, np.where(cut_h | cut_v, 0.5 * (gw + gh), uncut)]
    if jumped is not None:  # the box jumped into these frames (onto the border): no approach in that step
        r = np.where(jumped, 0.0, r)
    return pd.Series(r, index=g.index).rolling(smooth_frames(fps), center=True, min_periods=1).mean()


def smooth_frames(fps: float) -> int:
    """The odd number of frames nearest to ``SMOOTH_S`` (3 at 10-20 fps, 5 at 30 fps: a clip resampled to 30 fps
    repeats every third frame, its box growth 0 there and double the next; 1 below 6.7 fps: three frames at 5 fps
    span 0.6 s, and the box of a bus cutting in was "near" a frame early, where the camera jolted as it swept the
    view, ccd_001143 at half its frame rate 0.8 s early -> 0.2 s)."""
    return max(1, int(round(SMOOTH_S * fps))) | 1


def border_margin(width: int) -> float:
    """The margin (px) within which a box edge is on the picture's border (``BORDER_SHARE``)."""
    return BORDER_SHARE * width


def on_side(g: pd.DataFrame, width: int) -> np.ndarray:
    """Per frame (bool): the box is on the picture's left or right border (within :func:`border_margin`)."""
    m = border_margin(width)
    return ((g["x1"] <= m) | (g["x2"] >= width - m)).to_numpy(bool)


def motion_change(g: pd.DataFrame, width: int, fps: float, other: pd.DataFrame | None = None) -> pd.Series:
    """0..1 per frame: a sudden change of the box centre's velocity (:data:`CHANGE_SPAN_S` before against
    after, in box widths per second, at least :data:`CHANGE_MIN_WIDTH` of the image), full at
    :data:`CHANGE_FULL` and held :data:`CHANGE_HOLD_S` either side; none within a span of either end of the
    track, where a track coasting on its prediction is detected again (``reacquired``), or where the picture's
    left or right side cuts the box (:func:`on_side`). With ``other`` (a track on the same frames): the change of
    the offset between the two boxes' centres, in the smaller box's widths, quiet where either box is."""
    t = g.index.to_numpy(float) / fps
    cx = ((g["x1"] + g["x2"]) / 2).to_numpy(float)
    cy = ((g["y1"] + g["y2"]) / 2).to_numpy(float)
    w = np.maximum((g["x2"] - g["x1"]).to_numpy(float), CHANGE_MIN_WIDTH * width)
    quiet = on_side(g, width)  # a box cut by the picture's side: its centre moves as it is cut, not with it
    for h in (g,) if other is None else (g, other):
        if "reacquired" in h.columns:  # the tracker correcting its prediction, not the road user's motion
            quiet |= h["reacquired"].to_numpy(bool)
        if "switched" in h.columns:  # the detector's box took in a road user beside it for a round
            quiet |= h["switched"].to_numpy(bool)
    if other is not None:
        cx = cx - ((other["x1"] + other["x2"]) / 2).to_numpy(float)
        cy = cy - ((other["y1"] + other["y2"]) / 2).to_numpy(float)
        w = np.minimum(w, np.maximum((other["x2"] - other["x1"]).to_numpy(float), CHANGE_MIN_WIDTH * width))
        quiet |= on_side(other, width)
    tau = CHANGE_SPAN_S
    a = np.zeros(len(g))
    inside = (t - tau >= t[0] - 1e-9) & (t + tau <= t[-1] + 1e-9) & (t > t[0]) & (t < t[-1])
    if inside.any():
        d2 = [np.interp(t + tau, t, c) - 2 * c + np.interp(t - tau, t, c) for c in (cx, cy)]
        a = np.where(inside, np.hypot(*d2) / tau / w, 0.0)  # velocity change, widths/s
    if quiet.any():
        a[np.abs(t[:, None] - t[quiet][None, :]).min(axis=1) <= max(tau, 1 / fps) + 1e-9] = 0.0
    hold = 2 * int(round(CHANGE_HOLD_S * fps)) + 1
    return pd.Series(np.clip(a / CHANGE_FULL, 0, 1), index=g.index).rolling(hold, center=True, min_periods=1).max()
