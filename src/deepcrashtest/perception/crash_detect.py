"""Find the crash in a dashcam video from image evidence: which two road users touch, when, how sure.

Inputs are plain arrays (no upstream stage is imported): the tracks table (one row per track per
frame: ``frame``, ``time`` s, ``track_id``, ``x1, y1, x2, y2`` px), the image size, and per frame
the camera's global image motion (``GlobalMotion``: dx, dy px between consecutive frames, on a
downscaled image) and, optionally, each track's distance to the ego and to other tracks in 3D
(metres, from localisation).

Evidence, per candidate pair and frame (each scored 0..1):

* ego + track: the track's box is near (wide in the image, its bottom at the image bottom or cut
  off), closing fast (time to contact from the box's growth under ~1 s), and the camera jolts
  (a spike of the global image motion's second difference against its median: the impact shakes
  the camera);
* two tracks: their boxes touch or overlap in the image, they are close in 3D (``world``: their
  ground positions, metres, less than ``CLOSE_3D_M`` apart beyond their half widths within the last
  ``CLOSE_3D_WINDOW_S``; without ``world``, bottoms at a similar image row), and one of them changes
  motion suddenly (its box centre's velocity over ``CHANGE_SPAN_S`` after against before); discounted
  when a road user is at the ego's bumper in the clip (near, approaching or with a jolt: not the ego's
  own bonnet; in full when that ego crash scores ``EGO_CREDIBLE``). Two pedestrians are never a crash
  pair.

Every time scale is in seconds, every size a share of the picture (the picture inside black bars,
``picture``, when the video has them): users' clips are resampled (frames repeated or dropped),
upscaled and letterboxed.

Only what the detector saw counts (with a ``state`` column, detected or predicted): a pair's evidence
fades where a track coasts on the tracker's prediction (``SEEN_GAP_S``), the box jump where a coasting
track is detected again is no change of motion, and a pair inside a nearer road user's box (a rider, a
road user behind it: ``HIDDEN_FROM``) is hidden. A pair must be seen apart before it touches, unless one
of them entered the view at the image border. A road user that leaves the view at the side soon after
its ego "contact" without having been ahead (``EXIT_WINDOW_S``) drove past: no ego crash without a jolt.

"Near" for an ego crash is the box's width or, for narrow road users (a person, a two-wheeler), its
height as a share of the image, with its bottom in the lower part of the image.

The contact frame of an ego crash is the first camera jolt while the road user is near (where that jolt
peaks when it starts while the box still grows fast, :func:`_jolt_peak`; or, when its
box had already stopped growing at the bumper ``STILL_BEFORE_JOLT_S`` before that jolt, the frame it
stopped: the jolt is the same crash going on), else the
"knee" where its approaching box stops growing, else the first frame at which it is nearest; one
frame later when that frame is where the box jumps onto the image border (the road user filling the
view: its box stops growing and it moves the image the jolt is measured on), and for a jolt on the frame
just before that jump (its centred second difference holds the jump's shift) the frame after the jump.

The crash is the best-scoring (pair, frame); among pairs of road users within ``TIE_MARGIN`` of the
best pair, the one whose score holds longest over ``CONTACT_HOLD_S`` after its contact (:func:`ranked`).
The contact frame is the first frame of that pair's evidence peak. ``confidence`` is the combined score
(0..1). None when nothing scores above ``min_score``.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import pandas as pd

from deepcrashtest.perception.global_motion import GlobalMotion as GlobalMotion  # detect_crash's input, re-exported
from deepcrashtest.perception.roadusers import track_category

EGO = 0  # the ego's id in a crash pair
#: A knee (the box stops growing) is one when the box grows less than this (log size) in the next 0.5 s
#: (chosen on dad_000487: a box jump 1.6 s before the contact).
KNEE_MAX_LATER_GROWTH = 0.1
#: ... and the box is at least this near (``ego_scores``' ``near``, 0..1) at the knee.
KNEE_MIN_NEAR = 0.3
#: A camera jolt that starts while the road user's box still grows at least this fast (``closing``, 0..1: 1 is a
#: time to contact of 0.67 s) has its contact where the jolt peaks (:func:`_jolt_peak`); chosen on ccd_000330 at
#: 5 fps (``bench/fidelity_perturbed.py`` halffps, its box's closing 0.36-0.73 through the jolt's rise) against
#: ccd_000487 (closing 0.08 at its jolt).
JOLT_RISE_CLOSING = 0.3
#: A camera jolt after which the road user's box still grows by more than APPROACH_AFTER_GROWTH (log size) within
#: APPROACH_AFTER_S (s) is no contact: a road user cannot go on approaching through the ego's front, and a box
#: growing fast fills more of the view each frame and moves the image the jolt is measured on
#: (:class:`~deepcrashtest.perception.global_motion.GlobalMotion`), most where a narrow lens makes it large early.
#: ``bench/fidelity_perturbed.py --variants zoom`` (the middle 1/1.3 of the frame): ccd_001143's bus jolted the
#: "camera" three frames while it still closed in by 0.5 in log size, the crash put 0.7 s early.
APPROACH_AFTER_S = 0.3
APPROACH_AFTER_GROWTH = 0.25
#: A pair's contact must follow a time apart: the share of the previous ONSET_WINDOW_S (s) with the boxes
#: apart, saturating at ONSET_APART (chosen on dad_000478 and the highway clip: image overlap all along).
ONSET_WINDOW_S = 1.0
ONSET_APART = 0.3
#: An ego crash needs this much approach (closing) or jolt evidence at full score: a box at the bumper
#: from the start without either is the ego's own bonnet or a queue (dad_000512: the bonnet as a "car").
EGO_MIN_EVIDENCE = 0.3
#: A road user at the ego's bumper discounts the pairs of tracks (an ego crash is the likelier one) in full when
#: its ego crash scores at least EGO_CREDIBLE (the default cut), less in proportion below: a two-wheeler that
#: passed close beside the ego 3 s before a third-party crash is no rival ego crash (dad_000478).
EGO_CREDIBLE = 0.35
#: A pair's contact frame is the first frame whose score reaches this share of its peak (0.9 -> 0.97 on
#: dad_000550: 0.35 s early -> on the label; dad_000478 unchanged).
PAIR_PEAK_SHARE = 0.97
#: Pairs of road users whose scores come within TIE_MARGIN (of the 0..1 score) of the best pair's are a
#: near-tie, ranked by how their evidence holds after the contact: the mean score over CONTACT_HOLD_S (s) from
#: the contact frame on (two road users in contact stay touching and close; a box overlap meeting a spike of
#: motion is over within a frame or two). Chosen on dad_000512 letterboxed: the scooters' crash (its score
#: held 0.3 s) tied at the peak with a "car" box riding on one scooter and the ego's bonnet under the other
#: (each 1 frame at the peak); the 20 clips of bench/labels unchanged (no near-tie changes their pair).
TIE_MARGIN = 0.05
CONTACT_HOLD_S = 0.3
#: A pair whose score reaches its peak on a plateau (the boxes overlap and the footprints touch before the
#: road users meet) has its contact where the motion change rises anew: the first frame within
#: NEW_CHANGE_WINDOW_S (s) of the plateau's start whose motion change exceeds the least since that start by
#: NEW_CHANGE_RISE, while the pair still touches and is close (image contact x closeness >= NEW_CHANGE_HELD)
#: and its score is at least NEW_CHANGE_SCORE of the peak. dad_000550 re-encoded at crf 35 loses the
#: scooter's detections at the contact: its score is flat from frame 82, where the boxes first overlap, to the
#: contact (88), where its motion change rises (0.31 s early -> on the label).
NEW_CHANGE_RISE = 0.1
NEW_CHANGE_WINDOW_S = 0.5
NEW_CHANGE_HELD = 0.9
NEW_CHANGE_SCORE = 0.5
#: Two road users count as close in 3D when their ground-plane gap (centre distance less their half
#: widths, metres) is under this; chosen on the DAD clips (labelled pairs 0-1 m, others >= 2.5 m).
CLOSE_3D_M = 2.5
#: ... at some time in the last CLOSE_3D_WINDOW_S (s) up to the frame (mono 3D positions jump by metres from
#: frame to frame). Only before it: a window either side made the pair close up to 0.3 s before they met, and
#: the contact that early (dad_000550 upscaled: 0.35 s early; dad_000512 0.1 s -> on the label).
CLOSE_3D_WINDOW_S = 0.3
#: ... and the last gap is held this long (s) after a road user's 3D positions end.
CLOSE_3D_HOLD_S = 0.6
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
#: A box edge within this share of the picture's width (4 px at 1280) of its border is cut off by it.
BORDER_SHARE = 4 / 1280
#: ... and a box growing more than this (log size) in the frame it reaches the border jumped onto it
#: (chosen on the tune clips: ccd_000014 0.33, ccd_001143 0.26 jumped; ccd_000132 0.07 grew).
BORDER_JUMP = 0.15
#: A jolt that comes after the road user's box has stayed this long (s) at the bumper without growing
#: (by less than ``KNEE_MAX_LATER_GROWTH`` in log size over the next 0.5 s) belongs to a crash that began
#: when the box stopped growing (chosen between ccd_000053, a jolt 0.4 s after the box stops: the
#: contact, and ccd_000755, a jolt 1.0 s after the car is at the bumper as it is pushed on).
STILL_BEFORE_JOLT_S = 0.7
#: A pedestrian's box is upright at a median height/width of at least UPRIGHT_ASPECT and knocked over below
#: FALLEN_ASPECT (walkers 2-3.5; ccd_000882's struck woman 2.1 -> 1.25 at the contact frame).
UPRIGHT_ASPECT = 1.8
FALLEN_ASPECT = 1.5
#: A road user's evidence counts where the detector saw it: fully within SEEN_GAP_S (s; at least the
#: detector's own interval) of a frame in which its track was detected (not carried on by the tracker's
#: prediction), fading to nothing over SEEN_FADE_S more (chosen on dad_000487: the wrong pairs were tracks
#: coasting on their prediction for 0.5-1 s behind the nearer scooter; dad_000478's fallen scooter, last
#: detected 0.2 s before the contact, keeps its score).
SEEN_GAP_S = 0.3
SEEN_FADE_S = 0.3
#: A pair whose boxes lie inside a nearer road user's box (its bottom lower in the image) is hidden behind
#: it or part of it (a rider, a passenger): no discount while less than HIDDEN_FROM of the pair's joint box
#: lies inside, none of its score left from HIDDEN_FULL on (chosen on dad_000487: a rider and a car behind
#: the ego's scooter, both inside its box, their boxes jittering as it passes).
HIDDEN_FROM = 0.5
HIDDEN_FULL = 0.9
#: A road user leaving the view at the image's side within EXIT_WINDOW_S (s) after an ego "contact"
#: (its visible width at the border falling below EXIT_WIDTH_SHARE of the width at that frame) without
#: having been ahead (its box over the image's centre column while near, in the second before) drove past
#: the ego; without a camera jolt it is no ego crash (chosen on dad_000487: an oncoming car passing close;
#: dad_000493's scooter, hit while ahead, leaves the view at the side as the ego turns).
EXIT_WINDOW_S = 1.0
EXIT_WIDTH_SHARE = 0.5


@dataclass(frozen=True)
class WorldTrack:
    """A road user's ground position per video frame (world x, y metres) and its half width (m); with
    its half length (m) and heading per frame (``yaw``, rad CCW from world x, unwrapped) its footprint
    is a rectangle, else a disc of its half width."""

    frames: np.ndarray
    x: np.ndarray
    y: np.ndarray
    half_width: float
    half_length: float | None = None
    yaw: np.ndarray | None = None


@dataclass(frozen=True)
class CrashFinding:
    """The detected crash: the contact frame (video index), its time (s, video time), the pair (ids,
    0 = ego), a confidence 0..1 and the evidence scores behind it."""

    frame: int
    time_s: float
    pair: tuple[int, int]
    confidence: float
    evidence: dict[str, float]


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


def _per_track(tracks: pd.DataFrame, fps: float) -> dict[int, pd.DataFrame]:
    """Each track (>= 3 frames) indexed by frame, with ``seen`` (:func:`observed`) and ``reacquired``."""
    det_frames = _detector_frames(tracks)
    out = {}
    for tid, g in tracks.sort_values("frame").groupby("track_id"):
        g = g.drop_duplicates("frame").set_index("frame")
        if len(g) >= 3:
            out[int(str(tid))] = g.assign(seen=observed(g, det_frames, fps), reacquired=reacquired(g, det_frames, fps))
    return out


def _growth(g: pd.DataFrame, fps: float) -> pd.Series:
    """d ln(box size)/dt (1/s), smoothed over :func:`_smooth_frames`: 1/TTC when the track approaches."""
    w = g["x2"].to_numpy(float) - g["x1"].to_numpy(float)
    h = g["y2"].to_numpy(float) - g["y1"].to_numpy(float)
    dt = np.maximum(np.diff(g.index.to_numpy(float)) / fps, 1e-6)
    r = np.r_[0.0, np.diff(np.log(np.sqrt(np.maximum(w * h, 1.0)))) / dt]
    return pd.Series(r, index=g.index).rolling(_smooth_frames(fps), center=True, min_periods=1).mean()


def _smooth_frames(fps: float) -> int:
    """The odd number of frames nearest to ``SMOOTH_S`` (3 at 10-20 fps, 5 at 30 fps: a clip resampled to 30 fps
    repeats every third frame, its box growth 0 there and double the next; 1 below 6.7 fps: three frames at 5 fps
    span 0.6 s, and the box of a bus cutting in was "near" a frame early, where the camera jolted as it swept the
    view, ccd_001143 at half its frame rate 0.8 s early -> 0.2 s)."""
    return max(1, int(round(SMOOTH_S * fps))) | 1


def _border(width: int) -> float:
    """The margin (px) within which a box edge is on the picture's border (``BORDER_SHARE``)."""
    return BORDER_SHARE * width


