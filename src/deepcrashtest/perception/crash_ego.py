"""Evidence of an ego crash, per track and frame (:mod:`deepcrashtest.perception.crash_detect`): the road user's box
is near (wide, or tall for a person or two-wheeler, its bottom low in the picture), closing fast (its growth) and the
camera jolts; and the contact frame: the first jolt while near (where it peaks while the box still grows fast, or
where the box stopped growing when it had been at the bumper that long), else the knee where the box stops growing,
else its nearest frame; a pedestrian knocked off their feet first. A road user leaving the view at the side soon after
without having been ahead drove past: no crash without a jolt."""

from __future__ import annotations

import numpy as np
import pandas as pd

from deepcrashtest.perception.crash_tracks import border_margin, box_growth, on_side, smooth_frames
from deepcrashtest.perception.roadusers import MOTOR_VEHICLES, track_category

#: A knee (the box stops growing) is one when the box grows less than this (log size) in the next 0.5 s
#: (chosen on dad_000487: a box jump 1.6 s before the contact).
KNEE_MAX_LATER_GROWTH = 0.1


#: ... nor more than this share of what it grew over the half second before at its rate then: a box still growing
#: at half its pace is still approaching, slower (chosen on dad_000487's variants in ``bench/codec_variants.py``, the
#: scooter ahead closing slowly: its box grew 0.10 in the half second after a two-frame pause at frame 83 against
#: 0.2 before, and the contact was put there, 0.7 s before the label; 1/3 and 1/4 gave the same, 1/2 nothing).
KNEE_LATER_SHARE = 1 / 3


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


#: An ego crash needs this much approach (closing) or jolt evidence at full score: a box at the bumper
#: from the start without either is the ego's own bonnet or a queue (dad_000512: the bonnet as a "car").
EGO_MIN_EVIDENCE = 0.3


#: ... and its box's growth is closing in only where the box grew by at least this (log size) in the second before
#: the contact (:func:`_rise`): a box at the bumper from the start whose one visible edge jitters (a tanker beside the
#: ego in a queue, cut by the picture's side and top: 383 -> 498 -> 425 -> 505 px wide, a rise of 0.16) has a growth
#: rate but no approach. The labelled ego crashes of the 20 clips and six variant sets rise by 0.27 and more.
EGO_MIN_RISE = 0.2


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


#: A squat box the track's next detection within this long (s) shows upright again is no fall: a person struck off
#: their feet is not back up a few frames later (dad_000487 cut 1.5 s before its crash: a scooter rider detected as
#: a person, one detection boxed with the scooter, 2.0 -> 1.36 -> 2.0 a quarter second apart, taken for a fall 0.5 s
#: before the contact; ccd_000882's struck woman is next detected 0.6 s later, on the bonnet).
BACK_UP_WITHIN_S = 0.4


#: A squat person box is two people, not one knocked over, where it covers (at least COVERED_SHARE of its area)
#: another person's box standing at the same distance (bottoms within SAME_DEPTH_BOTTOM of the squat box's height,
#: at least SAME_DEPTH_HEIGHT of its height): the detector's one box over two riders of a scooter or two walkers
#: side by side (dad_000487 mirrored, at half size and at half its frame rate: the two riders at the ego's bumper
#: in one box of height/width 1.4, 0.6 s before the contact, each rider's own track inside it; ccd_000882's struck
#: woman, 2.1 -> 1.25, covers no one). Chosen on those four clips' boxes.
COVERED_SHARE = 0.7
SAME_DEPTH_BOTTOM = 0.15
SAME_DEPTH_HEIGHT = 0.6


#: A road user leaving the view at the image's side within EXIT_WINDOW_S (s) after an ego "contact"
#: (its visible width at the border falling below EXIT_WIDTH_SHARE of the width at that frame) without
#: having been ahead (its box over the image's centre column while near, in the second before) drove past
#: the ego; without a camera jolt it is no ego crash (chosen on dad_000487: an oncoming car passing close;
#: dad_000493's scooter, hit while ahead, leaves the view at the side as the ego turns).
EXIT_WINDOW_S = 1.0


#: ... a motor vehicle within VEHICLE_EXIT_WINDOW_S: one the ego strikes jolts the camera and stays near, where a
#: struck pedestrian or rider can be thrown out of the view at the side (ccd_000882 through a longer lens: the struck
#: woman's box on the left border 1.5 s after the contact). KITTI odometry seq00: a car parked at the right, only
#: ever seen cut by the right border as the ego turns past it, grows (the box entering the view) and leaves the
#: view 1.5 s later: an ego crash at 0.48 with the 1 s window.
VEHICLE_EXIT_WINDOW_S = 2.0


