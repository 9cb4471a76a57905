"""Stage 2's working state: every vehicle's positions on the common time grid, and how an agent's is built.

Times are video seconds (the raw ego's first sample is 0) until the step-back shifts them to
scenario time; positions are world-frame metres (x forward, y left).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field, replace

import numpy as np

from deepcrashtest.scenario import Vehicle
from deepcrashtest.trajectory.classify import ClassFeatures, circular_mean, is_oncoming, is_static, trajectory_class
from deepcrashtest.trajectory.collision import BoxTrack, first_contact, headings
from deepcrashtest.trajectory.extrapolate import continue_after, continue_before, overtaker_relative_station
from deepcrashtest.trajectory.params import Stage2Params
from deepcrashtest.trajectory.roadframe import RoadFrame
from deepcrashtest.trajectory.smoothing import SmoothTrack, smooth_track
from deepcrashtest.trajectory.stepback import LeadIn

EPS_T = 1e-3  # seconds: samples closer than this are merged


@dataclass
class Dense:
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
    box_yaw: tuple[np.ndarray, np.ndarray] | None = None
    """(t s, yaw rad) the box faces instead of the motion's direction (a crawling ego: the camera's yaw)."""
    lead_in: LeadIn | None = None
    """The step-back lead-in prepended to a moving vehicle present at the video's start (its samples before t_max)."""

    @property
    def id(self) -> int:
        return self.vehicle.id

    def reclassify(self, t_end_video: float, overtake_entry_gap_m: float) -> None:
        """An agent the ego hits has not been passed: "passed" only counts up to the collision."""
        if self.feats is None:
            return
        passed = bool((self.rel_s[self.rel_t <= t_end_video + EPS_T] < 0).any())
        self.feats = replace(self.feats, passed=passed)
        self.cls = trajectory_class(self.feats, overtake_entry_gap_m)

    def box_track(self) -> BoxTrack:
        v = self.vehicle
        return BoxTrack(self.t, self.xy[:, 0], self.xy[:, 1], self.box_headings(), v.length, v.width)

    def box_headings(self) -> np.ndarray:
        """The box's heading (rad) per sample: ``box_yaw`` where set, a parked road user's box heading
        (``heading``: a shift that keeps it apart must not turn it), else the motion's direction."""
        if self.box_yaw is not None:
            return np.interp(self.t, *self.box_yaw)
        if self.static:
            return np.full(len(self.t), self.heading)
        return headings(self.t, self.xy, self.heading)

    def keep(self, mask: np.ndarray) -> None:
        self.t, self.xy, self.observed = self.t[mask], self.xy[mask], self.observed[mask]

    def prepend(self, t: np.ndarray, xy: np.ndarray) -> None:
        """Unobserved samples before the first one."""
        self.t = np.concatenate([t, self.t])
        self.xy = np.vstack([xy, self.xy])
        self.observed = np.concatenate([np.zeros(len(t), bool), self.observed])

    def cut(self, t_end: float) -> None:
        """Keep samples up to ``t_end`` (adding one exactly at ``t_end`` by interpolation). A kept sample
        closer than ``CUT_MIN_GAP_S`` to ``t_end`` is dropped: a near-duplicate sample makes the final
        spline's speed jump between the two (ccd_000080: 5 ms apart, "not physically possible")."""
        keep = self.t < t_end - CUT_MIN_GAP_S
        if not keep.any():
            keep = self.t < t_end - EPS_T
        if self.t[-1] >= t_end - EPS_T:
            end = np.array([[np.interp(t_end, self.t, self.xy[:, 0]), np.interp(t_end, self.t, self.xy[:, 1])]])
            obs_end = bool(self.observed[min(int(np.searchsorted(self.t, t_end)), len(self.t) - 1)])
            self.t = np.append(self.t[keep], t_end)
            self.xy = np.vstack([self.xy[keep], end])
            self.observed = np.append(self.observed[keep], obs_end)


CUT_MIN_GAP_S = 0.02  # s: a fifth of a 10 fps frame interval; cut ends closer to a sample replace it


def span(grid: np.ndarray, a: float, b: float) -> np.ndarray:
    """Times from ``a`` to ``b`` inclusive: both ends plus the grid points strictly between."""
    inner = grid[(grid > a + EPS_T) & (grid < b - EPS_T)]
    return np.unique(np.concatenate([[a], inner, [b]])) if b > a + EPS_T else np.array([a])


@dataclass
class EgoFrame:
    """What every agent is placed against: the grid (video s), the road frame, the ego's station/speeds."""

    grid: np.ndarray
    frame: RoadFrame
    s_ego: np.ndarray
    v_ego_road: np.ndarray
    speed: np.ndarray
    box: BoxTrack
    fps: float

    def speed_at(self, t: np.ndarray) -> np.ndarray:
        return np.interp(t, self.grid, self.speed)


