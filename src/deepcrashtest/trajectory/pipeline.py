"""Stage 2: a raw Scenario (world-frame tracks) -> a processed, simulation-ready Scenario.

Steps (times in seconds, world frame in metres):

1. Smooth every observed track (Savitzky-Golay + two-level spline, ``trajectory.smoothing``).
2. Road frame from the ego's smoothed path (``trajectory.roadframe``); classify every agent
   (``trajectory.classify``); parked/static agents are held at their mean smoothed position with
   their box heading for the whole scenario (they were there before and after they were seen,
   so they get no start delay).
3. Extrapolate (``trajectory.extrapolate``): D0T2 before it appears; agents that leave the view
   along the road to the end; agents first seen a few frames late back to the start.
   D0T3/D1T3/D1T4 start late: ``start_delay_s == trajectory.t[0]``.
4. Step-back (``trajectory.stepback``): vehicles present at the start are led from rest to their
   first observed state, reached at ``t_max``; the video part is shifted by ``t_max``
   (``provenance.parameters["t_max_s"]``).
5. Collision: the raw scenario's (time shifted) or the first ego-agent box overlap after t_max;
   every trajectory ends there (the simulator's physics takes over).
6. Each vehicle's final path is fitted with one spline (``Vehicle.spline``, x(t), y(t)); the
   samples (t, x, y, yaw, speed) are that spline and its derivative at the sample times, with
   ``observed`` false on extrapolated and stepped-back samples.
7. Road (``trajectory.road``).

Time: the raw ego's first sample is video time 0; scenario time = video time + t_max.
Input rules: the raw scenario must be ``stage="raw"`` with a finite positive fps and finite
samples; the ego needs >= 2 samples; agent tracks shorter than ``min_track_samples`` or starting
after the end (or the collision) are dropped with a warning in ``Scenario.warnings``.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field, replace

import numpy as np

from deepcrashtest.errors import UserError
from deepcrashtest.scenario import (
    MAX_ACCEL_MPS2,
    MAX_SPEED_MPS,
    Collision,
    LaneTimeline,
    Provenance,
    Road,
    Scenario,
    Trajectory,
    Vehicle,
)
from deepcrashtest.trajectory.classify import (
    ClassFeatures,
    circular_mean,
    is_oncoming,
    is_static,
    trajectory_class,
)
from deepcrashtest.trajectory.collision import BoxTrack, Contact, first_contact
from deepcrashtest.trajectory.extrapolate import continue_after, continue_before, overtaker_relative_station
from deepcrashtest.trajectory.params import Stage2Params
from deepcrashtest.trajectory.road import along_road, build_road, extend_head_on
from deepcrashtest.trajectory.roadframe import RoadFrame
from deepcrashtest.trajectory.smoothing import eval_xy, fit_xy_spline, smooth_track, spline_params
from deepcrashtest.trajectory.stepback import plan_step_back, step_back_prefix

_EPS_T = 1e-3  # seconds: samples closer than this are merged
_MOVING_MPS = 0.3  # below this speed the heading is taken from the neighbouring samples


@dataclass
class _Dense:
    """One vehicle's positions on the common time grid (video time, later scenario time)."""

    vehicle: Vehicle
    t: np.ndarray
    xy: np.ndarray
    observed: np.ndarray
    heading: float  # fallback heading (radians): box yaw of static agents, travel direction otherwise
    cls: str | None = None
    static: bool = False
    lateral_m: float = 0.0
    feats: ClassFeatures | None = None
    rel_t: np.ndarray = field(default_factory=lambda: np.zeros(0))  # video time, s
    rel_s: np.ndarray = field(default_factory=lambda: np.zeros(0))  # station minus the ego's, m

    def reclassify(self, t_end_video: float, overtake_entry_gap_m: float) -> None:
        """An agent the ego hits has not been passed: "passed" only counts up to the collision."""
        if self.feats is None:
            return
        passed = bool((self.rel_s[self.rel_t <= t_end_video + _EPS_T] < 0).any())
        self.feats = replace(self.feats, passed=passed)
        self.cls = trajectory_class(self.feats, overtake_entry_gap_m)

    def box_track(self) -> BoxTrack:
        return BoxTrack(self.t, self.xy[:, 0], self.xy[:, 1], headings(self.t, self.xy, self.heading), *self._size())

    def _size(self) -> tuple[float, float]:
        return self.vehicle.length, self.vehicle.width

    def cut(self, t_end: float) -> None:
        """Keep samples up to ``t_end`` (adding one exactly at ``t_end`` by interpolation)."""
        keep = self.t < t_end - _EPS_T
        if self.t[-1] >= t_end - _EPS_T:
            end = np.array([[np.interp(t_end, self.t, self.xy[:, 0]), np.interp(t_end, self.t, self.xy[:, 1])]])
            obs_end = bool(self.observed[min(int(np.searchsorted(self.t, t_end)), len(self.t) - 1)])
            self.t = np.append(self.t[keep], t_end)
            self.xy = np.vstack([self.xy[keep], end])
            self.observed = np.append(self.observed[keep], obs_end)