def _on_side(g: pd.DataFrame, width: int) -> np.ndarray:
    """Per frame (bool): the box is on the picture's left or right border (within :func:`_border`)."""
    m = _border(width)
    return ((g["x1"] <= m) | (g["x2"] >= width - m)).to_numpy(bool)


def _motion_change(g: pd.DataFrame, width: int, fps: float) -> pd.Series:
    """0..1 per frame: a sudden change of the box centre's velocity (:data:`CHANGE_SPAN_S` before against
    after, in box widths per second, at least :data:`CHANGE_MIN_WIDTH` of the image), full at
    :data:`CHANGE_FULL` and held :data:`CHANGE_HOLD_S` either side; none within a span of either end of the
    track, where a track coasting on its prediction is detected again (``reacquired``), or where the picture's
    left or right side cuts the box (:func:`_on_side`)."""
    t = g.index.to_numpy(float) / fps
    cx = ((g["x1"] + g["x2"]) / 2).to_numpy(float)
    cy = ((g["y1"] + g["y2"]) / 2).to_numpy(float)
    w = np.maximum((g["x2"] - g["x1"]).to_numpy(float), CHANGE_MIN_WIDTH * width)
    tau = CHANGE_SPAN_S
    a = np.zeros(len(g))
    inside = (t - tau >= t[0] - 1e-9) & (t + tau <= t[-1] + 1e-9) & (t > t[0]) & (t < t[-1])
    if inside.any():
        d2 = [np.interp(t + tau, t, c) - 2 * c + np.interp(t - tau, t, c) for c in (cx, cy)]
        a = np.where(inside, np.hypot(*d2) / tau / w, 0.0)  # velocity change, widths/s
    quiet = _on_side(g, width)  # a box cut by the picture's side: its centre moves as it is cut, not with it
    if "reacquired" in g.columns:  # the tracker correcting its prediction, not the road user's motion
        quiet |= g["reacquired"].to_numpy(bool)
    if quiet.any():
        a[np.abs(t[:, None] - t[quiet][None, :]).min(axis=1) <= max(tau, 1 / fps) + 1e-9] = 0.0
    hold = 2 * int(round(CHANGE_HOLD_S * fps)) + 1
    return pd.Series(np.clip(a / CHANGE_FULL, 0, 1), index=g.index).rolling(hold, center=True, min_periods=1).max()


