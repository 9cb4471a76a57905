"""Offline pass over the world tracker's tracks, once the whole clip is tracked.

A Scenario is built after the whole video is seen, so its trajectories may use later frames:

1. tracks with fewer than ``min_detections`` detections, or a mean detector score below
   ``min_mean_score`` (None: no limit), are dropped (short-lived false alarms);
2. *extension*: from each end of a track (longest tracks first), frames further out are searched
   for detections the tracker left unused (weaker ones, down to ``extend_min_score``, included) within
   ``gate_m`` of the constant-velocity extrapolation; found ones join the track, and the search stops
   after ``extend_max_gap`` frames without one. This recovers the first frames of a car, before the
   tracker had enough confident detections to start a track;
3. *stitching*: a track that ends and a track that starts at most ``max_gap`` frames later are joined
   when each one's constant-velocity extrapolation (velocity fitted on its ``fit_frames`` nearest
   detections) reaches the other's end within ``gate_m + gate_m_per_s * gap`` metres; the pairs are
   chosen by the Hungarian algorithm on that distance;
4. every track is reported in every frame from its first to its last detection; frames without a
   detection get the linear interpolation of the neighbouring detected boxes (no extrapolation past
   the ends).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.optimize import linear_sum_assignment

from deepcrashtest.datasets.kitti.world_tracker import TrackHistory, WorldDetections


@dataclass(frozen=True)
class OfflineConfig:
    """Settings of the offline pass; frames at ``dt`` seconds, distances metres."""

    dt: float = 0.1
    min_detections: int = 3
    min_mean_score: float | None = None
    max_gap: int = 0
    gate_m: float = 2.0
    gate_m_per_s: float = 0.5
    fit_frames: int = 10
    extend_max_gap: int = 0
    extend_min_score: float | None = None


def _velocity(frames: np.ndarray, xy: np.ndarray, dt: float) -> np.ndarray:
    """Least-squares velocity (m/s) of positions over frames; zero for a single point."""
    if len(frames) < 2:
        return np.zeros(2)
    t = (frames - frames.mean()) * dt
    return (t @ (xy - xy.mean(axis=0))) / max(float(t @ t), 1e-9)


def _stitch(tracks: list[TrackHistory], cfg: OfflineConfig) -> list[TrackHistory]:
    """Join tracks end-to-start (step 2 of the module docstring), repeatedly until nothing joins."""
    if cfg.max_gap <= 0 or len(tracks) < 2:
        return tracks
    while True:
        n = len(tracks)
        cost = np.full((n, n), np.inf)
        for i, a in enumerate(tracks):
            va = _velocity(a.frames[-cfg.fit_frames :], a.boxes[-cfg.fit_frames :, :2], cfg.dt)
            for j, b in enumerate(tracks):
                gap = int(b.frames[0] - a.frames[-1])
                if i == j or gap < 1 or gap > cfg.max_gap:
                    continue
                vb = _velocity(b.frames[: cfg.fit_frames], b.boxes[: cfg.fit_frames, :2], cfg.dt)
                s = gap * cfg.dt
                fwd = np.hypot(*(a.boxes[-1, :2] + va * s - b.boxes[0, :2]))
                back = np.hypot(*(b.boxes[0, :2] - vb * s - a.boxes[-1, :2]))
                d = max(fwd, back)
                if d <= cfg.gate_m + cfg.gate_m_per_s * s:
                    cost[i, j] = d
        if not np.isfinite(cost).any():
            return tracks
        rows, cols = linear_sum_assignment(np.where(np.isfinite(cost), cost, 1e9))
        links = {int(r): int(c) for r, c in zip(rows, cols, strict=True) if np.isfinite(cost[r, c])}
        merged: list[TrackHistory] = []
        absorbed = set(links.values())
        for i, a in enumerate(tracks):
            if i in absorbed:
                continue
            chain = [a]
            k = i
            while k in links:
                k = links[k]
                chain.append(tracks[k])
            merged.append(
                TrackHistory(
                    track_id=a.track_id,
                    frames=np.concatenate([c.frames for c in chain]),
                    boxes=np.concatenate([c.boxes for c in chain]),
                    scores=np.concatenate([c.scores for c in chain]),
                    detections=np.concatenate([c.detections for c in chain]),
                )
            )
        tracks = merged


def _interpolate(track: TrackHistory) -> TrackHistory:
    """Boxes in every frame from the first to the last detection (linear in between)."""
    frames = np.arange(track.frames[0], track.frames[-1] + 1)
    boxes = np.empty((len(frames), 7))
    for k in range(6):
        boxes[:, k] = np.interp(frames, track.frames, track.boxes[:, k])
    boxes[:, 6] = np.interp(frames, track.frames, np.unwrap(track.boxes[:, 6]))
    boxes[:, 6] = (boxes[:, 6] + np.pi) % (2 * np.pi) - np.pi
    scores = np.interp(frames, track.frames, track.scores)
    dets = np.full(len(frames), -1)
    dets[track.frames - frames[0]] = track.detections
    return TrackHistory(track.track_id, frames, boxes, scores, dets)


def _extend(
    track: TrackHistory, detections: list[WorldDetections], claimed: list[set[int]], cfg: OfflineConfig, step: int
) -> TrackHistory:
    """Step 2 of the module docstring at one end (``step`` -1: before the start, +1: after the end)."""
    frames, boxes = list(track.frames), list(track.boxes)
    scores, dets = list(track.scores), list(track.detections)
    end = -1 if step > 0 else 0
    f = int(frames[end])
    last_f = f
    while True:
        f += step
        if not 0 <= f < len(detections) or abs(f - last_f) > cfg.extend_max_gap:
            break
        near = slice(-cfg.fit_frames, None) if step > 0 else slice(0, cfg.fit_frames)
        fr = np.array(frames)[near]
        v = _velocity(fr, np.array(boxes)[near][:, :2], cfg.dt)
        pred = boxes[end][:2] + v * (f - last_f) * cfg.dt
        d = detections[f]
        floor = -np.inf if cfg.extend_min_score is None else cfg.extend_min_score
        cand = [i for i in range(len(d)) if i not in claimed[f] and d.score[i] >= floor]
        if not cand:
            continue
        dist = np.hypot(*(d.xy[cand] - pred).T)
        k = int(np.argmin(dist))
        if dist[k] > cfg.gate_m:
            continue
        i = cand[k]
        claimed[f].add(i)
        box = np.array([*d.xy[i], d.z[i], *d.size[i], d.yaw[i]])
        at = len(frames) if step > 0 else 0
        frames.insert(at, f)
        boxes.insert(at, box)
        scores.insert(at, float(d.score[i]))
        dets.insert(at, i)
        last_f = f
    return TrackHistory(track.track_id, np.array(frames), np.array(boxes), np.array(scores), np.array(dets))


def offline_tracks(
    tracks: list[TrackHistory], cfg: OfflineConfig, detections: list[WorldDetections] | None = None
) -> list[TrackHistory]:
    """Steps 1-4 of the module docstring (step 2 only when the per-frame ``detections`` the
    tracker saw are given); tracks come back ordered by id."""
    kept = [
        t
        for t in tracks
        if len(t.frames) >= cfg.min_detections
        and (cfg.min_mean_score is None or float(np.nanmean(t.scores)) >= cfg.min_mean_score)
    ]
    if detections is not None and cfg.extend_max_gap > 0:
        claimed: list[set[int]] = [set() for _ in detections]
        for t in kept:
            for f, i in zip(t.frames, t.detections, strict=True):
                if i >= 0:
                    claimed[int(f)].add(int(i))
        kept.sort(key=lambda t: -len(t.frames))
        kept = [_extend(_extend(t, detections, claimed, cfg, -1), detections, claimed, cfg, +1) for t in kept]
    kept.sort(key=lambda t: int(t.frames[0]))
    joined = _stitch(kept, cfg)
    return sorted((_interpolate(t) for t in joined), key=lambda t: t.track_id)