def headings(t: np.ndarray, xy: np.ndarray, fallback: float, vel: np.ndarray | None = None) -> np.ndarray:
    """Unwrapped heading (radians) of the motion; where slower than 0.3 m/s, the nearest moving sample's
    heading (``fallback`` if it never moves)."""
    if vel is None:
        vel = np.column_stack([np.gradient(xy[:, 0], t), np.gradient(xy[:, 1], t)]) if len(t) > 1 else np.zeros((1, 2))
    moving = np.hypot(vel[:, 0], vel[:, 1]) > _MOVING_MPS
    if not moving.any():
        return np.full(len(t), fallback)
    yaw = np.unwrap(np.arctan2(vel[moving, 1], vel[moving, 0]))
    idx = np.nonzero(moving)[0]
    nearest = idx[np.clip(np.searchsorted(idx, np.arange(len(t))), 0, len(idx) - 1)]
    prev = idx[np.clip(np.searchsorted(idx, np.arange(len(t))) - 1, 0, len(idx) - 1)]
    pick = np.where(np.abs(prev - np.arange(len(t))) < np.abs(nearest - np.arange(len(t))), prev, nearest)
    out = yaw[np.searchsorted(idx, pick)]
    return np.unwrap(out)


def _span(grid: np.ndarray, a: float, b: float) -> np.ndarray:
    """Times from ``a`` to ``b`` inclusive: both ends plus the grid points strictly between."""
    inner = grid[(grid > a + _EPS_T) & (grid < b - _EPS_T)]
    return np.unique(np.concatenate([[a], inner, [b]])) if b > a + _EPS_T else np.array([a])


def _check_raw(raw: Scenario) -> None:
    if raw.stage != "raw":
        raise UserError(f"scenario {raw.name!r} is already processed (stage={raw.stage}); stage 2 needs a raw one")
    fps = raw.source.fps
    if not (isinstance(fps, int | float) and math.isfinite(fps) and fps > 0):
        raise UserError(f"source.fps must be a finite number > 0 to turn frames into seconds (got {fps})")
    for v in raw.vehicles():
        label = "ego" if v is raw.ego else f"agent {v.id}"
        a = v.trajectory.arrays()
        if not all(np.all(np.isfinite(col)) for col in a.values()):
            raise UserError(f"{label}: trajectory contains non-finite numbers (NaN/inf)")
    if len(raw.ego.trajectory) < 2:
        raise UserError(f"ego trajectory has {len(raw.ego.trajectory)} sample; stage 2 needs at least 2")