EXIT_WIDTH_SHARE = 0.5


def ego_scores(
    g: pd.DataFrame,
    width: int,
    height: int,
    fps: float,
    jolt: dict[int, float],
    clip_end: int | None = None,
    people: pd.DataFrame | None = None,
) -> pd.DataFrame:
    """Per frame of one track: near (wide box reaching the image bottom), closing (box growth), jolt,
    and whether it is ahead (its box over the image's centre column) or leaves the view at the side
    (:func:`_exits`; ``clip_end``: the clip's last frame), or a pedestrian knocked over (:func:`_knocked_over`;
    ``people``: every track's person boxes, ``frame``, ``track_id``, ``x1``..``y2``, px)."""
    x1, y1, x2, y2 = (g[c].to_numpy(float) for c in ("x1", "y1", "x2", "y2"))
    size = np.log(np.sqrt(np.maximum((x2 - x1) * (y2 - y1), 1.0)))
    wide = np.clip(((x2 - x1) / width - 0.12) / 0.3, 0, 1)
    tall = np.clip(((y2 - y1) / height - 0.35) / 0.4, 0, 1)  # a person or two-wheeler close in front
    raw_near = np.maximum(wide, tall) * np.clip((y2 / height - 0.55) / 0.3, 0, 1)
    near = pd.Series(raw_near, index=g.index).rolling(smooth_frames(fps), center=True, min_periods=1).max()
    edge = _reaches_border(g, width)
    growth = box_growth(g, fps, width, height, jumped=_first_jump_onto_border(g, width, edge)).to_numpy()
    closing = np.clip(growth, 0, 1.5) / 1.5  # d ln(size)/dt = 1.5/s (TTC 0.67 s) -> 1
    j = pd.Series([jolt.get(int(f), 0.0) for f in g.index.to_numpy(int)], index=g.index)
    return pd.DataFrame(
        {
            "near": near,
            "closing": closing,
            "jolt": j,
            "log_size": size,
            "reaches_border": edge,
            "spans": pd.Series(_on_border(g, width)[:, :2].all(axis=1), index=g.index),
            "exits": _exits(g, width, fps, clip_end),
            "ahead": (g["x1"] <= width / 2) & (g["x2"] >= width / 2),
            "knocked_over": _knocked_over(g, width, height, people),
        }
    )


def _knocked_over(g: pd.DataFrame, width: int, height: int, people: pd.DataFrame | None = None) -> pd.Series:
    """True at the first frame where a pedestrian's box, upright until then (median height/width at least
    ``UPRIGHT_ASPECT``), turns squat (under ``FALLEN_ASPECT``) while no image border cuts it and it covers no other
    person standing at its distance (:func:`_covers_a_person`, ``people`` as :func:`ego_scores`'): the person
    is struck off their feet (ccd_000882: 2.1 -> 1.25 at the contact frame, then on the bonnet). Nothing for
    other road users (a pedestrian hit at the bumper does not jolt the camera)."""
    out = pd.Series(False, index=g.index)
    if _category(g) != "pedestrian":
        return out  # a two-wheeler's riders are detected as people (dad_000487), not knocked over
    w = np.maximum((g["x2"] - g["x1"]).to_numpy(float), 1.0)
    aspect = (g["y2"] - g["y1"]).to_numpy(float) / w
    m = border_margin(width)
    cut = ((g["x1"] <= m) | (g["x2"] >= width - m) | (g["y1"] <= m) | (g["y2"] >= height - m)).to_numpy()
    for k in range(2, len(g)):
        if aspect[k] < FALLEN_ASPECT and not cut[k] and np.median(aspect[:k]) >= UPRIGHT_ASPECT:
            if _covers_a_person(g.iloc[k], int(g.index[k]), people) or _back_up(g, aspect, k):
                continue
            out.iloc[k] = True
            break
    return out


def _back_up(g: pd.DataFrame, aspect: np.ndarray, k: int) -> bool:
    """Whether the track's next detection after row ``k`` (``state``; every later row without the column) comes
    within ``BACK_UP_WITHIN_S`` (``time``, s) and shows the box upright (``UPRIGHT_ASPECT``) again."""
    if "time" not in g.columns:
        return False
    later = np.arange(k + 1, len(g))
    if "state" in g.columns:
        later = later[(g["state"].to_numpy()[later] == "detected")]
    if not len(later):
        return False
    nxt = int(later[0])
    soon = float(g["time"].iloc[nxt]) - float(g["time"].iloc[k]) <= BACK_UP_WITHIN_S + 1e-9
    return soon and aspect[nxt] >= UPRIGHT_ASPECT


