"""Stage-2 parameters, all in physical units (seconds, metres, m/s, m/s^2).

Nothing here is counted in samples: windows are converted with the video's frame rate, so the
same parameters work for a 10 Hz KITTI sequence and a 30 fps dashcam clip.
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass, fields
from typing import Any

from deepcrashtest.errors import UserError

#: Values of ``Stage2Params.driving_side`` (and ``Road.driving_side``).
DRIVING_SIDES = ("right", "left")


@dataclass(frozen=True)
class Stage2Params:
    """Knobs of :func:`deepcrashtest.trajectory.pipeline.process_scenario`."""

    # --- smoothing (trajectory.smoothing)
    savgol_window_s: float = 0.7
    """Savitzky-Golay window, seconds (rounded to an odd number of frames)."""
    savgol_polyorder: int = 2
    local_window_s: float = 2.0
    """Length of the windows of the local spline fit, seconds (windows overlap by half)."""
    local_sigma_m: float = 0.15
    """Local fit: allowed RMS deviation from the Savitzky-Golay output (high smoothing), metres."""
    global_sigma_m: float = 0.01
    """Global fit: allowed RMS deviation from the blended local fits (low smoothing), metres."""
    final_sigma_m: float = 0.003
    """Fit of the final (extended, stepped-back) path that becomes ``Vehicle.spline``, metres."""
    ego_yaw_window_s: float = 0.3
    """The ego's heading is the camera's measured yaw, smoothed over this window, seconds (short: the
    camera's turns and shake are what the video shows)."""
    max_smoothing_accel_mps2: float = 12.0
    """If a smoothed track still accelerates harder than this, it is smoothed again more strongly."""
    # --- track selection and classes (trajectory.classify)
    min_track_samples: int = 3
    """Agent tracks with fewer samples are dropped (with a warning): too short to smooth or classify."""
    first_seen_tolerance_s: float = 0.25
    """An agent first seen within this time of the video's start counts as "in view at the start"."""
    observed_pad_s: float = 0.5
    """An agent's samples from its first to its last observed (detected) one, this much wider (s), are its observed
    part; stage 2 continues it outside by its own rules. Stage 1 may carry a track beyond what the video showed (the
    monocular tracker's constant-velocity extension of far tracks, ``MonoConfig.extend_s``; its tracked span ends
    within ``MonoConfig.carry_cut_s`` = 0.5 s of a detection): such samples were smoothed, classified ("in view at
    the start") and flagged observed as if seen (the Udacity highway clip: an oncoming car first detected at 4.2 s,
    282 m ahead "observed" from 0.2 s)."""
    static_speed_mps: float = 1.0
    """An agent whose net displacement / observed duration is below this is parked/static ..."""
    static_min_displacement_m: float = 1.0
    """... or whose net displacement is below this (label noise on a parked car), metres."""
    static_speed_pedestrian_mps: float = 0.4
    """``static_speed_mps`` for a pedestrian: people walk at 0.7-1.5 m/s (ccd_000882: a woman crossing at
    0.8 m/s for 1.4 s was held standing, and the crash correction swung the ego's rear into her)."""
    overtake_entry_gap_m: float = 20.0
    """A same-direction agent appearing later closer than this ahead and faster than the ego is D0T2."""
    # --- extrapolation (trajectory.extrapolate)
    ongoing_speed_ratio: float = 0.9
    """A same-direction agent that left the view continues at min(own speed, ratio x ego speed)."""
    extrapolation_accel_mps2: float = 2.0
    """Largest speed change per second while an extrapolated agent settles to its new speed."""
    overtaker_gap_m: float = 20.0
    """D0T2 before it appears: distance behind the ego (along the road) while it mimics the ego, metres."""
    overtaker_rel_accel_mps2: float = 1.0
    """D0T2: relative acceleration with which it closes in on the ego before it appears."""
    min_overtake_rel_speed_mps: float = 0.5
    max_invented_s: float = 2.0
    """D0T2: how long before it is first seen an overtaker is invented behind the ego, s (then it starts late)."""
    # --- step-back initialisation (trajectory.stepback)
    stepback_accel_mps2: float = 3.0
    """Acceleration a of every vehicle from rest to its first observed speed, m/s^2."""
    stepback_max_s: float = 4.0
    """Longest lead-in before the first frame, s: faster vehicles start moving rather than from rest."""
    max_agent_speed_mps: float = 60.0
    """An agent whose observed speed (90th percentile) exceeds this is localisation noise: dropped."""
    # --- the crash (trajectory.contact)
    crash_window_s: float = 2.0
    """How many seconds before the crash the pair's correction may start (tried x1, x1.5, x2.25)."""
    crash_accel_limit_mps2: float = 4.0
    """Largest acceleration the crash correction may add on each axis (driver braking/steering)."""
    crash_large_correction_m: float = 2.0
    """A crash correction larger than this is warned about."""
    crash_overlap_s: float = 0.1
    """The crash pair's paths go on this long (s) after their first touch, overlapping by their own closing, so that
    a replay that lags its path slightly still touches (``ContactParams.penetration_s``; at most 1 s)."""
    # --- road (trajectory.road)
    road_sigma_m: float = 0.3
    """Heavy smoothing of the ego path into the road centre line (RMS deviation), metres."""
    road_spacing_m: float = 2.0
    """Distance between stored centre-line waypoints, metres."""
    road_margin_m: float = 20.0
    """The centre line reaches this far past the first/last vehicle position along the road, metres."""
    default_lane_width_m: float = 3.5
    driving_side: str = "right"
    """Which side of the road traffic keeps to: ``right`` (right-hand traffic: the oncoming lanes left of the
    ego's carriageway) or ``left`` (UK, Ireland, Japan, India, Australia, ...: the oncoming lanes on its right)."""

    def __post_init__(self) -> None:
        if self.driving_side not in DRIVING_SIDES:
            raise UserError(
                f"Stage2Params.driving_side must be one of {', '.join(DRIVING_SIDES)} (got {self.driving_side!r})"
            )
        for f in fields(self):
            v = getattr(self, f.name)
            if f.name == "driving_side":
                continue
            if not isinstance(v, int | float) or isinstance(v, bool) or not math.isfinite(v):
                raise UserError(f"Stage2Params.{f.name} must be a finite number (got {v!r})")
            if v <= 0:
                raise UserError(f"Stage2Params.{f.name} must be > 0 (got {v})")
        if self.crash_overlap_s > 1.0:
            raise UserError(f"Stage2Params.crash_overlap_s must be <= 1 s (got {self.crash_overlap_s})")
        if self.ongoing_speed_ratio > 1:
            raise UserError(f"Stage2Params.ongoing_speed_ratio must be <= 1 (got {self.ongoing_speed_ratio})")
        if self.min_track_samples < 2:
            raise UserError(f"Stage2Params.min_track_samples must be >= 2 (got {self.min_track_samples})")

    def static_speed(self, category: str) -> float:
        """``static_speed_mps`` for a road user of ``category`` (m/s)."""
        return self.static_speed_pedestrian_mps if category == "pedestrian" else self.static_speed_mps

    def as_dict(self) -> dict[str, Any]:
        return asdict(self)