def process_scenario(raw: Scenario, seed: int = 0, params: Stage2Params | None = None) -> Scenario:
    """Stage 2 (see the module docstring). Deterministic: ``seed`` is recorded, nothing is random."""
    p = params or Stage2Params()
    _check_raw(raw)
    fps = float(raw.source.fps)
    dt = 1.0 / fps
    warnings = list(raw.warnings)
    t0 = float(raw.ego.trajectory.t[0])

    # ---- ego, end time, road frame
    e = raw.ego.trajectory.arrays()
    ego_t = e["t"] - t0
    t_end = float(ego_t[-1])
    if raw.collision is not None:
        tc = raw.collision.time_s - t0
        if not 0 < tc <= t_end + _EPS_T:
            raise UserError(f"collision.time_s {raw.collision.time_s} is outside the ego's trajectory")
        t_end = min(tc, t_end)
    grid = _span(dt * np.arange(int(np.floor(t_end / dt + 1e-6)) + 1), 0.0, t_end)
    ego_sm = smooth_track(ego_t, e["x"], e["y"], fps, p)
    ego_xy = ego_sm.pos(grid)
    ego_vel = ego_sm.vel(grid)
    ego_heading0 = headings(grid, ego_xy, float(e["yaw"][0]), ego_vel)[0]
    frame = RoadFrame.from_path(ego_xy, p.road_sigma_m, heading=ego_heading0)
    s_ego = frame.project(ego_xy)[0]
    v_ego_road = np.gradient(s_ego, grid) if len(grid) > 1 else np.zeros(1)
    ego_speed = np.hypot(ego_vel[:, 0], ego_vel[:, 1])

    def ego_speed_at(tt: np.ndarray) -> np.ndarray:
        return np.interp(tt, grid, ego_speed)

    ego_dense = _Dense(raw.ego, grid, ego_xy, np.ones(len(grid), bool), ego_heading0)
    ego_box = ego_dense.box_track()

    # ---- agents: smooth, classify, extrapolate (video time)
    dense: list[_Dense] = []
    for agent in raw.agents:
        d = _agent_dense(agent, t0, t_end, grid, fps, frame, s_ego, v_ego_road, ego_speed_at, ego_box, p, warnings)
        if d is not None:
            dense.append(d)

    # ---- step-back
    present = [ego_dense] + [d for d in dense if d.t[0] <= _EPS_T]
    v0 = np.array([_first_speed(d) for d in present])
    plan = plan_step_back(v0, p.stepback_accel_mps2)
    t_max = plan.t_max
    n_pre = int(np.ceil(t_max / dt - 1e-9)) if t_max > 0 else 0
    t_pre = t_max - dt * np.arange(n_pre, 0, -1)
    t_pre = np.concatenate([[0.0], t_pre[t_pre > _EPS_T]]) if t_max > 0 else np.zeros(0)
    for d in [ego_dense, *dense]:
        d.t = d.t + t_max
    for d, v in zip(present, v0, strict=True):
        if t_pre.size:
            heading = headings(d.t[:3], d.xy[:3], d.heading)[0] if v > _MOVING_MPS else d.heading
            prefix = step_back_prefix(d.xy[0], heading, float(v), plan, t_pre)
            d.t = np.concatenate([t_pre, d.t])
            d.xy = np.vstack([prefix, d.xy])
            d.observed = np.concatenate([np.zeros(len(t_pre), bool), d.observed])

    # ---- collision and the end of every trajectory
    collision = _collision(raw, ego_dense, dense, t0, t_max)
    if collision is not None:
        for d in [ego_dense, *dense]:
            d.cut(collision.time_s)
            d.reclassify(collision.time_s - t_max, p.overtake_entry_gap_m)
        late = [d for d in dense if d.t[0] >= collision.time_s - _EPS_T]
        for d in late:
            warnings.append(f"agent {d.vehicle.id}: appears after the collision; dropped")
        dense = [d for d in dense if d not in late]
    short = [d for d in dense if len(d.t) < 2]
    for d in short:
        warnings.append(f"agent {d.vehicle.id}: fewer than 2 samples after processing; dropped")
    dense = [d for d in dense if d not in short]

    # ---- final splines and samples
    ego = _final_vehicle(ego_dense, p, None)
    agents = []
    for d in dense:  # one implausible agent track (a monocular depth jump) must not sink the scenario
        try:
            agents.append(_final_vehicle(d, p, d.cls))
        except UserError as exc:
            warnings.append(f"{exc}; dropped")

    # ---- road: from the whole processed ego path (step-back included)
    road_frame = RoadFrame.from_path(ego_dense.xy, p.road_sigma_m, heading=ego_heading0)
    source = "ego_path"
    if collision is not None:
        ego_id = ego_dense.vehicle.id
        other = next((v for v in collision.participants if v != ego_id), None) if collision.involves_ego else None
        hit = next((d for d in dense if d.vehicle.id == other), None)
        if hit is not None and hit.cls is not None and hit.cls.startswith("D1"):
            s_c = float(road_frame.project(np.array([[collision.x or 0.0, collision.y or 0.0]]))[0][0])
            road_frame = extend_head_on(road_frame, s_c, hit.xy[hit.observed], p.road_sigma_m)
            source = "ego_path+oncoming"
    raw_road = raw.road
    if raw_road.lane_timeline is not None:
        lt = raw_road.lane_timeline
        raw_road = raw_road.model_copy(
            update={
                "lane_timeline": LaneTimeline(
                    t=[x - t0 + t_max for x in lt.t], lane_index=lt.lane_index, lateral_offset=lt.lateral_offset
                )
            }
        )
    road: Road = build_road(
        road_frame,
        raw_road,
        [d.xy for d in [ego_dense, *dense]],
        [d.lateral_m for d in dense if _lane_evidence(d, road_frame)],
        p,
        source,
        warnings,
    )

    params_out = dict(raw.provenance.parameters)
    params_out.update(
        {
            "t_max_s": t_max,
            "stepback_accel_mps2": p.stepback_accel_mps2,
            "video_time_offset_s": t_max - t0,
            "stage2": p.as_dict(),
        }
    )
    return Scenario(
        schema_version=raw.schema_version,
        name=raw.name,
        stage="processed",
        source=raw.source.model_copy(update={"time_offset_s": raw.source.time_offset_s + t_max - t0}),
        camera=raw.camera,
        ego=ego,
        agents=agents,
        road=road,
        collision=collision,
        provenance=Provenance(
            command=raw.provenance.command,
            parameters=params_out,
            seed=seed,
            history=[*raw.provenance.history, "stage 2: deepcrashtest.trajectory.pipeline.process_scenario"],
        ),
        warnings=warnings,
    )


