"""Camera-frame tracks + ego motion (+ lanes) -> a raw Scenario in the world frame.

Input contract (``tracks``, one row per track per frame): ``frame`` (int), ``time`` (s),
``track_id`` (int >= 1), ``category`` (car|truck|bus|motorcycle|bicycle|pedestrian), ``x1, y1, x2, y2``
(px, full frame), ``score``, ``state`` ('detected'|'predicted').

World frame (``deepcrashtest.scenario``): origin at the ego centre at the first frame, x forward,
y left, metres. The camera sits ``camera.forward_offset_m`` ahead of the ego centre.

By default the tracks go through the monocular 3D tracker of :mod:`deepcrashtest.geometry.mono3d`
(depth cues fused per frame with one size per track, a constant-velocity Kalman filter and smoother
in the ground plane). With an explicit ``localizer`` (e.g. a depth map's), each box is placed by it
in the camera frame of its frame, moved into the world frame with that frame's ego pose, and
smoothed per track (Savitzky-Golay over ~1 s); speeds are then the time derivative, headings follow
the smoothed motion (and the ego's heading, turned by 90 deg for side-on boxes, when nearly static).
"""

from __future__ import annotations

import dataclasses
import math
from collections import Counter
from collections.abc import Mapping
from typing import Any

import numpy as np
import pandas as pd
from scipy.signal import savgol_filter

from deepcrashtest.errors import UserError
from deepcrashtest.geometry.attitude import camera_wobble
from deepcrashtest.geometry.box_heading import fit_box_headings
from deepcrashtest.geometry.camera import undistorted_tracks
from deepcrashtest.geometry.ego_parts import ego_part_tracks
from deepcrashtest.geometry.egomotion import EgoMotion
from deepcrashtest.geometry.localize import Localizer
from deepcrashtest.geometry.mono3d import localize_tracks
from deepcrashtest.geometry.mono_config import MonoConfig
from deepcrashtest.perception.lanes import LaneTimelineResult
from deepcrashtest.perception.roadusers import track_category
from deepcrashtest.scenario import (
    MAX_SPEED_MPS,
    Camera,
    CameraAttitude,
    LaneTimeline,
    Provenance,
    Road,
    Scenario,
    Trajectory,
    Vehicle,
    VideoSource,
)

FRAME_RATE_NOTE = (
    "Uploaded videos may have altered frame rates (re-encoding, speed-up, dropped frames): absolute "
    "speeds scale with the true frame rate; the relative speed trends between vehicles are what the "
    "extraction must get right."
)
TRACK_COLUMNS = ("frame", "time", "track_id", "category", "x1", "y1", "x2", "y2", "score", "state")
EGO_SIZE = (4.5, 1.8, 1.5)  # length, width, height of the (unknown) ego car, metres
STATIC_SPEED_MPS = 1.0
#: Lane offsets may replace the ego's lateral drift only when the corrected path stays drivable with the
#: camera's measured heading: RMS speed sideways (across that heading) at most this, m/s. Chosen on the DAD
#: and highway clips: consistent corrections measured 0.03-0.14, lane-detector noise 0.8-1.4 (a car
#: sliding sideways at walking pace while the camera looks straight ahead).
MAX_SIDEWAYS_MPS = 0.3


def _video_source(meta: VideoSource | Mapping[str, Any]) -> VideoSource:
    if isinstance(meta, VideoSource):
        src = meta
    else:
        keys = {k: meta[k] for k in ("path", "fps", "frame_count", "width", "height", "frame_times") if k in meta}
        try:
            src = VideoSource(kind=meta.get("kind", "video"), sha256=meta.get("sha256"), **keys)
        except Exception as exc:  # pydantic error -> one line
            raise UserError(f"video metadata incomplete: {exc}") from None
    return src.model_copy(update={"frame_rate_note": FRAME_RATE_NOTE})


def _smooth(t: np.ndarray, v: np.ndarray, window_s: float = 1.0) -> np.ndarray:
    """Savitzky-Golay smoothing (quadratic) over about ``window_s`` seconds; short series unchanged."""
    n = len(v)
    if n < 5:
        return v.astype(float)
    dt = float(np.median(np.diff(t))) if n > 1 else 1.0
    win = int(round(window_s / max(dt, 1e-3))) | 1
    win = max(5, min(win, n if n % 2 else n - 1))
    return np.asarray(savgol_filter(v, win, 2), dtype=float)