def ego_scores(
    g: pd.DataFrame, width: int, height: int, fps: float, jolt: dict[int, float], clip_end: int | None = None
) -> pd.DataFrame:
    """Per frame of one track: near (wide box reaching the image bottom), closing (box growth), jolt,
    and whether it is ahead (its box over the image's centre column) or leaves the view at the side
    (:func:`_exits`; ``clip_end``: the clip's last frame)."""
    x1, y1, x2, y2 = (g[c].to_numpy(float) for c in ("x1", "y1", "x2", "y2"))
    size = np.log(np.sqrt(np.maximum((x2 - x1) * (y2 - y1), 1.0)))
    wide = np.clip(((x2 - x1) / width - 0.12) / 0.3, 0, 1)
    tall = np.clip(((y2 - y1) / height - 0.35) / 0.4, 0, 1)  # a person or two-wheeler close in front
    raw_near = np.maximum(wide, tall) * np.clip((y2 / height - 0.55) / 0.3, 0, 1)
    near = pd.Series(raw_near, index=g.index).rolling(_smooth_frames(fps), center=True, min_periods=1).max()
    closing = np.clip(_growth(g, fps).to_numpy(), 0, 1.5) / 1.5  # d ln(size)/dt = 1.5/s (TTC 0.67 s) -> 1
    j = pd.Series([jolt.get(int(f), 0.0) for f in g.index.to_numpy(int)], index=g.index)
    edge = _reaches_border(g, width)
    return pd.DataFrame(
        {
            "near": near,
            "closing": closing,
            "jolt": j,
            "log_size": size,
            "reaches_border": edge,
            "exits": _exits(g, width, fps, clip_end),
            "ahead": (g["x1"] <= width / 2) & (g["x2"] >= width / 2),
            "knocked_over": _knocked_over(g, width, height),
        }
    )


def _knocked_over(g: pd.DataFrame, width: int, height: int) -> pd.Series:
    """True at the first frame where a pedestrian's box, upright until then (median height/width at least
    ``UPRIGHT_ASPECT``), turns squat (under ``FALLEN_ASPECT``) while no image border cuts it: the person
    is struck off their feet (ccd_000882: 2.1 -> 1.25 at the contact frame, then on the bonnet). Nothing for
    other road users (a pedestrian hit at the bumper does not jolt the camera)."""
    out = pd.Series(False, index=g.index)
    if "category" not in g.columns or not len(g):
        return out
    if track_category({str(k): float(v) for k, v in g["category"].value_counts().items()}) != "pedestrian":
        return out  # a two-wheeler's riders are detected as people (dad_000487), not knocked over
    w = np.maximum((g["x2"] - g["x1"]).to_numpy(float), 1.0)
    aspect = (g["y2"] - g["y1"]).to_numpy(float) / w
    m = _border(width)
    cut = ((g["x1"] <= m) | (g["x2"] >= width - m) | (g["y1"] <= m) | (g["y2"] >= height - m)).to_numpy()
    for k in range(2, len(g)):
        if aspect[k] < FALLEN_ASPECT and not cut[k] and np.median(aspect[:k]) >= UPRIGHT_ASPECT:
            out.iloc[k] = True
            break
    return out