def _lane_evidence(d: _Dense, frame: RoadFrame) -> bool:
    """A vehicle (not a pedestrian) moving along the road: its lateral offset says where a lane is."""
    if d.static or d.vehicle.category == "pedestrian":
        return False
    return along_road(frame, d.xy[d.observed], d.heading)


def _first_speed(d: _Dense) -> float:
    """Speed (m/s) at the first sample from a one-sided 3-point difference."""
    if d.static or len(d.t) < 3:
        return 0.0 if d.static or len(d.t) < 2 else float(np.hypot(*(d.xy[1] - d.xy[0])) / (d.t[1] - d.t[0]))
    h0, h1 = d.t[1] - d.t[0], d.t[2] - d.t[0]
    # derivative at t0 of the quadratic through the first 3 samples
    w1 = h1 / (h0 * (h1 - h0))
    w2 = -h0 / (h1 * (h1 - h0))
    w0 = -(w1 + w2)
    v = w0 * d.xy[0] + w1 * d.xy[1] + w2 * d.xy[2]
    return float(np.hypot(*v))


def _agent_dense(
    agent: Vehicle,
    t0: float,
    t_end: float,
    grid: np.ndarray,
    fps: float,
    frame: RoadFrame,
    s_ego: np.ndarray,
    v_ego_road: np.ndarray,
    ego_speed_at,  # type: ignore[no-untyped-def]
    ego_box: BoxTrack,
    p: Stage2Params,
    warnings: list[str],
) -> _Dense | None:
    a = agent.trajectory.arrays()
    t = a["t"] - t0
    if len(t) < p.min_track_samples:
        warnings.append(f"agent {agent.id}: {len(t)}-sample track (< {p.min_track_samples}); dropped")
        return None
    keep = t <= t_end + _EPS_T
    if keep.sum() < 2 or t[0] >= t_end - _EPS_T:
        warnings.append(f"agent {agent.id}: first seen at or after the end of the scenario; dropped")
        return None
    t, x, y, box_yaw = t[keep], a["x"][keep], a["y"][keep], a["yaw"][keep]
    sm = smooth_track(t, x, y, fps, p)
    if sm.sigma_scale > 1:
        warnings.append(f"agent {agent.id}: noisy track, smoothed {sm.sigma_scale:g}x more strongly")
    obs_xy = sm.pos(t)
    in_view = bool(t[0] <= p.first_seen_tolerance_s)
    static = is_static(t, obs_xy, p.static_speed_mps, p.static_min_displacement_m)
    s_obs, d_obs = frame.project(obs_xy)
    lateral = float(np.median(d_obs))

    if static:
        pos = obs_xy.mean(axis=0)
        heading = circular_mean(box_yaw)
        oncoming = is_oncoming(heading, float(frame.tangent(float(np.median(s_obs)))[0]))
        s_a = float(frame.project(pos[None, :])[0][0])
        passed = bool((s_a - s_ego < 0).any())
        feats = ClassFeatures(oncoming, in_view, True, s_a - float(np.interp(t[0], grid, s_ego)), 0.0, passed)
        cls = trajectory_class(feats, p.overtake_entry_gap_m)
        observed = (grid >= t[0] - _EPS_T) & (grid <= t[-1] + _EPS_T)
        xy_static = np.tile(pos, (len(grid), 1))
        return _Dense(agent, grid.copy(), xy_static, observed, heading, cls, True, lateral, feats, grid, s_a - s_ego)

    disp = obs_xy[-1] - obs_xy[0]
    heading = float(np.arctan2(disp[1], disp[0]))
    oncoming = is_oncoming(heading, float(frame.tangent(float(np.median(s_obs)))[0]))
    t_obs = _span(grid, float(t[0]), float(t[-1]))
    xy_obs = sm.pos(t_obs)
    v_first, v_last = sm.vel(t[0])[0], sm.vel(t[-1])[0]
    t_post = grid[grid > t[-1] + _EPS_T]
    xy_post = np.zeros((0, 2))
    if t_post.size:
        xy_post = continue_after(
            frame, xy_obs[-1], float(np.hypot(*v_last)), float(np.arctan2(v_last[1], v_last[0])), float(t[-1]),
            t_post, oncoming, ego_speed_at,
            p.ongoing_speed_ratio, p.extrapolation_accel_mps2,
        )  # fmt: skip
    full_t = np.concatenate([t_obs, t_post])
    full_xy = np.vstack([xy_obs, xy_post])
    r = frame.project(full_xy)[0] - np.interp(full_t, grid, s_ego)
    tangent0 = float(frame.tangent(s_obs[0])[0])
    rel_speed = float(v_first @ [math.cos(tangent0), math.sin(tangent0)]) - float(np.interp(t[0], grid, v_ego_road))
    feats = ClassFeatures(oncoming, in_view, False, float(r[0]), rel_speed, bool((r < 0).any()))
    cls = trajectory_class(feats, p.overtake_entry_gap_m)
    observed = np.concatenate([np.ones(len(t_obs), bool), np.zeros(len(t_post), bool)])
    d = _Dense(agent, full_t, full_xy, observed, heading, cls, False, lateral, feats, full_t, r)

    if t_post.size:  # an extrapolation must not run into the ego
        hit = first_contact(ego_box, d.box_track(), t_from=float(t[-1]) + _EPS_T)
        if hit is not None:
            keep_t = d.t <= max(float(t[-1]), hit.time_s - 1.0)
            d.t, d.xy, d.observed = d.t[keep_t], d.xy[keep_t], d.observed[keep_t]
            warnings.append(
                f"agent {agent.id}: its extrapolation after leaving the view would hit the ego at "
                f"{hit.time_s:.2f} s (video time); it leaves the scenario 1 s earlier"
            )

    t_pre = grid[grid < t[0] - _EPS_T]
    if t_pre.size and cls == "D0T2":
        w0 = max(rel_speed, p.min_overtake_rel_speed_mps)
        r_pre, _gap = overtaker_relative_station(t_pre, float(t[0]), float(r[0]), w0, p.overtaker_gap_m,
                                                 p.overtaker_rel_accel_mps2)  # fmt: skip
        d_first = float(frame.project(xy_obs[:1])[1][0])
        xy_pre = frame.point(np.interp(t_pre, grid, s_ego) + r_pre, d_first)
    elif t_pre.size and in_view:
        h_first = float(np.arctan2(v_first[1], v_first[0]))
        xy_pre = continue_before(frame, xy_obs[0], float(np.hypot(*v_first)), h_first, float(t[0]), t_pre, oncoming)
    else:
        xy_pre = np.zeros((0, 2))
    if len(xy_pre):
        d.t = np.concatenate([t_pre, d.t])
        d.xy = np.vstack([xy_pre, d.xy])
        d.observed = np.concatenate([np.zeros(len(t_pre), bool), d.observed])
    return d