@dataclass
class _Observed:
    """An agent's smoothed observed part (video time)."""

    t: np.ndarray
    xy: np.ndarray
    box_yaw: np.ndarray
    sm: SmoothTrack
    in_view: bool
    s: np.ndarray
    lateral: float


def agent_dense(agent: Vehicle, t0: float, ego: EgoFrame, p: Stage2Params, warnings: list[str]) -> Dense | None:
    """An agent's dense path over the grid: smoothed, classified, extrapolated (None = dropped, warned)."""
    obs = _observe(agent, t0, ego, p, warnings)
    if obs is None:
        return None
    still = is_static(obs.t, obs.xy, p.static_speed(agent.category), p.static_min_displacement_m)
    if still and not moves_in_video(agent, p):
        return _static_dense(agent, obs, ego, p)
    d = _moving_dense(agent, obs, ego, p)
    _extend_after(d, obs, ego, p, warnings)
    _extend_before(d, obs, ego, p)
    return d


def moves_in_video(v: Vehicle, p: Stage2Params) -> bool:
    """Whether the road user's whole track (also after the scenario's end) is not static (``is_static`` on the
    medians of its first and last five positions): seen for 0.2 s before a crash, a car passing the ego looked
    parked and the crash correction drove the stopped ego into it instead (dad_000528)."""
    a = v.trajectory.arrays()
    xy = np.column_stack([a["x"], a["y"]])
    ends = np.stack([np.median(xy[:5], axis=0), np.median(xy[-5:], axis=0)])
    return not is_static(a["t"][[0, -1]], ends, p.static_speed(v.category), p.static_min_displacement_m)


def _observe(agent: Vehicle, t0: float, ego: EgoFrame, p: Stage2Params, warnings: list[str]) -> _Observed | None:
    a = seen_part(agent, p.observed_pad_s)
    t = a["t"] - t0
    t_end = float(ego.grid[-1])
    if len(t) < p.min_track_samples:
        warnings.append(f"agent {agent.id}: {len(t)}-sample track (< {p.min_track_samples}); dropped")
        return None
    keep = t <= t_end + EPS_T
    if keep.sum() < 2 or t[0] >= t_end - EPS_T:
        warnings.append(f"agent {agent.id}: first seen at or after the end of the scenario; dropped")
        return None
    t, x, y = t[keep], a["x"][keep], a["y"][keep]
    sm = smooth_track(t, x, y, ego.fps, p)
    if sm.sigma_scale > 1:
        warnings.append(f"agent {agent.id}: noisy track, smoothed {sm.sigma_scale:g}x more strongly")
    xy = sm.pos(t)
    speed = np.hypot(*sm.vel(t).T)
    if len(speed) and float(np.percentile(speed, 90)) > p.max_agent_speed_mps:
        warnings.append(
            f"agent {agent.id}: observed speed {np.percentile(speed, 90):.0f} m/s is not a road user's "
            "(localisation noise); dropped"
        )
        return None
    s_obs, d_obs = ego.frame.project(xy)
    in_view = bool(t[0] <= p.first_seen_tolerance_s)
    return _Observed(t, xy, a["yaw"][keep], sm, in_view, s_obs, float(np.median(d_obs)))


def seen_part(agent: Vehicle, pad_s: float) -> dict[str, np.ndarray]:
    """The agent's trajectory arrays from its first to its last observed sample, ``pad_s`` (s) wider: what the video
    showed, without a stage 1 continuation beyond it (all of it when nothing, or every sample, is flagged)."""
    a = agent.trajectory.arrays()
    obs = agent.trajectory.observed
    if obs is None or not any(obs) or all(obs):
        return a
    seen = a["t"][np.asarray(obs, bool)]
    keep = (a["t"] >= seen[0] - pad_s - EPS_T) & (a["t"] <= seen[-1] + pad_s + EPS_T)
    return {k: v[keep] for k, v in a.items()}


def _static_dense(agent: Vehicle, obs: _Observed, ego: EgoFrame, p: Stage2Params) -> Dense:
    """Parked: held at its mean position with its box heading over the whole grid."""
    grid = ego.grid
    pos = obs.xy.mean(axis=0)
    heading = circular_mean(obs.box_yaw)
    oncoming = is_oncoming(heading, float(ego.frame.tangent(float(np.median(obs.s)))[0]))
    s_a = float(ego.frame.project(pos[None, :])[0][0])
    passed = bool((s_a - ego.s_ego < 0).any())
    feats = ClassFeatures(oncoming, obs.in_view, True, s_a - float(np.interp(obs.t[0], grid, ego.s_ego)), 0.0, passed)
    cls = trajectory_class(feats, p.overtake_entry_gap_m)
    observed = (grid >= obs.t[0] - EPS_T) & (grid <= obs.t[-1] + EPS_T)
    xy = np.tile(pos, (len(grid), 1))
    return Dense(agent, grid.copy(), xy, observed, heading, cls, True, obs.lateral, feats, grid, s_a - ego.s_ego)