def _exits(g: pd.DataFrame, width: int, fps: float, clip_end: int | None = None) -> pd.Series:
    """True at the frames after which the road user leaves the view at the image's left or right side
    within ``EXIT_WINDOW_S``: its box is on that border with a visible width under ``EXIT_WIDTH_SHARE`` of
    its width at the frame, or its track ends there before the clip does (``clip_end``: the clip's last
    frame): it drove past the ego, out of the view."""
    f = g.index.to_numpy(int)
    w = (g["x2"] - g["x1"]).to_numpy(float)
    side = _on_side(g, width)
    n = EXIT_WINDOW_S * fps
    gone = bool(side[-1]) and clip_end is not None and f[-1] < clip_end  # the track ends on a side border
    out = np.zeros(len(f), bool)
    for k in range(len(f)):
        later = (f > f[k]) & (f <= f[k] + n) & side
        out[k] = bool(np.any(w[later] < EXIT_WIDTH_SHARE * w[k])) or (gone and f[-1] <= f[k] + n)
    return pd.Series(out, index=g.index)


def _reaches_border(g: pd.DataFrame, width: int) -> pd.Series:
    """True at the frames where the box jumps onto the left, right or top image border (it did not
    reach it in the previous frame, and it grew by more than ``BORDER_JUMP`` in log size into this
    one): the detector's box switched to the road user filling the view. Cut off, the box stops
    growing there, and the road user fills the image on which the camera's motion is measured (a
    "jolt" that is its own motion): a knee or jolt in that frame marks the road user arriving, the
    contact comes a frame later at the earliest (ccd_000014, ccd_001143: 2-3 frames before the label)."""
    m = _border(width)
    at = np.column_stack([g["x1"] <= m, g["x2"] >= width - m, g["y1"] <= m]).astype(bool)
    prev = np.vstack([np.zeros((1, 3), bool), at[:-1]])
    w, h = (g["x2"] - g["x1"]).to_numpy(float), (g["y2"] - g["y1"]).to_numpy(float)
    size = np.log(np.sqrt(np.maximum(w * h, 1.0)))
    jump = np.r_[False, np.diff(size) > BORDER_JUMP]
    return pd.Series((at & ~prev).any(axis=1) & jump, index=g.index)


def knee_frame(s: pd.DataFrame, fps: float) -> int | None:
    """The first frame at which an approaching box stops growing (two frames in a row growing at less
    than a third of its rate over the previous half second, frames repeating the last one left out of
    that rate, and not more than ``KNEE_MAX_LATER_GROWTH``
    in log size over the next half second: a detector's box jumping to a larger one is not it) while it is
    near (at least ``KNEE_MIN_NEAR``, and half its track's nearest, as for a jolt): the other road user is at
    the bumper. Half its nearest: at 5 fps the half second is two frames, and a car still 0.35 near (its
    nearest 1.0) paused its growth for them (ccd_000031 at half its frame rate: the crash put 2.6 s early
    there, scored under the cut, none found)."""
    ls_all = s["log_size"].to_numpy(float)
    at_bumper = max(KNEE_MIN_NEAR, 0.5 * float(s["near"].max()))  # as near as a jolt must be (ego_best)
    # A resampled clip repeats frames (10 -> 30 fps: each one three times) and its boxes with them: the box
    # "stops growing" between any two repeats. Only frames whose box changed count, the half second in them.
    kept = np.r_[True, np.diff(ls_all) != 0.0]
    ls, frames, near = ls_all[kept], s.index.to_numpy()[kept], s["near"].to_numpy(float)[kept]
    g = np.diff(ls)
    n_prev = max(2, int(round(0.5 * fps * len(ls) / max(len(ls_all), 1))))
    for k in range(n_prev, len(g) - 1):
        prev = g[k - n_prev : k]
        changed = prev[prev != 0.0]  # a resampled clip repeats frames: no growth there (ccd_000340 at 15 fps)
        rate = float(np.median(changed)) if len(changed) else 0.0
        stays = ls[k + 1 : k + 1 + n_prev].max() - ls[k] < KNEE_MAX_LATER_GROWTH  # not a box jump
        if rate > 0.02 and near[k] >= at_bumper and g[k] < rate / 3 and g[k + 1] < rate / 3 and stays:
            return int(frames[k])
    return None


def _approaching_after(s: pd.DataFrame, fps: float) -> pd.Series:
    """True at the frames after which the box still grows by more than ``APPROACH_AFTER_GROWTH`` in log size
    within ``APPROACH_AFTER_S`` (at least the next frame): the road user is still approaching, not in contact."""
    idx = s.index.to_numpy()
    ls = s["log_size"].to_numpy(float)
    span = max(APPROACH_AFTER_S * fps, 1.0)
    out = np.zeros(len(idx), bool)
    for k in range(len(idx)):
        later = ls[k + 1 : int(np.searchsorted(idx, idx[k] + span, side="right"))]
        out[k] = len(later) > 0 and float(later.max()) - ls[k] > APPROACH_AFTER_GROWTH
    return pd.Series(out, index=s.index)


def _still_since(s: pd.DataFrame, jolt_frame: int, fps: float) -> int | None:
    """The frame from which the road user's box has been at the bumper without growing (near, and growing
    by less than ``KNEE_MAX_LATER_GROWTH`` in log size over the next 0.5 s) up to the jolt at
    ``jolt_frame``, when that lasted at least ``STILL_BEFORE_JOLT_S``; else None. The jolt then is the
    road user pushed on or spun after the contact (ccd_000755: the car struck at frame 21, at the bumper
    from 23, the camera jolts at 33), and the contact is where the box stopped growing."""
    idx = s.index.to_numpy()
    ls = s["log_size"].to_numpy(float)
    near = (s["near"] >= 0.5 * float(s["near"].max())).to_numpy()
    n = max(2, int(round(0.5 * fps)))
    k = int(np.searchsorted(idx, jolt_frame)) - 1
    start = None
    while k >= 0 and near[k] and ls[k + 1 : k + 1 + n].max(initial=ls[k]) - ls[k] < KNEE_MAX_LATER_GROWTH:
        start = k
        k -= 1
    if start is None or (jolt_frame - idx[start]) / fps < STILL_BEFORE_JOLT_S:
        return None
    return int(idx[start])


