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
4. Step-back (``trajectory.stepback``): vehicles present at the start are led from rest (or, past
   ``stepback_max_s``, from a lower speed) to their first observed state, reached at ``t_max``;
   the video part is shifted by ``t_max`` (``provenance.parameters["t_max_s"]``).
5. Crash (``trajectory.crash``): the raw scenario's collision (time shifted): the pair's last
   seconds are corrected so they first touch then (``provenance.parameters["crash"]``); every
   other contact before it is removed (bystanders nudged or dropped). Without one, the first
   ego-agent box overlap after t_max, unless the extraction saw no crash in the video
   (``parameters["crash_detection"]["found"] is False``): then no contact at all. Every
   trajectory ends at the collision (the pair's first touch; the pair's continue at their last
   velocity for ``penetration_s``, 0.1 s, overlapping there; the simulator's physics takes over).
6. Each vehicle's final path is fitted with one spline (``Vehicle.spline``, x(t), y(t)); the
   samples (t, x, y, yaw, speed) are that spline and its derivative at the sample times, with
   ``observed`` false on extrapolated and stepped-back samples; the ego's yaw is the camera's measured
   one (the raw ego's, lightly smoothed; held before the video), through which every agent was placed.
   A path whose sampled speed changes faster than its road user's kinematics allow is re-timed along
   itself within them first (``trajectory.traction``; the crash pair held from the collision on).
7. Road (``trajectory.road``).

Time: the raw ego's first sample is video time 0; scenario time = video time + t_max.
Input rules: the raw scenario must be ``stage="raw"`` with a finite positive fps and finite
samples; the ego needs >= 2 samples; agent tracks shorter than ``min_track_samples``, faster than
``max_agent_speed_mps``, starting after the end (or the collision), or whose final trajectory is
not physically possible are dropped with a warning in ``Scenario.warnings``.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import numpy as np
from pydantic import ValidationError

from deepcrashtest.errors import ScenarioError, UserError, check_seed
from deepcrashtest.scenario import (
    MAX_ACCEL_MPS2,
    MAX_SPEED_MPS,
    Collision,
    Kinematics,
    LaneTimeline,
    Provenance,
    Road,
    Scenario,
    Trajectory,
    Vehicle,
    format_validation_error,
    kinematics,
)
from deepcrashtest.trajectory.agentheading import (
    holding_yaws_after,
    replayable_yaws,
    turned_no_closer,
    with_observed_yaw,
)
from deepcrashtest.trajectory.collision import MOVING_MPS, first_contact, headings, vehicle_box
from deepcrashtest.trajectory.contact import ContactParams
from deepcrashtest.trajectory.crash import CrashOutcome, earlier_touch, resolve_crash
from deepcrashtest.trajectory.dense import EPS_T, Dense, EgoFrame, agent_dense, moves_in_video, seen_part, span
from deepcrashtest.trajectory.egoheading import ego_along_measured_yaw, smooth_series
from deepcrashtest.trajectory.egotraction import ego_within_traction
from deepcrashtest.trajectory.params import Stage2Params
from deepcrashtest.trajectory.road import along_road, build_road, extend_head_on
from deepcrashtest.trajectory.roadframe import RoadFrame
from deepcrashtest.trajectory.smoothing import eval_xy, fit_xy_spline, smooth_track, spline_params
from deepcrashtest.trajectory.stepback import LeadIn, plan_step_back
from deepcrashtest.trajectory.traction import exceeding_s, retimed_within

__all__ = ["headings", "process_scenario"]


@dataclass
class _Run:
    """One stage-2 run's shared inputs: the raw scenario, parameters, its first time and the warnings."""

    raw: Scenario
    p: Stage2Params
    fps: float
    t0: float
    warnings: list[str]
    ego_shift_m: float = 0.0
    ego_retime_m: float = 0.0

    @property
    def jolt_at_crash(self) -> bool:
        """Whether the detected crash's frame had camera-jolt evidence (else: a box stopped growing there)."""
        det = self.raw.provenance.parameters.get("crash_detection")
        ev = det.get("evidence") if isinstance(det, dict) else None
        return not isinstance(ev, dict) or float(ev.get("jolt", 1.0)) > 0.0

    @property
    def no_crash_in_video(self) -> bool:
        det = self.raw.provenance.parameters.get("crash_detection")
        return isinstance(det, dict) and det.get("found") is False


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
    """Stage 2 (see the module docstring). Deterministic: ``seed`` is recorded, nothing is random.

    Raises UserError (never an internal error) when the tracks cannot make a valid processed Scenario.
    """
    check_seed(seed)
    try:
        return _process_scenario(raw, seed, params)
    except ValidationError as exc:  # a guard: the final Scenario must be valid or the error must say why
        raise ScenarioError(f"stage 2 could not build a valid scenario: {format_validation_error(exc)}") from None


def _process_scenario(raw: Scenario, seed: int, params: Stage2Params | None) -> Scenario:
    _check_raw(raw)
    run = _Run(raw, params or Stage2Params(), float(raw.source.fps), float(raw.ego.trajectory.t[0]), list(raw.warnings))
    run.raw, run.ego_shift_m = ego_along_measured_yaw(raw, run.p.ego_yaw_window_s, run.warnings)
    impact_s = raw.collision.time_s if raw.collision is not None and raw.collision.involves_ego else math.inf
    run.raw, run.ego_retime_m = ego_within_traction(
        run.raw, run.p.savgol_window_s, ContactParams().kin_margin, run.warnings, impact_s=impact_s
    )
    run.raw = _collision_with_seen_participants(run)
    run.raw = _collision_that_can_happen(run)
    ego_frame, ego = _ego_phase(run)
    agents = [d for a in run.raw.agents if (d := agent_dense(a, run.t0, ego_frame, run.p, run.warnings)) is not None]
    t_max = _step_back_phase(run, ego, agents)
    crash = _crash_phase(run, ego, agents, t_max)
    vehicles = _final_phase(run, ego, crash, t_max)
    vehicles[0] = _with_measured_yaw(vehicles[0], run, t_max)
    observed = [vehicles[0], *_with_observed_yaws(vehicles, crash.agents, t_max - run.t0, run.p.observed_pad_s)]
    vehicles = replayable_yaws(observed, vehicles, crash.collision, run.warnings)
    vehicles = holding_yaws_after(vehicles, crash.collision)
    collision = _collision_record(crash, vehicles)
    road = _road_phase(run, ego, crash, ego_frame, t_max)
    return _assemble(run, vehicles, road, collision, crash, t_max, seed)


def _collision_with_seen_participants(run: _Run) -> Scenario:
    """The raw scenario, without its collision when a participant was not seen for at least
    ``min_track_samples`` samples up to it: the pair cannot be made to touch then, and the scenario must not
    end there (every observed second after it would be lost for a collision that is then dropped)."""
    raw, c = run.raw, run.raw.collision
    if c is None:
        return raw
    agents = {a.id: a for a in raw.agents}
    unseen = []
    for i in c.participants:
        if i == raw.ego.id:
            continue
        t = agents[i].trajectory.arrays()["t"] if i in agents else np.zeros(0)
        if int((t <= c.time_s + EPS_T).sum()) < run.p.min_track_samples:
            unseen.append(i)
    if not unseen:
        return raw
    run.warnings.append(
        f"the collision at {c.time_s - run.t0:.2f} s (video time) names agent(s) {unseen} seen for fewer than "
        f"{run.p.min_track_samples} samples before it: no collision, the whole video is kept"
    )
    return raw.evolve(collision=None)


def _collision_that_can_happen(run: _Run) -> Scenario:
    """The raw scenario, without its detected (``video-auto``) collision when neither participant moves over
    the whole video (:func:`~deepcrashtest.trajectory.dense.moves_in_video`): a stopped ego and a parked car do
    not crash (dad_000512: two standing boxes "touched"; forcing it moves a parked car or the stopped ego).
    The whole video is kept, with a warning."""
    raw, c = run.raw, run.raw.collision
    if c is None or c.source != "video-auto":
        return raw
    byid = {v.id: v for v in raw.vehicles()}
    if any(i not in byid or moves_in_video(byid[i], run.p) for i in c.participants):
        return raw
    if _closing_m(byid[c.other_id], byid[c.agent_id], c.time_s) > run.p.static_min_displacement_m:
        return raw  # one creeps towards the other (ccd_000031: ego-motion lost in snow, the minivan's 1.7 m close)
    run.warnings.append(
        f"the detected crash of {c.other_id} and {c.agent_id} at {c.time_s - run.t0:.2f} s (video time) is dropped: "
        "neither moves in the video (a crash needs one that does)"
    )
    return raw.evolve(collision=None)


def _closing_m(a: Vehicle, b: Vehicle, t_crash: float) -> float:
    """How much closer (m) the two road users' raw positions are at ``t_crash`` (s) than where both are first
    seen: a crawl towards each other that neither track alone shows as motion (a stopped-looking ego whose
    ego-motion failed creeping into a car), unlike two standing boxes (dad_000528: 6.13 -> 6.18 m)."""
    ra, rb = a.trajectory.arrays(), b.trajectory.arrays()
    t0 = max(float(ra["t"][0]), float(rb["t"][0]))
    if t0 >= t_crash:
        return 0.0

    def gap(t: float) -> float:
        pa = np.array([np.interp(t, ra["t"], ra["x"]), np.interp(t, ra["t"], ra["y"])])
        pb = np.array([np.interp(t, rb["t"], rb["x"]), np.interp(t, rb["t"], rb["y"])])
        return float(np.hypot(*(pa - pb)))

    return gap(t0) - gap(t_crash)


SLOW_EGO_MPS = 1.0  # below it the ego's start heading is the camera's measured yaw (ccd_000882: the crawl's
# noisy first steps pointed backwards, the lead-in ran backwards and the replay's vehicle turned round)


def _ego_phase(run: _Run) -> tuple[EgoFrame, Dense]:
    """Smooth the ego on the frame grid (video time, up to the crash) and build the road frame from it."""
    raw, p = run.raw, run.p
    e = raw.ego.trajectory.arrays()
    ego_t = e["t"] - run.t0
    t_end = float(ego_t[-1])
    if raw.collision is not None:
        tc = raw.collision.time_s - run.t0
        if not 0 < tc <= t_end + EPS_T:
            raise UserError(f"collision.time_s {raw.collision.time_s} is outside the ego's trajectory")
        t_end = min(tc, t_end)  # what the video shows after the contact is the impact, not the approach
    dt = 1.0 / run.fps
    grid = span(dt * np.arange(int(np.floor(t_end / dt + 1e-6)) + 1), 0.0, t_end)
    ex, ey = _repair_start_jump(ego_t, e["x"], e["y"], run.warnings)
    ex, ey = _hold_backward_steps(ex, ey, run.warnings)
    sm = smooth_track(ego_t, ex, ey, run.fps, p)
    xy, vel = _forward_smoothed(grid, sm.pos(grid), sm.vel(grid))
    yaw0 = float(e["yaw"][0])
    heading0 = headings(grid, xy, yaw0, vel)[0]
    if float(np.hypot(*vel[0])) < SLOW_EGO_MPS or math.cos(heading0 - yaw0) < 0:
        heading0 = yaw0  # a crawling start: the camera's yaw, not the noise's direction (never backwards)
    frame = RoadFrame.from_path(xy, p.road_sigma_m, heading=heading0)
    s_ego = frame.project(xy)[0]
    v_road = np.gradient(s_ego, grid) if len(grid) > 1 else np.zeros(1)
    dense = Dense(raw.ego, grid, xy, np.ones(len(grid), bool), heading0)
    ego_frame = EgoFrame(grid, frame, s_ego, v_road, np.hypot(vel[:, 0], vel[:, 1]), dense.box_track(), run.fps)
    return ego_frame, dense


def _forward_smoothed(grid: np.ndarray, xy: np.ndarray, vel: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The smoothed ego (m, m/s) with the backward steps its smoothing added held in place: a spline
    through a car at rest that then pulls away swings back before it (ccd_000882: 0.14 m back at 1.1 m/s
    while the raw track stood still); that start then pointed the lead-in backwards and the replay's
    vehicle turned round. Velocities are recomputed where a position was held."""
    held_x, held_y = _hold_backward_steps(xy[:, 0], xy[:, 1], [], min_m=0.0)
    held = np.column_stack([held_x, held_y])
    moved = np.hypot(*(held - xy).T) > 1e-9
    if not moved.any() or len(grid) < 2:
        return xy, vel
    near = np.convolve(moved, np.ones(3), mode="same") > 0  # a held sample and its neighbours
    vel = vel.copy()
    vel[near] = np.gradient(held, grid, axis=0)[near]
    return held, vel


def _hold_backward_steps(
    x: np.ndarray, y: np.ndarray, warnings: list[str], min_m: float = 0.3
) -> tuple[np.ndarray, np.ndarray]:
    """The raw ego (m) with its backward steps along its overall travel held in place, when they add up
    to more than ``min_m``: a crawling dashcam car's monocular track drifts backwards (ccd_000882: 2 m
    over 4 s), the lead-in then extends that backwards and the replay's vehicle turns round to follow."""
    xy = np.column_stack([x, y])
    disp = xy[-1] - xy[0]
    norm = float(np.hypot(*disp))
    if len(xy) < 3 or norm < 1.0:
        return x, y
    u = disp / norm
    s = (xy - xy[0]) @ u
    held = np.maximum.accumulate(s) - s
    if held.max() <= min_m:
        return x, y
    warnings.append(f"ego: its monocular track ran up to {held.max():.1f} m backwards; held in place there")
    xy = xy + held[:, None] * u
    return xy[:, 0], xy[:, 1]


def _repair_start_jump(
    t: np.ndarray, x: np.ndarray, y: np.ndarray, warnings: list[str]
) -> tuple[np.ndarray, np.ndarray]:
    """An ego at rest for its first samples and then at speed at once (an ego-motion warm-up, not a
    launch no car can make) is continued back from its first moving samples at their speed."""
    step = np.hypot(np.diff(x), np.diff(y)) / np.maximum(np.diff(t), EPS_T)
    moving = np.nonzero(step > 0.5)[0]
    if not len(moving) or moving[0] == 0 or len(step) < moving[0] + 3:
        return x, y
    k = int(moving[0])  # first moving step: samples k -> k+1
    v = float(np.median(step[k : k + 3]))
    if v / max(float(t[k + 1] - t[k]), EPS_T) <= MAX_ACCEL_MPS2 or step[:k].max(initial=0.0) > 0.1:
        return x, y
    u = np.array([x[k + 1] - x[k], y[k + 1] - y[k]]) / max(float(np.hypot(x[k + 1] - x[k], y[k + 1] - y[k])), EPS_T)
    back = v * (t[k + 1] - t[: k + 1])
    x, y = x.copy(), y.copy()
    x[: k + 1] = x[k + 1] - back * u[0]
    y[: k + 1] = y[k + 1] - back * u[1]
    warnings.append(
        f"ego: at rest for its first {t[k]:.1f} s, then at {v:.1f} m/s at once (ego-motion warm-up); "
        "those seconds are continued back at that speed"
    )
    return x, y


def _step_back_phase(run: _Run, ego: Dense, agents: list[Dense]) -> float:
    """Lead every vehicle present at the start in from rest (bounded lead-in); shift to scenario time."""
    present = [ego] + [d for d in agents if d.t[0] <= EPS_T]
    v0 = np.array([first_speed(d) for d in present])
    plan = plan_step_back(v0, run.p.stepback_accel_mps2, run.p.stepback_max_s)
    t_max = plan.t_max
    dt = 1.0 / run.fps
    n_pre = int(np.ceil(t_max / dt - 1e-9)) if t_max > 0 else 0
    t_pre = t_max - dt * np.arange(n_pre, 0, -1)
    t_pre = np.concatenate([[0.0], t_pre[t_pre > EPS_T]]) if t_max > 0 else np.zeros(0)
    for d in [ego, *agents]:
        d.t = d.t + t_max
    if t_pre.size:
        for d, v in zip(present, v0, strict=True):
            moving = v > MOVING_MPS and not (d is ego and v < SLOW_EGO_MPS)
            heading = headings(d.t[:3], d.xy[:3], d.heading)[0] if moving else d.heading
            lead_in = LeadIn(d.xy[0].copy(), float(heading), float(v), plan)
            d.prepend(t_pre, lead_in.positions(t_pre))
            d.lead_in = lead_in if moving else None
    return t_max


def first_speed(d: Dense, window_s: float = 0.5) -> float:
    """Speed (m/s) at the first sample: the median over the first ``window_s`` of finite differences
    (robust to one noisy sample at a track's start); 0 for static agents."""
    if d.static or len(d.t) < 2:
        return 0.0
    step = np.hypot(*np.diff(d.xy, axis=0).T) / np.maximum(np.diff(d.t), EPS_T)
    first = step[: max(2, int(np.searchsorted(d.t, d.t[0] + window_s)))]
    return float(np.median(first))


def _crash_phase(run: _Run, ego: Dense, agents: list[Dense], t_max: float) -> CrashOutcome:
    """The video's crash in scenario time, made to happen; every other contact before it removed."""
    known = run.raw.collision
    if known is not None:
        known = known.model_copy(update={"time_s": known.time_s - run.t0 + t_max})
        if known.source == "video-auto" and not run.jolt_at_crash:
            known = earlier_touch(known, ego, agents, t_max, run.warnings)
        if _crawling(ego, known.time_s):  # its box faces where the camera faces, not its noisy path's way
            ego.box_yaw = _measured_yaw(run, t_max)
    out = resolve_crash(
        known, ego, agents, run.p, run.warnings, t_from=t_max, no_crash=known is None and run.no_crash_in_video
    )
    if out.collision is not None:
        for d in out.agents:
            d.reclassify(out.collision.time_s - t_max, run.p.overtake_entry_gap_m)
    short = [d for d in out.agents if len(d.t) < 2]
    for d in short:
        run.warnings.append(f"agent {d.id}: fewer than 2 samples after processing; dropped")
    out.agents = [d for d in out.agents if d not in short]
    return out


def _final_phase(run: _Run, ego: Dense, crash: CrashOutcome, t_max: float) -> list[Vehicle]:
    """Final splines and samples; the ego first. An agent whose path cannot be made physically
    possible (a monocular depth jump) is dropped with a warning instead of sinking the scenario.
    ``t_max`` (s): the end of the step-back lead-in, which the traction fit leaves as it is."""
    c = crash.collision
    pins = {i: c.time_s for i in c.participants} if c is not None else {}
    try:
        vehicles = [_traction_fit(ego, run, None, _Holds(pins.get(ego.id), t_max, run.fps))]
    except UserError:  # a slow, noisy ego-motion track whose every fit runs briefly backwards
        vehicles = [_forward_only_ego(ego, run, _Holds(pins.get(ego.id), t_max, run.fps))]
    for d in crash.agents:
        try:
            vehicles.append(_traction_fit(d, run, d.cls, _Holds(pins.get(d.id), t_max, run.fps)))
        except (UserError, ValidationError) as exc:  # a guard: an invalid agent is dropped, never an internal error
            bad = f"agent {d.id}: {format_validation_error(exc)}" if isinstance(exc, ValidationError) else exc
            run.warnings.append(f"{bad}; dropped")
    kept = {v.id for v in vehicles}
    crash.agents = [d for d in crash.agents if d.id in kept]
    if crash.collision is not None and not set(crash.collision.participants) <= kept:
        run.warnings.append("a participant of the collision was dropped (implausible trajectory); no collision")
        crash.collision = None
    return vehicles


TRACTION_MARGINS = (0.85, 0.8, 0.75, 0.7, 0.6, 0.5)
"""Shares of a road user's acceleration and braking limits its path is re-timed within, tried in turn until
its final spline keeps within the limits (the spline's speed rounds a profile's corners, asking up to ~25 %
more there: KITTI 0002's car 16, 3.55 -> 4.35 m/s^2). The first is the crash correction's ``kin_margin``; the
steps of 0.05 move a path less than steps of 0.15 did (dad_000487's ego: 0.09 m at 0.8, 0.39 m at 0.7; chosen
on the fidelity clips)."""


LEAD_JUNCTION_S = 0.5
"""The last seconds of a step-back lead-in the traction fit may re-time with the video's first ones: the lead-in
ramps from rest to the first observed speed (a median over 0.5 s), and the final spline's start can run faster
or slower than that, a jump where the two meet (ccd_000053 filmed off a screen: 4.6 -> 5.4 -> 5.8 m/s over 0.2 s,
5.9 m/s^2 beyond the car's 4)."""


MAX_RETIME_M = 0.5
"""A re-timing that moves a path further than this (m) is not applied: ccd_000755's crash partner, moved
0.55 m, lost 0.035 of reprojection IoU (0.61 -> 0.57) and 0.05 in its replay (chosen on the fidelity clips)."""


@dataclass(frozen=True)
class _Holds:
    """What the traction fit leaves as it is: samples from ``pin_s`` (s) on (a crash pair's contact; None: no
    pin) and up to ``t_max`` (s; the step-back lead-in from rest, built within the limits at
    ``stepback_accel_mps2``): the lead-in's own ramp is not re-timed, but where the video's first sample asks
    more than the limits of the one before it (``fps``: the frame rate, 1/s), the lead-in's last
    ``LEAD_JUNCTION_S`` are re-timed with the video's start."""

    pin_s: float | None
    t_max: float
    fps: float

    @property
    def lead_s(self) -> float:
        """Samples up to this time (s) are held."""
        return self.t_max - LEAD_JUNCTION_S

    @property
    def check_s(self) -> float:
        """Speed changes after this time (s) are checked against the limits: from the lead-in's last frame on."""
        return self.t_max - 1.0 / self.fps - 1e-6


def _exceeding_s(v: Vehicle, kin: Kinematics, after_s: float) -> np.ndarray:
    """Times (s) of the samples after ``after_s`` between which the vehicle's speed changes faster than ``kin``
    allows (:func:`traction.exceeding_s`)."""
    return exceeding_s(np.asarray(v.trajectory.t), np.asarray(v.trajectory.speed), kin, after_s)


def _traction_fit(d: Dense, run: _Run, cls: str | None, holds: _Holds, allow_reverse: bool = False) -> Vehicle:
    """:func:`_final_vehicle`; where its speed changes faster than the road user's kinematics allow (stage 2's
    smoothing or crash correction asked for more), the path is re-timed along itself within each of
    ``TRACTION_MARGINS`` x its limits in turn (``trajectory.traction``; ``holds``' samples held: the crash
    keeps its time and place, the lead-in its ramp) until its fit keeps within them. Where none does within
    ``MAX_RETIME_M`` the first fit is kept. Warns either way."""
    v = _final_vehicle(d, run.p, cls, allow_reverse)
    kin = kinematics(d.vehicle.category)
    around = np.zeros(0) if d.static else _exceeding_s(v, kin, holds.check_s)
    if not len(around):
        return v
    xy0, label = d.xy, "ego" if cls is None else f"agent {d.id}"
    for margin in TRACTION_MARGINS:
        d.xy = retimed_within(d.t, xy0, kin, margin, holds.pin_s, around, holds.lead_s)
        try:
            fit = _final_vehicle(d, run.p, cls, allow_reverse)
        except UserError:  # a guard: the re-timed path is smoother; if not, the first fit is kept
            break
        moved = float(np.hypot(*(d.xy - xy0).T).max())
        if moved > MAX_RETIME_M:  # smaller margins move it further
            break
        if not len(_exceeding_s(fit, kin, holds.check_s)):
            run.warnings.append(
                f"{label}: its processed path asked for more acceleration or braking than a {d.vehicle.category} "
                f"has; re-timed along itself within {margin:.2f} x its limits (moved up to {moved:.2f} m)"
            )
            return fit
    d.xy = xy0
    run.warnings.append(
        f"{label}: its processed path asks for more acceleration or braking than a {d.vehicle.category} has, and "
        f"re-timing it along itself by up to {MAX_RETIME_M} m does not keep it within; kept as it is"
    )
    return v


def _forward_only_ego(ego: Dense, run: _Run, holds: _Holds) -> Vehicle:
    """The ego of a crawling, noisy monocular track: its backward steps along its overall travel are
    held in place (a dashcam car crawling does not reverse and drive on; the replay's vehicle cannot
    follow a path that turns back on itself); if a fit still runs backwards, it is kept as it is."""
    x, y = _hold_backward_steps(ego.xy[:, 0], ego.xy[:, 1], run.warnings, min_m=0.0)
    ego.xy = np.column_stack([x, y])
    try:
        return _traction_fit(ego, run, None, holds)
    except UserError:
        run.warnings.append("ego: its processed path runs briefly backwards (a slow, noisy ego-motion track); kept")
        return _final_vehicle(ego, run.p, None, allow_reverse=True)


def _crawling(ego: Dense, t_crash: float, window_s: float = 1.0) -> bool:
    """True when the ego moves slower than ``SLOW_EGO_MPS`` on average over the ``window_s`` before the
    crash (scenario time, s): the direction of its path is then noise (ccd_000132: 0.2 rad off the
    camera's yaw at 0.4 m/s), which a replayed vehicle does not turn to."""
    m = (ego.t >= t_crash - window_s) & (ego.t <= t_crash + EPS_T)
    if m.sum() < 2:
        return False
    length = float(np.hypot(*np.diff(ego.xy[m], axis=0).T).sum())
    return length / max(float(ego.t[m][-1] - ego.t[m][0]), EPS_T) < SLOW_EGO_MPS


def _measured_yaw(run: _Run, t_max: float) -> tuple[np.ndarray, np.ndarray] | None:
    """(scenario time s, yaw rad): the camera's measured yaw, lightly smoothed (None when unusable)."""
    e = run.raw.ego.trajectory.arrays()
    t_video = e["t"] - run.t0
    yaw_raw = np.unwrap(e["yaw"])
    if len(t_video) < 2 or not np.all(np.isfinite(yaw_raw)):
        return None
    return t_video + t_max, smooth_series(t_video, yaw_raw, run.p.ego_yaw_window_s)


def _with_measured_yaw(ego: Vehicle, run: _Run, t_max: float) -> Vehicle:
    """The ego's heading where the video saw it: the camera's measured yaw (the raw ego's, from the
    image's rotation), lightly smoothed, instead of the direction of its fitted path.

    The camera turns with the car: its rotation is measured frame by frame, while the path's direction is
    noise when the ego is slow (a car waiting to turn) or its speed scale is unknown; every agent was placed
    through that measured yaw, so the processed scenario must view them through it. Before the video
    (step-back lead-in) the first measured yaw is held."""
    measured = _measured_yaw(run, t_max)
    if measured is None:
        return ego
    a = ego.trajectory.arrays()
    yaw = np.interp(a["t"], *measured)
    traj = ego.trajectory.model_copy(update={"yaw": [float(v) for v in yaw]})
    return ego.model_copy(update={"trajectory": traj})


def _with_observed_yaws(vehicles: list[Vehicle], dense: list[Dense], t_shift: float, pad_s: float) -> list[Vehicle]:
    """The agents of ``vehicles`` (the ego first, left out of the result): moving ones keep the raw heading (fitted
    to their boxes) where the video saw them (their seen part, ``pad_s``: :func:`~deepcrashtest.trajectory.dense.
    seen_part`; :func:`~deepcrashtest.trajectory.agentheading.with_observed_yaw`), turning from it no faster than
    they can steer where it did not, unless that brings them nearer another road user
    (:func:`~deepcrashtest.trajectory.agentheading.turned_no_closer`); parked ones already face it."""
    static = {d.id for d in dense if d.static}
    raw = {d.id: seen_part(d.vehicle, pad_s) for d in dense}
    clearance = ContactParams().clearance_m
    out = []
    for v in vehicles[1:]:
        if v.id in static or v.id not in raw:
            out.append(v)
            continue
        turned = with_observed_yaw(v, raw[v.id], t_shift)
        plain = with_observed_yaw(v, raw[v.id], t_shift, turn_limit=False)
        out.append(turned_no_closer(turned, plain, vehicles, clearance))
    return out


def _collision_record(crash: CrashOutcome, vehicles: list[Vehicle]) -> Collision | None:
    """The collision with its impact point and relative speed from the final trajectories; the pair's
    first contact time is recorded (``crash.record["contact_time_s"]``)."""
    c = crash.collision
    if c is None:
        return None
    byid = {v.id: v for v in vehicles}
    a, b = (byid[i] for i in c.participants)
    hit = first_contact(vehicle_box(a), vehicle_box(b))
    if hit is None:
        crash.record["contact_time_s"] = None
        return c
    crash.record["contact_time_s"] = round(hit.time_s, 3)
    update: dict[str, Any] = {"relative_speed": hit.relative_speed}
    if c.x is None or c.y is None:
        update.update(x=hit.x, y=hit.y)
    return c.model_copy(update=update)


def _road_phase(run: _Run, ego: Dense, crash: CrashOutcome, ego_frame: EgoFrame, t_max: float) -> Road:
    """The road from the whole processed ego path (step-back included), continued along an oncoming
    vehicle's path in a head-on crash; the raw lane timeline shifted to scenario time."""
    p, raw = run.p, run.raw
    heading0 = ego.heading
    road_frame = RoadFrame.from_path(ego.xy, p.road_sigma_m, heading=heading0)
    source = "ego_path"
    c = crash.collision
    if c is not None and c.involves_ego:
        other = c.agent_id if c.other_id == ego.id else c.other_id
        hit = next((d for d in crash.agents if d.id == other), None)
        if hit is not None and hit.cls is not None and hit.cls.startswith("D1"):
            s_c = float(road_frame.project(np.array([[c.x or 0.0, c.y or 0.0]]))[0][0])
            seen = hit.xy[hit.observed] if hit.observed.sum() >= 2 else hit.xy
            road_frame = extend_head_on(road_frame, s_c, seen, p.road_sigma_m)
            source = "ego_path+oncoming"
    raw_road = raw.road
    if raw_road.lane_timeline is not None:
        lt = raw_road.lane_timeline
        shifted = LaneTimeline(
            t=[x - run.t0 + t_max for x in lt.t], lane_index=lt.lane_index, lateral_offset=lt.lateral_offset
        )
        raw_road = raw_road.model_copy(update={"lane_timeline": shifted})
    paths = [d.xy for d in [ego, *crash.agents]]
    along = [d for d in crash.agents if _lane_evidence(d, road_frame)]
    oncoming = [_lateral_m(d, road_frame) for d in along if d.cls is not None and d.cls.startswith("D1")]
    same = [_lateral_m(d, road_frame) for d in along if d.cls is None or not d.cls.startswith("D1")]
    return build_road(road_frame, raw_road, paths, (same, oncoming), p, source, run.warnings)


def _seen_xy(d: Dense) -> np.ndarray:
    """A road user's observed positions (m), all of them where none is observed."""
    return d.xy[d.observed] if d.observed.any() else d.xy


def _lane_evidence(d: Dense, frame: RoadFrame) -> bool:
    """A vehicle (not a pedestrian) moving along the road: its lateral offset says where a lane is."""
    if d.static or d.vehicle.category == "pedestrian":
        return False
    return along_road(frame, _seen_xy(d), d.heading)


def _lateral_m(d: Dense, frame: RoadFrame) -> float:
    """Median lateral offset (m, left positive) of a road user's observed positions from the road's centre line."""
    return float(np.median(frame.project(_seen_xy(d))[1]))


def _assemble(
    run: _Run,
    vehicles: list[Vehicle],
    road: Road,
    collision: Collision | None,
    crash: CrashOutcome,
    t_max: float,
    seed: int,
) -> Scenario:
    raw, p = run.raw, run.p
    params_out = dict(raw.provenance.parameters)
    params_out.update(
        {
            "t_max_s": t_max,
            "stepback_accel_mps2": p.stepback_accel_mps2,
            "video_time_offset_s": t_max - run.t0,
            "ego_heading_shift_m": round(run.ego_shift_m, 3),
            "ego_traction_shift_m": round(run.ego_retime_m, 3),
            "stage2": p.as_dict(),
        }
    )
    if crash.record:
        params_out["crash"] = crash.record
    return Scenario(
        schema_version=raw.schema_version,
        name=raw.name,
        stage="processed",
        source=raw.source.model_copy(update={"time_offset_s": raw.source.time_offset_s + t_max - run.t0}),
        camera=raw.camera,
        ego=vehicles[0],
        agents=vehicles[1:],
        road=road,
        collision=collision,
        provenance=Provenance(
            command=raw.provenance.command,
            parameters=params_out,
            seed=seed,
            history=[*raw.provenance.history, "stage 2: deepcrashtest.trajectory.pipeline.process_scenario"],
        ),
        warnings=run.warnings,
    )


def _reverses(d: Dense, vel: np.ndarray, tol_mps: float = 0.5) -> bool:
    """True when the ego's fitted path runs backwards (against its overall travel) faster than
    ``tol_mps`` anywhere: a spline overshoot where its track starts abruptly (agents' monocular
    tracks wobble; a replay follows their positions, not a backward heading)."""
    if d.static or d.vehicle.id != 0 or len(d.t) < 3:
        return False
    disp = d.xy[-1] - d.xy[0]
    norm = float(np.hypot(*disp))
    if norm < 1.0:
        return False
    return bool((vel @ (disp / norm)).min() < -tol_mps)


def _final_vehicle(d: Dense, p: Stage2Params, cls: str | None, allow_reverse: bool = False) -> Vehicle:
    """Fit the final spline and sample it: positions, heading and speed from its derivative; a
    stronger fit where a junction of pieces is too abrupt; refused if still not physically possible.
    ``allow_reverse``: accept an ego path that runs briefly backwards (the last resort for a slow ego)."""
    label = "ego" if cls is None else f"agent {d.vehicle.id}"
    for scale in (1.0, 4.0, 16.0, 64.0, 256.0):
        tck = fit_xy_spline(d.t, d.xy[:, 0], d.xy[:, 1], p.final_sigma_m * scale)
        xy = eval_xy(tck, d.t)
        vel = eval_xy(tck, d.t, der=1)
        speed = np.zeros(len(d.t)) if d.static else np.hypot(vel[:, 0], vel[:, 1])
        if speed.max(initial=0.0) > MAX_SPEED_MPS or (not allow_reverse and _reverses(d, vel)):
            continue
        yaw = np.full(len(d.t), d.heading) if d.static else headings(d.t, xy, d.heading, vel)
        traj = Trajectory.from_arrays(d.t, xy[:, 0], xy[:, 1], yaw, speed, observed=d.observed)
        amax, i = traj.max_abs_accel()
        if amax <= MAX_ACCEL_MPS2:
            break
    else:
        raise UserError(
            f"{label}: the processed trajectory is not physically possible (speed up to "
            f"{speed.max(initial=0.0):.0f} m/s, acceleration limit {MAX_ACCEL_MPS2} m/s^2); the track is too noisy"
        )
    delay = float(d.t[0]) if d.t[0] > EPS_T else 0.0
    return d.vehicle.model_copy(
        update={"trajectory": traj, "spline": spline_params(tck), "trajectory_class": cls, "start_delay_s": delay}
    )