def _collision(raw: Scenario, ego: _Dense, dense: list[_Dense], t0: float, t_max: float) -> Collision | None:
    if raw.collision is not None:
        c = raw.collision
        for vid in c.participants:
            if vid != raw.ego.id and all(d.vehicle.id != vid for d in dense):
                raise UserError(f"collision participant {vid} was dropped in stage 2 (track too short)")
        return c.model_copy(update={"time_s": c.time_s - t0 + t_max})
    ego_box = ego.box_track()
    best: tuple[Contact, int] | None = None
    for d in dense:
        hit = first_contact(ego_box, d.box_track(), t_from=t_max)
        if hit is not None and (best is None or hit.time_s < best[0].time_s):
            best = (hit, d.vehicle.id)
    if best is None:
        return None
    hit, agent_id = best
    return Collision(
        time_s=hit.time_s, agent_id=agent_id, other_id=ego.vehicle.id, x=hit.x, y=hit.y,
        relative_speed=hit.relative_speed,
    )  # fmt: skip


def _final_vehicle(d: _Dense, p: Stage2Params, cls: str | None) -> Vehicle:
    """Fit the final spline and sample it: positions, heading and speed from its derivative."""
    label = "ego" if cls is None else f"agent {d.vehicle.id}"
    for scale in (1.0, 4.0, 16.0):  # a stronger final fit where a junction of pieces is too abrupt
        tck = fit_xy_spline(d.t, d.xy[:, 0], d.xy[:, 1], p.final_sigma_m * scale)
        xy = eval_xy(tck, d.t)
        vel = eval_xy(tck, d.t, der=1)
        speed = np.zeros(len(d.t)) if d.static else np.hypot(vel[:, 0], vel[:, 1])
        if speed.max(initial=0.0) > MAX_SPEED_MPS:  # too noisy for this fit: a stronger one, else dropped
            amax, i = float("inf"), int(np.argmax(speed))
            continue
        yaw = headings(d.t, xy, d.heading, vel)
        traj = Trajectory.from_arrays(d.t, xy[:, 0], xy[:, 1], yaw, speed, observed=d.observed)
        amax, i = traj.max_abs_accel()
        if amax <= MAX_ACCEL_MPS2:
            break
    else:
        what = (
            f"exceeds {MAX_SPEED_MPS:.0f} m/s"
            if math.isinf(amax)
            else f"accelerates at {amax:.1f} m/s^2 (limit {MAX_ACCEL_MPS2})"
        )
        raise UserError(
            f"{label}: processed trajectory {what} at t={d.t[i]:.2f} s; the track is too noisy for the "
            "smoothing parameters"
        )
    delay = float(d.t[0]) if d.t[0] > _EPS_T else 0.0
    return d.vehicle.model_copy(
        update={
            "trajectory": traj,
            "spline": spline_params(tck),
            "trajectory_class": cls,
            "start_delay_s": delay,
        }
    )