def ego_best(s: pd.DataFrame, fps: float) -> tuple[float, int, dict[str, float]]:
    """The ego-crash score of one track and its contact frame: the first camera jolt while the track is
    near, else the first frame at which the track is nearest (its box stops growing at contact)."""
    peak = float(s["near"].max())
    if peak <= 0:
        return 0.0, int(s.index.to_numpy()[0]), {}
    near_enough = s["near"] >= 0.5 * peak
    jolted = s.index.to_numpy()[(near_enough & (s["jolt"] >= 0.3) & ~_approaching_after(s, fps)).to_numpy()]
    knee = knee_frame(s, fps)
    if len(jolted):
        frame = int(jolted[0])
    elif knee is not None:
        frame = knee
    else:
        frame = int(s.index.to_numpy()[int(np.argmax(s["near"].to_numpy() >= 0.9 * peak))])
    before = s[(s.index <= frame) & (s.index >= frame - fps)]
    closing = float(before["closing"].max()) if len(before) else 0.0
    jolt = float(s["jolt"].to_numpy()[s.index.to_numpy() == frame][0])
    score = (
        peak * (0.45 + 0.3 * closing + 0.25 * jolt) if not len(jolted) else peak * (0.5 + 0.35 * jolt + 0.15 * closing)
    )
    score *= min(1.0, (closing + jolt) / EGO_MIN_EVIDENCE)  # near all along (the bonnet, a queue): no crash
    if "exits" in s and bool(s.loc[frame, "exits"]) and not (near_enough & s["ahead"])[before.index].any():
        score *= jolt  # it drove on out of the view past the ego: only a jolt says it touched on the way
    ev = {"near": round(peak, 3), "closing": round(closing, 3), "jolt": round(jolt, 3), "score": round(score, 3)}
    still = _still_since(s, frame, fps) if len(jolted) else None
    if still is not None:  # the jolt is the crash going on: scored as it is, the contact is earlier
        ev["jolt_frame"], frame = frame, still
    elif len(jolted):  # scored where the jolt starts, the contact where it peaks
        frame = _jolt_peak(s, frame, near_enough)
    jolt_at = frame if len(jolted) and still is None else None
    fallen = s["knocked_over"] if "knocked_over" in s else pd.Series(False, index=s.index)
    fell = s.index.to_numpy()[(fallen & near_enough).to_numpy()]
    if len(fell) and int(fell[0]) < frame:  # a pedestrian struck off their feet: contact before knee or jolt
        ev["later_frame"], frame = frame, int(fell[0])
    if frame == jolt_at and "reaches_border" in s:
        nxt = _next_new_frame(s, frame)
        if nxt in s.index and bool(s.loc[nxt, "reaches_border"]):
            frame = nxt  # the jolt's second difference holds the next frame's shift: the box jumping onto the border
    if "reaches_border" in s and bool(s.loc[frame, "reaches_border"]):
        frame = _next_new_frame(s, frame)  # the box jumped onto the border there: filling the view, not touching
    return score, frame, ev


def _jolt_peak(s: pd.DataFrame, first: int, near: pd.Series) -> int:
    """The contact of a camera jolt that starts at ``first`` while the road user's box still grows fast (``closing``
    at least ``JOLT_RISE_CLOSING``): the frame where the jolt peaks (on while the next frame jolts more, the road
    user near). A box growing fast fills more of the view each frame and moves the image the jolt is measured
    on: the jolt rises with it before the impact (ccd_000330 at 5 fps: 0.31 / 0.59 / 1.0 at frames 16-18, the box
    growing until 19, the contact at 19). A box that has stopped growing is at the bumper: the jolt's first frame
    is the contact (ccd_000487: 0.94 then 1.0, the contact at the first)."""
    idx = s.index.to_numpy()
    jolt, closing = s["jolt"].to_numpy(float), s["closing"].to_numpy(float)
    k = int(np.searchsorted(idx, first))
    while k + 1 < len(idx) and closing[k] >= JOLT_RISE_CLOSING and jolt[k + 1] > jolt[k] and bool(near.iloc[k + 1]):
        k += 1
    return int(idx[k])


def _next_new_frame(s: pd.DataFrame, frame: int) -> int:
    """The next frame after ``frame`` whose box differs from it (``log_size``): the next frame of the video,
    or of a resampled clip the next one that is no repeat of it; ``frame + 1`` at the track's end."""
    idx = s.index.to_numpy()
    ls = s["log_size"].to_numpy(float)
    later = np.flatnonzero((idx > frame) & (ls != ls[int(np.searchsorted(idx, frame))]))
    return int(idx[later[0]]) if len(later) else frame + 1


def _extended(w: WorldTrack, frames: float) -> WorldTrack:
    """``w`` carried ``frames`` frames before its first and after its last position at its constant
    velocity there (over its first/last few positions), its heading held."""
    f, x, y = w.frames, w.x, w.y
    yaw = None if w.yaw is None else np.r_[w.yaw[0], w.yaw, w.yaw[-1]]
    if len(f) < 2:
        return WorldTrack(
            np.r_[f[0] - frames, f, f[-1] + frames],
            np.r_[x[0], x, x[-1]],
            np.r_[y[0], y, y[-1]],
            w.half_width,
            w.half_length,
            yaw,
        )
    k = min(len(f) - 1, 4)
    v0 = np.array([x[k] - x[0], y[k] - y[0]]) / max(f[k] - f[0], 1e-6)
    v1 = np.array([x[-1] - x[-1 - k], y[-1] - y[-1 - k]]) / max(f[-1] - f[-1 - k], 1e-6)
    return WorldTrack(
        np.r_[f[0] - frames, f, f[-1] + frames],
        np.r_[x[0] - v0[0] * frames, x, x[-1] + v1[0] * frames],
        np.r_[y[0] - v0[1] * frames, y, y[-1] + v1[1] * frames],
        w.half_width,
        w.half_length,
        yaw,
    )


def _footprint(w: WorldTrack, grid: np.ndarray) -> np.ndarray | None:
    """The road user's ground rectangle at the frames ``grid``: corners (N, 4, 2) world x, y (m); None
    without a half length and headings."""
    if w.half_length is None or w.yaw is None:
        return None
    x, y, yaw = (np.interp(grid, w.frames, v) for v in (w.x, w.y, w.yaw))
    dx = np.array([1.0, -1.0, -1.0, 1.0]) * w.half_length
    dy = np.array([1.0, 1.0, -1.0, -1.0]) * w.half_width
    c, s = np.cos(yaw)[:, None], np.sin(yaw)[:, None]
    return np.stack([x[:, None] + c * dx - s * dy, y[:, None] + s * dx + c * dy], axis=-1)


