"""Evidence of a crash between two road users, per frame (:mod:`deepcrashtest.perception.crash_detect`): their boxes
touch in the image, they are close on the ground (3D footprints, ``WorldTrack``; else bottoms at a similar row), one
changes motion suddenly and the offset between them with it (a change both share is the view's), they were apart
before (the onset), both were seen by the detector and neither is hidden inside a nearer road user's box; and the
pair's contact frame (its score's peak, or a new rise of the motion change on a plateau)."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import pandas as pd

from deepcrashtest.perception.crash_tracks import MIN_BOX_SHARE, border_margin, motion_change

#: A pair's contact must follow a time apart: the share of the previous ONSET_WINDOW_S (s) with the boxes
#: apart, saturating at ONSET_APART (chosen on dad_000478 and the highway clip: image overlap all along).
ONSET_WINDOW_S = 1.0


ONSET_APART = 0.3


#: A pair's contact frame is the first frame whose score reaches this share of its peak (0.9 -> 0.97 on
#: dad_000550: 0.35 s early -> on the label; dad_000478 unchanged).
PAIR_PEAK_SHARE = 0.97


#: A pair's ``hold``: its mean score over this long (s) from its contact on, by which
#: :func:`~deepcrashtest.perception.crash_detect.ranked` orders near-ties (its ``TIE_MARGIN``).
CONTACT_HOLD_S = 0.3


#: A pair's ``touching_s``: how long (s) its boxes had touched and its footprints been close (image contact x
#: closeness >= TOUCHING_HELD, consecutive frames) up to its contact frame. Two road users that collide change
#: their motion as they meet; a road user that passes in front of another overlaps it for a while first (its motion
#: changing later, for another reason): :func:`~deepcrashtest.perception.crash_detect.ranked` keeps, of near-tied
#: pairs, those touching within ``crash_detect.TOUCHING_MARGIN_S`` of the freshest contact.
TOUCHING_HELD = 0.5


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


#: A pair whose boxes lie inside a nearer road user's box (its bottom lower in the image) is hidden behind
#: it or part of it (a rider, a passenger): no discount while less than HIDDEN_FROM of the pair's joint box
#: lies inside, none of its score left from HIDDEN_FULL on (chosen on dad_000487: a rider and a car behind
#: the ego's scooter, both inside its box, their boxes jittering as it passes).
HIDDEN_FROM = 0.5


HIDDEN_FULL = 0.9


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
    motion change (the larger of the two boxes' own, no more than that of the offset between them: two parked cars
    passed in a row speed up across the view together), onset (apart before; ``entered``: one of them came into the
    view during the clip at its border, :func:`entered_view`), both seen by the detector (a track's ``seen`` column,
    0..1, from :func:`.crash_tracks.observed`; 1 without it), not hidden behind a nearer road user (``scene``: every
    box per frame, :func:`hidden_behind`)."""
    common = a.index.intersection(b.index)
    if not len(common):
        return pd.DataFrame(columns=["touch", "depth", "change", "onset", "seen", "score"])
    a, b = a.loc[common], b.loc[common]
    ix = np.minimum(a["x2"], b["x2"]) - np.maximum(a["x1"], b["x1"])
    iy = np.minimum(a["y2"], b["y2"]) - np.maximum(a["y1"], b["y1"])
    scale = np.minimum(a["x2"] - a["x1"], b["x2"] - b["x1"])
    least = MIN_BOX_SHARE * width
    touch = np.clip(1 + np.minimum(ix, iy) / np.maximum(scale, least) / 0.15, 0, 1) * (iy > 0)
    if not np.any(np.asarray(touch, float) > 0):  # the boxes never meet: no score on any frame (most pairs of a
        return _never_touching(common)  # busy street), and none of the costlier cues is needed
    seen = np.minimum(_seen(a).to_numpy(), _seen(b).to_numpy())
    hb = np.maximum(np.maximum(a["y2"] - a["y1"], b["y2"] - b["y1"]), least)
    rows = np.clip(1 - np.abs(a["y2"].to_numpy(float) - b["y2"].to_numpy(float)) / np.asarray(hb, float) / 0.35, 0, 1)
    near3 = close_3d(*world, common.to_numpy(), fps) if world is not None else np.full(len(common), np.nan)
    depth = pd.Series(np.where(np.isfinite(near3), near3, rows), index=common)
    changes = [motion_change(t, width, fps).to_numpy() for t in (a, b)]
    change = pd.Series(np.minimum(np.maximum(*changes), motion_change(a, width, fps, b).to_numpy()), common)
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


def _never_touching(common: pd.Index) -> pd.DataFrame:
    """:func:`pair_scores`' table for two road users whose boxes never meet in the image: every score 0 (its contact,
    :func:`pair_contact`, their first common frame). Their closeness, motion change and onset are not computed: on
    dad_000487 (29 tracks) 102 of its 114 pairs, ~70 % of the crash detection's CPU."""
    zero = np.zeros(len(common))
    cols = ("touch", "depth", "change", "onset", "seen", "hidden", "score")
    return pd.DataFrame({c: zero for c in cols}, index=common)


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
    m = border_margin(width)
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


def ground_seen(w: WorldTrack, g: pd.DataFrame | None, width: int, height: int) -> WorldTrack:
    """``w`` as a disc of its half width (no footprint) when its box is cut by the image's bottom in most
    of its frames: where it meets the ground is not seen, so neither its distance nor its heading is (the
    ego's own bonnet detected as a "car", dad_000512: its 4.4 m footprint turned across reached the
    scooters' crash)."""
    if g is None or float((g["y2"] >= height - border_margin(width)).mean()) <= 0.5:
        return w
    return WorldTrack(w.frames, w.x, w.y, w.half_width)


def pair_contact(
    s: pd.DataFrame, pair: tuple[int, int], fps: float
) -> tuple[float, int, tuple[int, int], dict[str, float]]:
    """The pair's peak score and its contact frame: the first frame reaching ``PAIR_PEAK_SHARE`` of the
    peak, or a new rise of the motion change soon after it (:func:`_contact_index`); its evidence there,
    with ``hold``: the mean score over ``CONTACT_HOLD_S`` from the first frame reaching the peak share on (a
    frame without both tracks counts 0), and ``touching_s`` (:func:`_touching_frames`, in seconds)."""
    peak = float(s["score"].max())
    idx = s.index.to_numpy()
    k = int(np.argmax(s["score"].to_numpy() >= PAIR_PEAK_SHARE * peak)) if peak > 0 else 0
    first = int(idx[k])
    k = _contact_index(s, k, peak, fps)
    frame = int(idx[k])
    ev = {str(c): round(float(s[c].to_numpy()[k]), 3) for c in s.columns}
    after = np.arange(first, first + max(1, int(round(CONTACT_HOLD_S * fps))))
    ev["hold"] = round(float(s["score"].reindex(after).fillna(0.0).mean()), 3)
    ev["touching_s"] = round(_touching_frames(s, k) / fps, 3)
    return peak, frame, pair, ev


def _touching_frames(s: pd.DataFrame, k: int) -> int:
    """How many frames before row ``k`` the pair had touched and been close without a break (image contact x
    closeness >= ``TOUCHING_HELD`` on consecutive frames)."""
    held = (s["touch"] * s["depth"]).to_numpy(float) >= TOUCHING_HELD
    frames = s.index.to_numpy(int)
    j = k
    while j > 0 and held[j - 1] and frames[j - 1] == frames[j] - 1:
        j -= 1
    return int(frames[k] - frames[j])


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