def _category(g: pd.DataFrame) -> str | None:
    """The track's class from its rows' ``category`` votes (None without the column or rows)."""
    if "category" not in g.columns or not len(g):
        return None
    return track_category({str(k): float(v) for k, v in g["category"].value_counts().items()})


def _covers_a_person(box: pd.Series, frame: int, people: pd.DataFrame | None) -> bool:
    """Whether the person box ``box`` (``track_id``, ``x1``..``y2``, px) at ``frame`` covers another track's person
    box standing at its distance (``COVERED_SHARE``, ``SAME_DEPTH_BOTTOM``, ``SAME_DEPTH_HEIGHT``)."""
    if people is None or not len(people):
        return False
    o = people[(people["frame"] == frame) & (people["track_id"] != box["track_id"])]
    if not len(o):
        return False
    x1, y1, x2, y2 = (float(box[c]) for c in ("x1", "y1", "x2", "y2"))
    ox1, oy1, ox2, oy2 = (o[c].to_numpy(float) for c in ("x1", "y1", "x2", "y2"))
    inter = np.clip(np.minimum(ox2, x2) - np.maximum(ox1, x1), 0, None) * np.clip(
        np.minimum(oy2, y2) - np.maximum(oy1, y1), 0, None
    )
    area = np.maximum((ox2 - ox1) * (oy2 - oy1), 1.0)
    h = max(y2 - y1, 1.0)
    same_depth = (np.abs(oy2 - y2) <= SAME_DEPTH_BOTTOM * h) & (oy2 - oy1 >= SAME_DEPTH_HEIGHT * h)
    return bool(np.any((inter >= COVERED_SHARE * area) & same_depth))


def _exits(g: pd.DataFrame, width: int, fps: float, clip_end: int | None = None) -> pd.Series:
    """True at the frames after which the road user leaves the view at the image's left or right side
    within ``EXIT_WINDOW_S`` (a motor vehicle within ``VEHICLE_EXIT_WINDOW_S``): its box is on that border with a
    visible width under ``EXIT_WIDTH_SHARE`` of its width at the frame, or its track ends there before the clip does
    (``clip_end``: the clip's last frame): it drove past the ego, out of the view."""
    f = g.index.to_numpy(int)
    w = (g["x2"] - g["x1"]).to_numpy(float)
    side = on_side(g, width)
    n = (VEHICLE_EXIT_WINDOW_S if _category(g) in MOTOR_VEHICLES else EXIT_WINDOW_S) * fps
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
    at = _on_border(g, width)
    prev = np.vstack([np.zeros((1, 3), bool), at[:-1]])
    w, h = (g["x2"] - g["x1"]).to_numpy(float), (g["y2"] - g["y1"]).to_numpy(float)
    size = np.log(np.sqrt(np.maximum(w * h, 1.0)))
    jump = np.r_[False, np.diff(size) > BORDER_JUMP]
    return pd.Series((at & ~prev).any(axis=1) & jump, index=g.index)


def _first_jump_onto_border(g: pd.DataFrame, width: int, edge: pd.Series) -> np.ndarray:
    """Per frame (bool): the box jumps onto the left, right or top border (``edge``, :func:`_reaches_border`) for the
    first time in its track. The detector's box switched there to something larger (a truck and the tanker beside
    it in one box, KITTI's stop-and-go highway queue: 240 -> 480 px wide in one frame, a false ego crash at 0.75);
    that step's growth is no approach. A box that has been on the border before and comes back to it with a
    detection grows there by what the carried boxes between missed (ccd_000340 through a longer lens)."""
    before = np.r_[False, np.cumsum(_on_border(g, width).any(axis=1))[:-1] > 0]
    return edge.to_numpy(bool) & ~before


def _on_border(g: pd.DataFrame, width: int) -> np.ndarray:
    """(frames, 3) bool: the box's left side on the left border, its right side on the right, its top on the top."""
    m = border_margin(width)
    return np.column_stack([g["x1"] <= m, g["x2"] >= width - m, g["y1"] <= m]).astype(bool)