def _vertex_edge_gap(p: np.ndarray, q: np.ndarray) -> np.ndarray:
    """Per frame the least distance (m) from a corner of rectangles ``p`` to an edge of ``q`` (N, 4, 2)."""
    a, b = q[:, None, :, :], np.roll(q, -1, axis=1)[:, None, :, :]
    v = p[:, :, None, :]
    ab = b - a
    t = np.clip(((v - a) * ab).sum(-1) / np.maximum((ab * ab).sum(-1), 1e-12), 0, 1)
    return np.linalg.norm(v - (a + t[..., None] * ab), axis=-1).min(axis=(1, 2))


def rect_gap(p: np.ndarray, q: np.ndarray) -> np.ndarray:
    """Per frame the ground gap (m) between two rectangles (corners (N, 4, 2)): 0 where they overlap
    (no separating axis among their edges' directions), else the least corner-to-edge distance."""
    separated = np.zeros(len(p), bool)
    for r in (p, q):
        for k in (0, 1):
            axis = r[:, k + 1] - r[:, k]
            pa, pb = (np.einsum("nij,nj->ni", z, axis) for z in (p, q))
            separated |= (pa.max(1) < pb.min(1)) | (pb.max(1) < pa.min(1))
    return np.where(separated, np.minimum(_vertex_edge_gap(p, q), _vertex_edge_gap(q, p)), 0.0)


def close_3d(a: WorldTrack, b: WorldTrack, frames: np.ndarray, fps: float) -> np.ndarray:
    """0..1 per frame: 1 when the two road users' ground gap (m) was 0 at some time in the last
    ``CLOSE_3D_WINDOW_S``, 0 from ``CLOSE_3D_M`` on. Each is carried at constant velocity for
    ``CLOSE_3D_HOLD_S`` beyond its 3D positions (a road user at the contact is often partly hidden
    and no longer placed in 3D); NaN where unknown."""
    hold = CLOSE_3D_HOLD_S * fps
    a, b = _extended(a, hold), _extended(b, hold)
    lo = max(a.frames[0], b.frames[0])
    hi = min(a.frames[-1], b.frames[-1])
    if hi < lo or not len(frames):
        return np.full(len(frames), np.nan)
    grid = np.arange(np.ceil(lo), np.floor(hi) + 1)
    fa, fb = _footprint(a, grid), _footprint(b, grid)
    if fa is not None and fb is not None:
        ground = rect_gap(fa, fb)  # a two-wheeler at a car's rear is half the car's length from its centre
    else:
        d = np.hypot(
            np.interp(grid, a.frames, a.x) - np.interp(grid, b.frames, b.x),
            np.interp(grid, a.frames, a.y) - np.interp(grid, b.frames, b.y),
        )
        ground = np.maximum(d - a.half_width - b.half_width, 0.0)
    gap = pd.Series(ground, index=grid.astype(int))
    k = max(1, int(round(CLOSE_3D_WINDOW_S * fps)))
    gap = gap.rolling(k + 1, min_periods=1).min()
    g = gap.reindex(frames.astype(int)).to_numpy(float)
    return np.clip(1 - g / CLOSE_3D_M, 0, 1)


def pair_scores(
    a: pd.DataFrame,
    b: pd.DataFrame,
    width: int,
    height: int,
    world: tuple[WorldTrack, WorldTrack] | None = None,
    fps: float = 10.0,
    entered: bool = False,
    scene: dict[int, tuple[np.ndarray, np.ndarray]] | None = None,
) -> pd.DataFrame:
    """Per common frame of two tracks: contact in the image, close in 3D (or a similar ground row),
    motion change, onset (apart before; ``entered``: one of them came into the view during the clip at
    its border, :func:`entered_view`), both seen by the detector (a track's ``seen`` column, 0..1, from
    :func:`observed`; 1 without it), not hidden behind a nearer road user (``scene``: every box per frame,
    :func:`hidden_behind`)."""
    common = a.index.intersection(b.index)
    if not len(common):
        return pd.DataFrame(columns=["touch", "depth", "change", "onset", "seen", "score"])
    seen = np.minimum(_seen(a).loc[common].to_numpy(), _seen(b).loc[common].to_numpy())
    a, b = a.loc[common], b.loc[common]
    ix = np.minimum(a["x2"], b["x2"]) - np.maximum(a["x1"], b["x1"])
    iy = np.minimum(a["y2"], b["y2"]) - np.maximum(a["y1"], b["y1"])
    scale = np.minimum(a["x2"] - a["x1"], b["x2"] - b["x1"])
    least = MIN_BOX_SHARE * width
    touch = np.clip(1 + np.minimum(ix, iy) / np.maximum(scale, least) / 0.15, 0, 1) * (iy > 0)
    hb = np.maximum(np.maximum(a["y2"] - a["y1"], b["y2"] - b["y1"]), least)
    rows = np.clip(1 - np.abs(a["y2"].to_numpy(float) - b["y2"].to_numpy(float)) / np.asarray(hb, float) / 0.35, 0, 1)
    near3 = close_3d(*world, common.to_numpy(), fps) if world is not None else np.full(len(common), np.nan)
    depth = pd.Series(np.where(np.isfinite(near3), near3, rows), index=common)
    changes = [_motion_change(t, width, fps).to_numpy() for t in (a, b)]
    change = pd.Series(np.maximum(*changes), common)
    onset = _onset(pd.Series(np.asarray(touch, float), index=common), fps, entered)
    score = touch * depth * (0.2 + 0.8 * change) * onset * seen
    hidden = hidden_behind(a, b, scene, np.asarray(score, float) > 0) if scene is not None else np.zeros(len(common))
    score = score * (1 - hidden)
    return pd.DataFrame(
        {
            "touch": touch,
            "depth": depth,
            "change": change,
            "onset": onset,
            "seen": seen,
            "hidden": hidden,
            "score": score,
        }
    )


def scene_boxes(tracks: pd.DataFrame) -> dict[int, tuple[np.ndarray, np.ndarray]]:
    """Every track's box per frame: frame -> (track ids (N,), boxes (N, 4) px ``x1, y1, x2, y2``)."""
    f = tracks["frame"].to_numpy(int)
    ids = tracks["track_id"].to_numpy(int)
    boxes = tracks[["x1", "y1", "x2", "y2"]].to_numpy(float)
    order = np.argsort(f, kind="stable")
    cuts = np.flatnonzero(np.diff(f[order])) + 1
    return {int(f[k[0]]): (ids[k], boxes[k]) for k in np.split(order, cuts) if len(k)}