def _moving_dense(agent: Vehicle, obs: _Observed, ego: EgoFrame, p: Stage2Params) -> Dense:
    """The observed part on the grid, continued along the road to the end; classified."""
    grid, frame = ego.grid, ego.frame
    disp = obs.xy[-1] - obs.xy[0]
    heading = float(np.arctan2(disp[1], disp[0]))
    oncoming = is_oncoming(heading, float(frame.tangent(float(np.median(obs.s)))[0]))
    t_obs = span(grid, float(obs.t[0]), float(obs.t[-1]))
    xy_obs = obs.sm.pos(t_obs)
    v_last = obs.sm.vel(obs.t[-1])[0]
    t_post = grid[grid > obs.t[-1] + EPS_T]
    xy_post = np.zeros((0, 2))
    if t_post.size:
        xy_post = continue_after(
            frame, xy_obs[-1], float(np.hypot(*v_last)), float(np.arctan2(v_last[1], v_last[0])), float(obs.t[-1]),
            t_post, oncoming, ego.speed_at, p.ongoing_speed_ratio, p.extrapolation_accel_mps2,
        )  # fmt: skip
    full_t = np.concatenate([t_obs, t_post])
    full_xy = np.vstack([xy_obs, xy_post])
    r = frame.project(full_xy)[0] - np.interp(full_t, grid, ego.s_ego)
    tangent0 = float(frame.tangent(obs.s[0])[0])
    v_first = obs.sm.vel(obs.t[0])[0]
    rel_speed = float(v_first @ [math.cos(tangent0), math.sin(tangent0)]) - float(
        np.interp(obs.t[0], grid, ego.v_ego_road)
    )
    feats = ClassFeatures(oncoming, obs.in_view, False, float(r[0]), rel_speed, bool((r < 0).any()))
    cls = trajectory_class(feats, p.overtake_entry_gap_m)
    observed = np.concatenate([np.ones(len(t_obs), bool), np.zeros(len(t_post), bool)])
    return Dense(agent, full_t, full_xy, observed, heading, cls, False, obs.lateral, feats, full_t, r)


def _extend_after(d: Dense, obs: _Observed, ego: EgoFrame, p: Stage2Params, warnings: list[str]) -> None:
    """An extrapolation after leaving the view must not run into the ego: it leaves 1 s earlier."""
    t_last = float(obs.t[-1])
    if d.t[-1] <= t_last + EPS_T:
        return
    hit = first_contact(ego.box, d.box_track(), t_from=t_last + EPS_T)
    if hit is not None:
        d.keep(d.t <= max(t_last, hit.time_s - 1.0))
        warnings.append(
            f"agent {d.id}: its extrapolation after leaving the view would hit the ego at "
            f"{hit.time_s:.2f} s (video time); it leaves the scenario 1 s earlier"
        )


def _extend_before(d: Dense, obs: _Observed, ego: EgoFrame, p: Stage2Params) -> None:
    """D0T2 (an overtaker) approaches from behind for at most ``max_invented_s`` before it appears;
    agents in view at the start but first seen a few frames late are continued back to the start;
    the others start late."""
    grid, frame = ego.grid, ego.frame
    t_pre = grid[grid < obs.t[0] - EPS_T]
    if not t_pre.size:
        return
    v_first = obs.sm.vel(obs.t[0])[0]
    xy_first = obs.sm.pos(obs.t[0])
    if d.cls == "D0T2" and d.feats is not None:  # nobody is invented long before they are seen
        t_pre = t_pre[t_pre >= obs.t[0] - p.max_invented_s - EPS_T]
        if not t_pre.size:
            return
        w0 = max(d.feats.entry_rel_speed_mps, p.min_overtake_rel_speed_mps)
        r_pre, _gap = overtaker_relative_station(
            t_pre, float(obs.t[0]), float(d.rel_s[0]), w0, p.overtaker_gap_m, p.overtaker_rel_accel_mps2
        )
        d_first = float(frame.project(xy_first)[1][0])
        d.prepend(t_pre, frame.point(np.interp(t_pre, grid, ego.s_ego) + r_pre, d_first))
    elif obs.in_view:
        h_first = float(np.arctan2(v_first[1], v_first[0]))
        oncoming = d.feats is not None and d.feats.oncoming
        speed = float(np.hypot(*v_first))
        d.prepend(t_pre, continue_before(frame, xy_first[0], speed, h_first, float(obs.t[0]), t_pre, oncoming))