def _heading(t: np.ndarray, x: np.ndarray, y: np.ndarray, fallback: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(yaw, speed) from smoothed positions; where slow, the fallback yaw."""
    if len(t) < 2:
        return fallback.copy(), np.zeros_like(t)
    vx, vy = np.gradient(x, t), np.gradient(y, t)
    speed = np.hypot(vx, vy)
    yaw = np.where(speed > STATIC_SPEED_MPS, np.arctan2(vy, vx), fallback)
    return np.unwrap(yaw), speed


def corrected_ego_path(ego: EgoMotion, lanes: LaneTimelineResult | None, warnings: list[str]) -> np.ndarray:
    """Camera path (N, 2) with its lateral drift replaced by the lane offsets where lanes were seen.

    Lateral position relative to the starting lane: ``offset(t) - offset(0) + (lane(t) - lane(0)) * width``
    (y left). Applied when the lanes were found in >= 30 % of frames and the road stays within
    15 deg of the initial heading (a straight-road assumption), interpolated across gaps.
    """
    xy = np.column_stack([ego.x, ego.y])
    if lanes is None or len(lanes.t) == 0:
        return xy
    both = lanes.both_found
    if both.mean() < 0.3:
        return xy
    if np.abs(ego.yaw).max() > math.radians(15):
        warnings.append("lanes: the road turns; ego lateral drift not corrected by lane offsets")
        return xy
    width = float(np.nanmedian(lanes.lane_width[both]))
    lat = lanes.lateral_offset + (lanes.lane_index - lanes.lane_index[both][0]) * width
    lat_t = lanes.t[both]
    lat_v = lat[both] - lat[both][0]
    y_lane = np.interp(ego.t, lat_t, _smooth(lat_t, lat_v, 0.5))
    corrected = xy.copy()
    corrected[:, 1] = y_lane
    side = sideways_speed(ego.t, corrected, ego.yaw)
    if side > MAX_SIDEWAYS_MPS:
        warnings.append(
            f"lanes: the lane offsets would move the ego sideways at {side:.1f} m/s RMS across its measured heading "
            "(lane-detector noise); ego lateral drift not corrected by lane offsets"
        )
        return xy
    return corrected


def sideways_speed(t: np.ndarray, xy: np.ndarray, yaw: np.ndarray) -> float:
    """RMS speed (m/s) of a path ``xy`` (N, 2) across the heading ``yaw`` (N,): ~0 for a car that drives
    where it points."""
    if len(t) < 2:
        return 0.0
    vx, vy = np.gradient(xy[:, 0], t), np.gradient(xy[:, 1], t)
    return float(np.sqrt(np.mean((-np.sin(yaw) * vx + np.cos(yaw) * vy) ** 2)))


def raw_scenario_from_tracks(
    tracks: pd.DataFrame,
    meta: VideoSource | Mapping[str, Any],
    camera: Camera,
    ego: EgoMotion,
    lanes: LaneTimelineResult | None = None,
    localizer: Localizer | None = None,
    name: str = "scenario",
    seed: int = 0,
    mono: MonoConfig | None = None,
    horizon_v: float | None = None,
    min_detected: int = 1,
    min_confidence: float = 0.0,
) -> Scenario:
    """Build the raw (``stage="raw"``) Scenario: ego from ego-motion, agents from localised tracks.

    ``localizer`` None: the monocular 3D tracker (``mono`` its settings, ``horizon_v`` the horizon
    row, else the camera's pitch gives it); tracks detected in fewer than ``min_detected`` frames
    are left out, and those whose detections score ``min_confidence`` or less on average."""
    missing = [c for c in TRACK_COLUMNS if c not in tracks.columns and c not in ("score", "state")]
    if missing:
        raise UserError(f"tracks table misses columns {missing} (expected {list(TRACK_COLUMNS)})")
    if len(ego) < 2:
        raise UserError("ego motion has fewer than 2 frames: the video is too short")
    source = _video_source(meta).model_copy(update={"time_offset_s": -float(ego.t[0])})
    params: dict[str, Any] = {}
    if camera.distortion:  # every box measured in the pinhole image of the camera's intrinsics
        tracks = undistorted_tracks(tracks, camera, (source.width, source.height))
        params["boxes_undistorted"] = True
    warnings = list(ego.warnings) + (list(lanes.warnings) if lanes is not None else [])
    parts = ego_part_tracks(tracks, camera, (source.width, source.height))
    if parts:
        tracks = tracks[~tracks["track_id"].isin(parts)]
        warnings += [
            f"track {k}: a box along the picture's bottom too wide and too low for a road user (the ego's own "
            "bonnet, or a reflection on it, taken for a vehicle); left out"
            for k in parts
        ]

    # ego: camera path -> ego centre (camera forward_offset ahead of the centre)
    cam_xy = corrected_ego_path(ego, lanes, warnings)
    heading = np.column_stack([np.cos(ego.yaw), np.sin(ego.yaw)])
    ego_xy = cam_xy - camera.forward_offset_m * heading
    origin = ego_xy[0].copy()
    ego_xy = ego_xy - origin
    t0 = float(ego.t[0])
    ego_vehicle = Vehicle(
        id=0, category="car", length=EGO_SIZE[0], width=EGO_SIZE[1], height=EGO_SIZE[2],
        first_frame=int(ego.frame[0]), last_frame=int(ego.frame[-1]),
        trajectory=Trajectory.from_arrays(
            ego.t - t0, ego_xy[:, 0], ego_xy[:, 1], ego.yaw, np.clip(ego.speed, 0, MAX_SPEED_MPS), ego.valid
        ),
    )  # fmt: skip
    size = (source.width, source.height)
    if localizer is None:
        path = dataclasses.replace(ego, x=cam_xy[:, 0], y=cam_xy[:, 1])
        wobble = camera_wobble(ego, roll=False)
        pitch_change = None if wobble is None else wobble[:, 0]
        states = localize_tracks(
            tracks, camera, path, size, source.fps, mono, horizon_v, pitch_change, frame_times=source.frame_times
        )
        camera = camera.model_copy(update={"attitude": frame_attitude(states, camera, ego, pitch_change, horizon_v)})
        agents = _mono_agents(states, t0, origin, min_detected, warnings, min_confidence)
        method = "mono3d"
        if camera.attitude is not None:
            extra = " + ego-motion pitch" if wobble is not None else ""
            params["camera_attitude"] = "boxes' per-frame horizon" + extra
    else:
        agents = _localized_agents(tracks, camera, ego, cam_xy, origin, localizer, size, t0, warnings)
        method = type(localizer).__name__
    raw = Scenario(
        name=name, stage="raw", source=source, camera=camera, ego=ego_vehicle, agents=agents,
        road=_road(ego_xy, lanes), warnings=warnings,
        provenance=Provenance(command="extract", parameters={"localizer": method, **params}, seed=seed),
    )  # fmt: skip
    return fit_box_headings(raw, tracks)  # headings that fit the boxes, not only the noisy direction of motion


def frame_attitude(
    states: pd.DataFrame, camera: Camera, ego: EgoMotion, pitch_change: np.ndarray | None, horizon_v: float | None
) -> CameraAttitude | None:
    """The camera's pitch at each of ``ego``'s frames as the localisation read the boxes (the horizon rows of
    :func:`~deepcrashtest.geometry.mono3d.localize_tracks`' ``states``; frames without a box: ``pitch_change``),
    as a change of ``camera.pitch_rad``; None when it never changes (a fixed camera, no per-frame horizon)."""
    vh0 = camera.horizon_v() if horizon_v is None else float(horizon_v)
    pitch = np.full(len(ego.t), math.atan2(camera.cy - vh0, camera.fy))
    if pitch_change is not None:
        pitch = pitch + np.asarray(pitch_change, dtype=float)
    if len(states) and "horizon_v" in states.columns:
        rows = states[np.isfinite(states["horizon_v"].to_numpy(float))]
        per_frame = rows.groupby("frame")["horizon_v"].median()
        at = {int(f): i for i, f in enumerate(ego.frame)}
        for f, v in per_frame.items():
            i = at.get(int(f))  # type: ignore[arg-type]
            if i is not None:
                pitch[i] = math.atan2(camera.cy - float(v), camera.fy)
    change = pitch - camera.pitch_rad
    if len(change) == 0 or float(np.abs(change).max()) < 1e-6:
        return None
    return CameraAttitude(
        video_t=[round(float(v), 6) for v in ego.t],
        pitch_rad=[round(float(v), 5) for v in np.clip(change, -0.5, 0.5)],
        roll_rad=[0.0] * len(change),
    )


def _mono_agents(
    states: pd.DataFrame, t0: float, origin: np.ndarray, min_detected: int, warnings: list[str],
    min_confidence: float = 0.0,
) -> list[Vehicle]:  # fmt: skip
    """Agents from :func:`~deepcrashtest.geometry.mono3d.localize_tracks` states (world = path - origin)."""
    agents: list[Vehicle] = []
    clipped = 0
    for tid, g in states.groupby("track_id", sort=True):
        det = g["detected"].to_numpy(bool)
        if det.sum() < max(min_detected, 1) or len(g) < 2:
            continue
        if min_confidence > 0 and float(g["score"].to_numpy(float)[det].mean()) <= min_confidence:
            continue
        speed = g["speed"].to_numpy(float)
        if speed.max() > MAX_SPEED_MPS:
            clipped += 1
            speed = np.minimum(speed, MAX_SPEED_MPS)
        t = g["time"].to_numpy(float) - t0
        tracked = g["frame"].to_numpy(int)[np.isfinite(g["x1"].to_numpy(float))]  # not the far-track extension
        agents.append(
            Vehicle(
                id=int(tid),  # type: ignore[arg-type]
                category=str(g["category"].iloc[0]),  # type: ignore[arg-type]
                length=float(g["length"].iloc[0]),
                width=float(g["width"].iloc[0]),
                height=float(g["height"].iloc[0]),
                confidence=float(np.clip(g["score"].to_numpy(float)[det].mean(), 0.0, 1.0)),
                first_frame=int(tracked[0]) if len(tracked) else int(g["frame"].iloc[0]),
                last_frame=int(tracked[-1]) if len(tracked) else int(g["frame"].iloc[-1]),
                start_delay_s=max(0.0, float(t[0])),
                trajectory=Trajectory.from_arrays(
                    t,
                    g["x"].to_numpy(float) - origin[0],
                    g["y"].to_numpy(float) - origin[1],
                    g["yaw"].to_numpy(float),
                    speed,
                    det,
                ),
            )  # fmt: skip
        )
    if clipped:
        warnings.append(f"{clipped} agent track(s) had speeds above {MAX_SPEED_MPS} m/s (clipped): localisation noise")
    return agents


def _localized_agents(
    tracks: pd.DataFrame,
    camera: Camera,
    ego: EgoMotion,
    cam_xy: np.ndarray,
    origin: np.ndarray,
    loc: Localizer,
    size: tuple[int, int],
    t0: float,
    warnings: list[str],
) -> list[Vehicle]:
    """Agents placed frame by frame by ``loc`` and smoothed per track (Savitzky-Golay)."""
    frame_to_i = {int(f): i for i, f in enumerate(ego.frame)}
    agents: list[Vehicle] = []
    if not len(tracks):
        return agents
    df = tracks.copy()
    df = df[df["frame"].isin(frame_to_i.keys())].sort_values(["track_id", "frame"])
    if "state" not in df.columns:
        df["state"] = "detected"
    if "score" not in df.columns:
        df["score"] = 1.0
    px = np.full(len(df), np.nan)
    py = np.full(len(df), np.nan)
    dims = np.zeros((len(df), 3))
    for _, grp in df.groupby("frame", sort=False):
        rows = df.index.get_indexer(grp.index)
        p = loc.localize(grp[["x1", "y1", "x2", "y2"]].to_numpy(float), list(grp["category"]), camera, size)
        i = frame_to_i[int(grp["frame"].iloc[0])]
        c, s = math.cos(ego.yaw[i]), math.sin(ego.yaw[i])
        fwd, left = p.z, -p.x
        px[rows] = cam_xy[i, 0] + c * fwd - s * left - origin[0]
        py[rows] = cam_xy[i, 1] + s * fwd + c * left - origin[1]
        dims[rows] = np.column_stack([p.length, p.width, p.height])
        px[rows[~p.valid]] = np.nan
    df["wx"], df["wy"] = px, py
    df["L"], df["W"], df["H"] = dims[:, 0], dims[:, 1], dims[:, 2]
    clipped = 0
    for tid, g in df.groupby("track_id"):
        g = g[np.isfinite(g["wx"])].drop_duplicates("frame")
        if len(g) < 2:
            continue
        t = g["time"].to_numpy(float) - t0
        x = _smooth(t, g["wx"].to_numpy(float))
        y = _smooth(t, g["wy"].to_numpy(float))
        ego_yaw = np.interp(t, ego.t - t0, ego.yaw)
        aspect = ((g["x2"] - g["x1"]) / np.maximum(g["y2"] - g["y1"], 1.0)).to_numpy(float)
        fallback = ego_yaw + np.where(aspect > 2.2, math.pi / 2, 0.0)
        yaw, speed = _heading(t, x, y, fallback)
        cat = track_category(Counter(g["category"].astype(str)))  # the class most frames agree on
        first = g[g["category"] == cat].iloc[0]
        if speed.max() > MAX_SPEED_MPS:
            clipped += 1
            speed = np.minimum(speed, MAX_SPEED_MPS)
        agents.append(
            Vehicle(
                id=int(tid),  # type: ignore[arg-type]
                category=cat,  # type: ignore[arg-type]
                length=float(first["L"]),
                width=float(first["W"]),
                height=float(first["H"]),
                confidence=float(np.clip(g["score"].mean(), 0.0, 1.0)),
                first_frame=int(g["frame"].iloc[0]),
                last_frame=int(g["frame"].iloc[-1]),
                start_delay_s=max(0.0, float(t[0])),
                trajectory=Trajectory.from_arrays(t, x, y, yaw, speed, (g["state"] == "detected").to_numpy()),
            )  # fmt: skip
        )
    if clipped:
        warnings.append(f"{clipped} agent track(s) had speeds above {MAX_SPEED_MPS} m/s (clipped): localisation noise")
    return agents


def _road(ego_xy: np.ndarray, lanes: LaneTimelineResult | None) -> Road:
    """Road along the ego path (or 20 m straight ahead when the ego hardly moves), lanes when seen."""
    step = np.hypot(*np.diff(ego_xy, axis=0).T)
    if step.sum() < 5.0:
        cl = np.array([[0.0, 0.0], [20.0, 0.0]])
    else:
        cum = np.concatenate([[0.0], np.cumsum(step)])
        idx = np.unique(np.concatenate([np.searchsorted(cum, np.arange(0.0, cum[-1], 2.0)), [len(cum) - 1]]))
        cl = ego_xy[idx]
    width, timeline, ego_lane, source = 3.5, None, 0, "ego_path"
    if lanes is not None and lanes.both_found.mean() >= 0.3:
        ok = lanes.both_found
        width = float(np.clip(np.median(lanes.lane_width[ok]), 2.5, 5.0))
        timeline = LaneTimeline(
            t=[float(v) for v in lanes.t[ok] - lanes.t[0]],
            lane_index=[int(v) for v in lanes.lane_index[ok]],
            lateral_offset=[float(v) for v in lanes.lateral_offset[ok]],
        )
        ego_lane = int(lanes.lane_index[ok][0])
        source = "lanes"
    lane_count = max(2, ego_lane + 1, int(lanes.lane_index.max()) + 1 if lanes is not None and len(lanes.t) else 2)
    return Road(
        centerline_x=[float(v) for v in cl[:, 0]], centerline_y=[float(v) for v in cl[:, 1]],
        lane_width=width, lane_count=min(lane_count, 12), ego_lane=ego_lane, source=source,  # type: ignore[arg-type]
        lane_timeline=timeline,
    )  # fmt: skip