def hidden_behind(
    a: pd.DataFrame, b: pd.DataFrame, scene: dict[int, tuple[np.ndarray, np.ndarray]], where: np.ndarray
) -> np.ndarray:
    """0..1 per frame of ``a`` and ``b`` (same frames): how much the pair's joint box lies inside the box
    of a third, nearer road user (its bottom lower in the image), ``HIDDEN_FROM`` -> 0, ``HIDDEN_FULL``
    -> 1; only at the frames in ``where`` (else 0)."""
    out = np.zeros(len(a))
    pair = (int(a["track_id"].iloc[0]), int(b["track_id"].iloc[0]))
    frames = a.index.to_numpy(int)
    ba, bb = (t[["x1", "y1", "x2", "y2"]].to_numpy(float) for t in (a, b))
    for k in np.flatnonzero(where):
        ids, o = scene.get(int(frames[k]), (np.zeros(0, int), np.zeros((0, 4))))
        ux1, uy1 = np.minimum(ba[k, :2], bb[k, :2])
        ux2, uy2 = np.maximum(ba[k, 2:], bb[k, 2:])
        o = o[(ids != pair[0]) & (ids != pair[1]) & (o[:, 3] > uy2)]
        if not len(o):
            continue
        iw = np.clip(np.minimum(o[:, 2], ux2) - np.maximum(o[:, 0], ux1), 0, None)
        ih = np.clip(np.minimum(o[:, 3], uy2) - np.maximum(o[:, 1], uy1), 0, None)
        share = float((iw * ih).max()) / max((ux2 - ux1) * (uy2 - uy1), 1.0)
        out[k] = np.clip((share - HIDDEN_FROM) / (HIDDEN_FULL - HIDDEN_FROM), 0, 1)
    return out


def _seen(g: pd.DataFrame) -> pd.Series:
    return g["seen"] if "seen" in g.columns else pd.Series(1.0, index=g.index)


def entered_view(g: pd.DataFrame, width: int, height: int, first_frame: int) -> bool:
    """Whether the track came into the view during the clip (it starts after ``first_frame``) with its
    first box on the left, right or bottom image border: before, it was apart from everything in view."""
    x1, x2, y2 = (float(g[c].iloc[0]) for c in ("x1", "x2", "y2"))
    m = _border(width)
    at_border = x1 <= m or x2 >= width - m or y2 >= height - m
    return bool(int(g.index[0]) > first_frame and at_border)


def _onset(touch: pd.Series, fps: float, entered: bool = False) -> pd.Series:
    """0..1 per frame: how much of the previous ``ONSET_WINDOW_S`` the two boxes were apart (touch < 0.5;
    frames without both tracks do not count as apart: the pair must be seen apart first, unless one of
    them ``entered`` the view at its border), saturating at ``ONSET_APART``: a contact starts at a moment;
    boxes overlapping all along are one road user seen behind the other."""
    frames = touch.index.to_numpy(int)
    n = max(2, int(round(ONSET_WINDOW_S * fps)))
    full = touch.reindex(np.arange(frames.min() - n, frames.max() + 1)).fillna(0.0 if entered else 1.0)
    apart = (full < 0.5).astype(float).rolling(n, min_periods=1).mean().shift(1).fillna(0.0)
    return pd.Series(np.clip(apart.reindex(frames).to_numpy() / ONSET_APART, 0, 1), index=touch.index)


Candidate = tuple[float, int, tuple[int, int], dict[str, float]]  # (score, contact frame, pair, evidence)


def detect_crash(
    tracks: pd.DataFrame,
    width: int,
    height: int,
    fps: float,
    motion: tuple[np.ndarray, np.ndarray] | None = None,
    min_score: float = 0.35,
    allowed: set[int] | None = None,
    frames: tuple[int, int] | None = None,
    world: dict[int, WorldTrack] | None = None,
    picture: tuple[int, int, int, int] | None = None,
) -> CrashFinding | None:
    """The most likely crash (module docstring), or None. ``motion`` = (frames, shifts) of
    :class:`GlobalMotion`; only tracks in ``allowed`` (if given) and frames in ``frames`` (inclusive);
    ``world``: ground positions per track id (close in 3D; a pair without them uses the image rows);
    ``picture``: the picture ``(x0, y0, x1, y1)`` (px) inside black bars (:func:`in_picture`)."""
    cands = crash_candidates(tracks, width, height, fps, motion, allowed, frames, world, picture)
    if not cands:
        return None
    score, frame, pair, ev = cands[0]
    if score < min_score:
        return None
    return CrashFinding(frame, frame / fps, pair, float(np.clip(score, 0, 1)), ev)


def crash_candidates(
    tracks: pd.DataFrame,
    width: int,
    height: int,
    fps: float,
    motion: tuple[np.ndarray, np.ndarray] | None = None,
    allowed: set[int] | None = None,
    frames: tuple[int, int] | None = None,
    world: dict[int, WorldTrack] | None = None,
    picture: tuple[int, int, int, int] | None = None,
) -> list[Candidate]:
    """Every candidate crash (each ego + track and each pair of tracks at its best frame), best first
    (arguments as :func:`detect_crash`)."""
    tracks, width, height = in_picture(tracks, width, height, picture)
    per = {k: g for k, g in _per_track(tracks, fps).items() if allowed is None or k in allowed}
    clip_end = int(tracks["frame"].max()) if len(tracks) else None
    scene = scene_boxes(tracks)
    jolt = jolt_score(*motion, fps) if motion is not None else {}
    lo, hi = frames if frames is not None else (-(10**9), 10**9)
    cands: list[Candidate] = []
    for tid, g in per.items():
        s = ego_scores(g, width, height, fps, jolt, clip_end)
        s = s[(s.index >= lo) & (s.index <= hi)]
        if len(s):
            score, frame, ev = ego_best(s, fps)
            cands.append((score, frame, (EGO, tid), ev))
    ego_near = max((_at_bumper(c[3]) * min(1.0, c[0] / EGO_CREDIBLE) for c in cands), default=0.0)
    ids = sorted(per)
    cats = _categories(tracks)
    first = int(tracks["frame"].min()) if len(tracks) else 0
    world = {k: _ground_seen(w, per.get(k), width, height) for k, w in (world or {}).items()}
    span = {k: (int(g.index.min()), int(g.index.max())) for k, g in per.items() if len(g)}
    came_in = {k: entered_view(g, width, height, first) for k, g in per.items()}
    for i, ta in enumerate(ids):
        for tb in ids[i + 1 :]:
            if cats.get(ta) == cats.get(tb) == "pedestrian":
                continue
            if ta not in span or tb not in span or span[ta][1] < span[tb][0] or span[tb][1] < span[ta][0]:
                continue  # never in view together (a long recording's road users mostly are not)
            wpair = (world[ta], world[tb]) if ta in world and tb in world else None
            entered = came_in[ta] or came_in[tb]
            s = pair_scores(per[ta], per[tb], width, height, wpair, fps, entered, scene)
            s = s[(s.index >= lo) & (s.index <= hi)]
            if len(s):  # something at the ego's bumper makes an ego crash the likelier one
                score, frame, pair, ev = _best(s, (ta, tb), fps)
                cands.append((score * (1 - 0.5 * ego_near), frame, pair, ev))
    return ranked(cands)