def knee_frame(s: pd.DataFrame, fps: float) -> int | None:
    """The first frame at which an approaching box stops growing (two frames in a row growing at less
    than a third of its rate over the previous half second, frames repeating the last one left out of
    that rate, and not more than ``KNEE_MAX_LATER_GROWTH`` in log size over the next half second, a detector's box
    jumping to a larger one being no knee, nor more than ``KNEE_LATER_SHARE`` of the half second's growth at that
    rate: a box growing on slower is still approaching) while it is
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
        limit = min(KNEE_MAX_LATER_GROWTH, KNEE_LATER_SHARE * rate * n_prev)  # not a box jump, not slower growth
        stays = ls[k + 1 : k + 1 + n_prev].max() - ls[k] < limit
        if rate > 0.02 and near[k] >= at_bumper and g[k] < rate / 3 and g[k + 1] < rate / 3 and stays:
            return int(frames[k])
    return None


NEAREST_WITHIN_S = 0.5
"""Without a jolt or a knee a crash is scored at the track's first frame at least 0.9 of its nearest, and its contact
is where its box is largest within this (s) after that frame (the ``near`` cue, a rolling maximum over the box's
bottom row and width, reaches 0.9 of its peak while the box still grows: dad_000487 re-encoded, the scooter at the
ego's bumper, scored at frame 92, its box largest at 94, the label 97; chosen on the six variant sets: the
re-encoded dad_000487 reproduced, no crash lost on the 20 clips or the 42 robust variants)."""


def _largest_soon_after(s: pd.DataFrame, first: int, fps: float) -> int:
    """The frame of the largest box (``log_size``) from ``first`` to ``NEAREST_WITHIN_S`` after it."""
    idx = s.index.to_numpy()
    win = (idx >= first) & (idx <= first + NEAREST_WITHIN_S * fps)
    return int(idx[win][int(np.argmax(s["log_size"].to_numpy(float)[win]))])


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
    if "spans" in s:  # a box across the whole width cannot widen: its standing still is not seen
        near &= ~s["spans"].to_numpy(bool)
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
    near, else the knee where its box stops growing (:func:`knee_frame`), else the frame where its box is largest
    soon after it is first nearly its nearest (:func:`_largest_soon_after`; the contact)."""
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
    closing = float(before["closing"].max()) if len(before) and _rise(before) >= EGO_MIN_RISE else 0.0
    jolt = float(s["jolt"].to_numpy()[s.index.to_numpy() == frame][0])
    score = (
        peak * (0.45 + 0.3 * closing + 0.25 * jolt) if not len(jolted) else peak * (0.5 + 0.35 * jolt + 0.15 * closing)
    )
    score *= min(1.0, (closing + jolt) / EGO_MIN_EVIDENCE)  # near all along (the bonnet, a queue): no crash
    fallen = s["knocked_over"] if "knocked_over" in s else pd.Series(False, index=s.index)
    fell = s.index.to_numpy()[(fallen & near_enough).to_numpy()]
    passed = "exits" in s and bool(s.loc[frame, "exits"]) and not (near_enough & s["ahead"])[before.index].any()
    if passed and not len(fell):  # a pedestrian knocked off their feet at the bumper did not walk past
        score *= jolt  # it drove on out of the view past the ego: only a jolt says it touched on the way
    ev = {"near": round(peak, 3), "closing": round(closing, 3), "jolt": round(jolt, 3), "score": round(score, 3)}
    still = _still_since(s, frame, fps) if len(jolted) else None
    if still is not None:  # the jolt is the crash going on: scored as it is, the contact is earlier
        ev["jolt_frame"], frame = frame, still
    elif len(jolted):  # scored where the jolt starts, the contact where it peaks
        frame = _jolt_peak(s, frame, near_enough)
    elif knee is None:  # scored where it is first that near, the contact where its box is largest soon after
        frame = _largest_soon_after(s, frame, fps)
    jolt_at = frame if len(jolted) and still is None else None
    if len(fell) and int(fell[0]) < frame:  # a pedestrian struck off their feet: contact before knee or jolt
        ev["later_frame"], frame = frame, int(fell[0])
    if frame == jolt_at and "reaches_border" in s:
        nxt = _next_new_frame(s, frame)
        if nxt in s.index and bool(s.loc[nxt, "reaches_border"]):
            frame = nxt  # the jolt's second difference holds the next frame's shift: the box jumping onto the border
    if "reaches_border" in s and bool(s.loc[frame, "reaches_border"]):
        frame = _next_new_frame(s, frame)  # the box jumped onto the border there: filling the view, not touching
    return score, frame, ev


def _rise(s: pd.DataFrame) -> float:
    """The most the box grew (``log_size``) from any frame of ``s`` to a later one."""
    ls = s["log_size"].to_numpy(float)
    return float(np.max(ls - np.minimum.accumulate(ls))) if len(ls) else 0.0


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


def at_bumper(ev: dict[str, float]) -> float:
    """How surely a road user is at the ego's bumper (0..1): near, with approach or jolt evidence (a box
    near all along without either is the ego's bonnet or a queue: ``EGO_MIN_EVIDENCE``)."""
    return ev.get("near", 0.0) * min(1.0, (ev.get("closing", 0.0) + ev.get("jolt", 0.0)) / EGO_MIN_EVIDENCE)