def ranked(cands: list[Candidate]) -> list[Candidate]:
    """The candidates best first: by score (an ego crash first on an exact tie), and when the best is a
    pair of road users, the pair whose evidence holds longest after its contact (``hold``) first among
    the pairs within :data:`TIE_MARGIN` of it."""
    order = sorted(cands, key=lambda c: -c[0])
    if not order or EGO in order[0][2]:
        return order
    near = [c for c in order if EGO not in c[2] and c[0] >= order[0][0] - TIE_MARGIN]
    top = max(near, key=lambda c: (c[3].get("hold", 0.0), c[0]))
    return [top] + [c for c in order if c is not top]


def _ground_seen(w: WorldTrack, g: pd.DataFrame | None, width: int, height: int) -> WorldTrack:
    """``w`` as a disc of its half width (no footprint) when its box is cut by the image's bottom in most
    of its frames: where it meets the ground is not seen, so neither its distance nor its heading is (the
    ego's own bonnet detected as a "car", dad_000512: its 4.4 m footprint turned across reached the
    scooters' crash)."""
    if g is None or float((g["y2"] >= height - _border(width)).mean()) <= 0.5:
        return w
    return WorldTrack(w.frames, w.x, w.y, w.half_width)


def in_picture(
    tracks: pd.DataFrame, width: int, height: int, picture: tuple[int, int, int, int] | None
) -> tuple[pd.DataFrame, int, int]:
    """The tracks' boxes in the coordinates of the picture ``(x0, y0, x1, y1)`` (px) inside black bars,
    and the picture's width and height (px), each box clipped to the picture: every image share (near,
    wide, tall), border and row test is the picture's, not the frame's, and a box the tracker's optical
    flow carried into a bar is cut at the picture's edge (letterboxed ccd_000132: the car's box at the
    bumper jumping between the picture's bottom and 40 px into the bar hid where it stopped growing, the
    crash found 0.6 s late). Unchanged without ``picture`` or when it is the whole frame."""
    if picture is None or tuple(picture) == (0, 0, width, height):
        return tracks, width, height
    x0, y0, x1, y1 = (int(v) for v in picture)
    w, h = x1 - x0, y1 - y0
    x = {c: (tracks[c] - x0).clip(0, w) for c in ("x1", "x2")}
    y = {c: (tracks[c] - y0).clip(0, h) for c in ("y1", "y2")}
    return tracks.assign(**x, **y), w, h


def _at_bumper(ev: dict[str, float]) -> float:
    """How surely a road user is at the ego's bumper (0..1): near, with approach or jolt evidence (a box
    near all along without either is the ego's bonnet or a queue: ``EGO_MIN_EVIDENCE``)."""
    return ev.get("near", 0.0) * min(1.0, (ev.get("closing", 0.0) + ev.get("jolt", 0.0)) / EGO_MIN_EVIDENCE)


def _categories(tracks: pd.DataFrame) -> dict[int, str]:
    """Each track's most frequent category (empty without a ``category`` column)."""
    if "category" not in tracks.columns or not len(tracks):
        return {}
    top = tracks.groupby("track_id")["category"].agg(lambda c: c.value_counts().index[0])
    return {int(str(k)): str(v) for k, v in top.items()}


def _best(s: pd.DataFrame, pair: tuple[int, int], fps: float) -> tuple[float, int, tuple[int, int], dict[str, float]]:
    """The pair's peak score and its contact frame: the first frame reaching ``PAIR_PEAK_SHARE`` of the
    peak, or a new rise of the motion change soon after it (:func:`_contact_index`); its evidence there,
    with ``hold``: the mean score over ``CONTACT_HOLD_S`` from the first frame reaching the peak share on (a
    frame without both tracks counts 0)."""
    peak = float(s["score"].max())
    idx = s.index.to_numpy()
    k = int(np.argmax(s["score"].to_numpy() >= PAIR_PEAK_SHARE * peak)) if peak > 0 else 0
    first = int(idx[k])
    k = _contact_index(s, k, peak, fps)
    frame = int(idx[k])
    ev = {str(c): round(float(s[c].to_numpy()[k]), 3) for c in s.columns}
    after = np.arange(first, first + max(1, int(round(CONTACT_HOLD_S * fps))))
    ev["hold"] = round(float(s["score"].reindex(after).fillna(0.0).mean()), 3)
    return peak, frame, pair, ev


def _contact_index(s: pd.DataFrame, k: int, peak: float, fps: float) -> int:
    """The row of a pair's contact given ``k``, the first row reaching its peak share: the first later row
    within ``NEW_CHANGE_WINDOW_S`` (s) where the motion change rises by ``NEW_CHANGE_RISE`` over its least
    since ``k`` (:func:`_motion_rise`), or ``k`` when there is none."""
    frames = s.index.to_numpy(float)
    held = (s["touch"] * s["depth"] * s["onset"]).to_numpy(float)
    strong = s["score"].to_numpy(float) >= NEW_CHANGE_SCORE * peak
    change = s["change"].to_numpy(float)
    for j in range(k + 1, len(s)):
        if frames[j] - frames[k] > NEW_CHANGE_WINDOW_S * fps + 1e-9 or held[j] < NEW_CHANGE_HELD * held[k]:
            break
        if strong[j] and _motion_rise(change[k : j + 1]):
            return j
    return k


def _motion_rise(change: np.ndarray) -> bool:
    """Whether the last of a run of motion-change values (0..1) exceeds the least before it by
    ``NEW_CHANGE_RISE``."""
    return bool(change[-1] - change[:-1].min() >= NEW_CHANGE_RISE)
