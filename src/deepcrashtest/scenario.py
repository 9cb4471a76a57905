"""The versioned Scenario model: the one contract between extraction and everything after it.

A Scenario is what stage 1 (extraction) and stage 2 (trajectory processing) hand to the
simulator, the search, the exporters and the viewer. It is stored as JSON with a
``schema_version``; users edit, share and re-run these files.

Frames and units (everywhere in this file):

* World frame: origin at the ego vehicle's position at the first observed sample, x forward
  (the ego's initial heading), y left, z up. Metres.
* Time ``t``: seconds from the start of the scenario (t = 0 is the first simulated instant).
* ``yaw``: heading in the world frame, radians, counter-clockwise from +x, unwrapped.
* ``speed``: m/s along the heading, >= 0.
* Trajectories describe each vehicle's geometric centre on the ground (the centre of its
  bounding box, projected onto the road plane).
"""

from __future__ import annotations

import json
import math
import os
import re
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Annotated, Any, Literal

import numpy as np
from pydantic import (
    AfterValidator,
    BaseModel,
    BeforeValidator,
    ConfigDict,
    Field,
    ValidationError,
    ValidationInfo,
    field_validator,
    model_validator,
)

from deepcrashtest import __version__
from deepcrashtest.errors import ScenarioError
from deepcrashtest.fileio import atomic_write_text, require_file

SCHEMA_VERSION = "1.6"
"""Major.minor. A file with another major, or a newer minor, is refused; older minors are migrated on load
(:func:`migrate`)."""

#: Physical limits used by validation. Stated, never clipped silently.
MAX_SPEED_MPS = 90.0  # 324 km/h: above any road vehicle
MAX_ACCEL_MPS2 = 15.0  # ~1.5 g: above any tyre-limited braking/acceleration (impacts are cut away)
_PHYSICS_CHECKED = "physics_checked"  # validation context: id()s of trajectories whose physics passed already


@dataclass(frozen=True)
class Kinematics:
    """What a road user can do, as the simulator models it (``sim.vehicle``: kinematic bicycle with a
    steering angle/rate limit; pedestrians replayed holonomically) and as stage 2 keeps its corrections
    (``trajectory.contact``), so that a replay can follow a processed trajectory. SI units."""

    max_steer_rad: float = 0.6
    """Road-wheel angle (~34 deg)."""
    max_steer_rate_rps: float = 1.0
    """Road-wheel angle rate, rad/s."""
    max_accel_mps2: float = 4.0
    """Traction-limited acceleration."""
    max_brake_mps2: float = 9.0
    """Tyre-limited braking on dry asphalt."""
    wheelbase_fraction: float = 0.6
    """Wheelbase as a fraction of the overall length (passenger cars: 2.7 m / 4.5 m)."""
    holonomic: bool = False
    """Moves without a vehicle's kinematics (a pedestrian steps sideways, turns on the spot): only
    ``max_accel_mps2`` (any direction) applies."""


VEHICLE_KINEMATICS = Kinematics()
PEDESTRIAN_KINEMATICS = Kinematics(max_accel_mps2=3.0, max_brake_mps2=3.0, holonomic=True)


def interp_heading(t_query: np.ndarray, t: np.ndarray, yaw: np.ndarray) -> np.ndarray:
    """Heading (rad) at times ``t_query`` (s) from samples ``(t, yaw)``: linear between samples, except that a box
    read the other way round (a change of more than a quarter turn between two samples: a box fits both ways)
    flips at once instead of spinning through its neighbours; its axis turns the short way. Where no two
    samples differ by a quarter turn, exactly ``np.interp`` of the unwrapped headings."""
    return interp_heading_axis(t_query, t, *heading_axis(yaw))


def heading_axis(yaw: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The samples' headings unwrapped (rad) and their boxes' axis (rad, continuous modulo a half turn): what
    :func:`interp_heading` interpolates, for a caller that samples one track many times."""
    heading = np.unwrap(np.asarray(yaw, dtype=float))
    return heading, 0.5 * np.unwrap(2.0 * heading)


def interp_heading_axis(t_query: np.ndarray, t: np.ndarray, heading: np.ndarray, axis: np.ndarray) -> np.ndarray:
    """:func:`interp_heading` from :func:`heading_axis`'s arrays (at times ``t``, s)."""
    along = np.interp(t_query, t, axis)
    return along + math.pi * np.round((np.interp(t_query, t, heading) - along) / math.pi)


def kinematics(category: str) -> Kinematics:
    """The limits of a road user of ``category`` (a pedestrian's or a vehicle's)."""
    return PEDESTRIAN_KINEMATICS if category == "pedestrian" else VEHICLE_KINEMATICS


def brush_past(category_a: str, category_b: str) -> bool:
    """Whether two road users of these categories pass each other without a collision when their boxes touch: two
    pedestrians. People walk and stand side by side and step round each other, and their boxes (KITTI's ~0.8 x
    0.6 m) are larger than their bodies; two pedestrians are never a crash (``perception.crash_detect``). Stage 2
    does not keep them apart, the plausibility checks do not count them, the simulator counts no contact between
    them but for the scenario's collision (two walkers a user says collided: ``extract --crash FRAME:ID,ID``).
    KITTI 0019's labelled road users: people in groups touched 44 times; stage 2 dropped 11 of its 80 road users
    after 84 s of nudges that could not keep each 0.5 m from everyone."""
    return category_a == category_b == "pedestrian"


#: Physical ranges: a value outside them is a broken file, not a scenario (stated, never clipped).
MAX_CAMERA_HEIGHT_M = 100.0  # metres above the road (Camera.height_m)
MAX_COORD_M = 1e5  # |x|, |y| of any position, metres (100 km from the ego's start)
MAX_TIME_S = 1e4  # |t| of any time, seconds
MAX_YAW_RAD = 1e4  # |yaw| (unwrapped heading), radians
MIN_SIZE_M, MAX_SIZE_M = 0.1, 30.0  # length, width, height of a road user, metres
MAX_PIXELS = 1e6  # image sizes, focal lengths, principal points, pixels
MAX_NAME_CHARS = 200


def _number(v: Any) -> Any:
    """Strict numbers: a JSON string ("12.5") or a boolean is refused, numpy scalars become Python numbers."""
    if isinstance(v, np.generic):
        v = v.item()
    if isinstance(v, bool) or not isinstance(v, int | float):
        raise ValueError(f"expected a number, got {type(v).__name__} {_short(v)}")
    return v


def _integer(v: Any) -> Any:
    """Strict integers: strings, booleans and floats (even 2.0) are refused."""
    if isinstance(v, np.integer):
        v = int(v)
    if isinstance(v, bool) or not isinstance(v, int):
        raise ValueError(f"expected an integer, got {type(v).__name__} {_short(v)}")
    return v


#: What :func:`_text` refuses: control characters but tab, newline and carriage return; DEL; lone surrogates.
_BAD_CHAR = re.compile("[\x00-\x08\x0b\x0c\x0e-\x1f\x7f\ud800-\udfff]")


def _text(v: str) -> str:
    """Text written into exports (XML, CSV): no control characters but tab/newline, no lone surrogates.

    One regular-expression scan (a per-character Python loop was half the CPU of validating a Scenario: a
    search validates one per variant file it writes)."""
    bad = _BAD_CHAR.search(v)
    if bad is not None:
        raise ValueError(f"control or invalid character U+{ord(bad.group()):04X} at position {bad.start()}")
    return v


def _name(v: str) -> str:
    _text(v)
    if any(ch in "\t\n\r" for ch in v):
        raise ValueError("name must be one line")
    return v


def _short(v: Any) -> str:
    text = repr(v)
    return text if len(text) <= 40 else text[:40] + "..."


# strict finite numbers with bounds (constraints before the validator: the JSON Schema shows minimum/maximum)
Number = Annotated[float, Field(allow_inf_nan=False), BeforeValidator(_number)]
Integer = Annotated[int, BeforeValidator(_integer)]
FiniteFloat = Number
PositiveFloat = Annotated[float, Field(allow_inf_nan=False, gt=0), BeforeValidator(_number)]
NonNegFloat = Annotated[float, Field(allow_inf_nan=False, ge=0), BeforeValidator(_number)]
Coord = Annotated[float, Field(allow_inf_nan=False, ge=-MAX_COORD_M, le=MAX_COORD_M), BeforeValidator(_number)]
Time = Annotated[float, Field(allow_inf_nan=False, ge=-MAX_TIME_S, le=MAX_TIME_S), BeforeValidator(_number)]
Yaw = Annotated[float, Field(allow_inf_nan=False, ge=-MAX_YAW_RAD, le=MAX_YAW_RAD), BeforeValidator(_number)]
Size = Annotated[float, Field(allow_inf_nan=False, ge=MIN_SIZE_M, le=MAX_SIZE_M), BeforeValidator(_number)]
Pixels = Annotated[float, Field(allow_inf_nan=False, ge=-MAX_PIXELS, le=MAX_PIXELS), BeforeValidator(_number)]
# list items (trajectories hold thousands): pydantic's own strict floats (ints and floats only, no strings or
# booleans) - the same rule as the scalars, checked in Rust
CoordItem = Annotated[float, Field(strict=True, allow_inf_nan=False, ge=-MAX_COORD_M, le=MAX_COORD_M)]
TimeItem = Annotated[float, Field(strict=True, allow_inf_nan=False, ge=-MAX_TIME_S, le=MAX_TIME_S)]
YawItem = Annotated[float, Field(strict=True, allow_inf_nan=False, ge=-MAX_YAW_RAD, le=MAX_YAW_RAD)]
SpeedItem = Annotated[float, Field(strict=True, allow_inf_nan=False, ge=0)]
Distortion = Annotated[float, Field(allow_inf_nan=False, ge=-1e3, le=1e3), BeforeValidator(_number)]
LaneOffset = Annotated[float, Field(allow_inf_nan=False, ge=-100.0, le=100.0), BeforeValidator(_number)]
Text = Annotated[str, AfterValidator(_text)]
Name = Annotated[str, AfterValidator(_name), Field(min_length=1, max_length=MAX_NAME_CHARS)]

VehicleCategory = Literal["car", "van", "truck", "bus", "motorcycle", "bicycle", "pedestrian"]
"""Road-user categories. A two-wheeler and its rider are one road user (``motorcycle``, ``bicycle``);
``pedestrian`` is a person not riding."""
ROAD_USER_CATEGORIES: tuple[str, ...] = ("car", "van", "truck", "bus", "motorcycle", "bicycle", "pedestrian")
CollisionSource = Literal["video-auto", "user", "simulated", "labels"]
TrajectoryClass = Literal["D0T1", "D0T2", "D0T3", "D1T1", "D1T2", "D1T3", "D1T4"]
TRAJECTORY_CLASSES: tuple[str, ...] = ("D0T1", "D0T2", "D0T3", "D1T1", "D1T2", "D1T3", "D1T4")


class _Model(BaseModel):
    model_config = ConfigDict(extra="forbid", validate_assignment=False)


class VideoSource(_Model):
    """Where the scenario came from."""

    kind: Literal["video", "image_folder", "kitti_labels", "synthetic"] = "video"
    path: Text = Field(description="Path of the video file, image folder or label file, as given by the user")
    fps: PositiveFloat = Field(le=10000, description="Frames per second used to turn frame numbers into seconds")
    frame_count: Integer = Field(ge=0, le=10**9, description="Number of frames read")
    width: Integer = Field(gt=0, le=MAX_PIXELS, description="Frame width, pixels")
    height: Integer = Field(gt=0, le=MAX_PIXELS, description="Frame height, pixels")
    sha256: Text | None = Field(default=None, description="SHA-256 of the source file, hex")
    time_offset_s: Time = Field(
        default=0.0,
        description="Scenario time of video time 0 (video time = frame / fps): scenario time = video time + "
        "time_offset_s. The one time mapping used by the viewer, the report, the fidelity evaluation and the "
        "exports (Scenario.video_time / scenario_time / video_frame)",
    )
    frame_rate_note: Text | None = Field(
        default=None,
        description="Caveat on the frame rate (uploaded videos may be re-timed: relative speed trends are "
        "what extraction gets right; absolute speeds scale with the true frame rate)",
    )
    frame_times: list[FiniteFloat] | None = Field(
        default=None,
        description="Video time (s) of each frame, by index, where the file's frame rate varies (a phone's "
        "variable-frame-rate recording, dropped frames): video time = frame_times[frame] instead of frame / fps "
        "(fps is then the mean; frames beyond the list continue at it). None: frame / fps (schema 1.6)",
    )

    @model_validator(mode="after")
    def _increasing_frame_times(self) -> VideoSource:
        t = self.frame_times
        if t is not None and (not t or (len(t) > 1 and not bool(np.all(np.diff(t) > 0)))):
            raise ValueError("frame_times must be a non-empty list of increasing video times")
        return self


def frame_video_time(frame: int, fps: float, frame_times: Sequence[float] | None) -> float:
    """Video time (s) of video frame ``frame``: ``frame / fps`` at a constant rate (``frame_times`` None, and for a
    negative index), else ``frame_times[frame]``, frames past the list continuing at ``fps`` from its last time
    (``VideoSource.frame_times``; :meth:`Scenario.frame_time`, the monocular filter's clock)."""
    if frame_times is None or frame < 0:
        return float(frame) / fps
    if frame < len(frame_times):
        return float(frame_times[frame])
    return float(frame_times[-1]) + (frame - len(frame_times) + 1) / fps


class CameraAttitude(_Model):
    """The camera's pitch and roll frame by frame (a car pitches when it brakes, rolls and bounces on the road;
    a road's grade changes under the road users): changes added to ``Camera.pitch_rad`` / ``roll_rad`` at each
    video time (seconds, ``frame / fps``: independent of the scenario's time offset), linear in between, the
    ends held outside. ``yaw_rad`` (optional, schema 1.5): the camera's yaw relative to the ego's heading, added
    to ``Camera.yaw_rad``: stage 2 gives the processed ego the heading its replayed vehicle has on its path, and
    the camera keeps the yaw the video measured through it (:mod:`deepcrashtest.pipeline.stage2`)."""

    video_t: list[FiniteFloat] = Field(description="Video times, seconds, increasing")
    pitch_rad: list[FiniteFloat] = Field(description="Downward pitch added to Camera.pitch_rad, radians")
    roll_rad: list[FiniteFloat] = Field(description="Roll added to Camera.roll_rad, radians")
    yaw_rad: list[FiniteFloat] | None = Field(
        default=None, description="Yaw (to the left) added to Camera.yaw_rad, radians (None: none)"
    )

    @model_validator(mode="after")
    def _same_length(self) -> CameraAttitude:
        n = len(self.video_t)
        if n == 0 or len(self.pitch_rad) != n or len(self.roll_rad) != n:
            raise ValueError("video_t, pitch_rad and roll_rad need the same (non-zero) length")
        if self.yaw_rad is not None and len(self.yaw_rad) != n:
            raise ValueError("yaw_rad needs the length of video_t")
        if n > 1 and not bool(np.all(np.diff(self.video_t) > 0)):
            raise ValueError("video_t must increase")
        if max(map(abs, [*self.pitch_rad, *self.roll_rad, *(self.yaw_rad or [])])) > 0.5:
            raise ValueError("pitch/roll/yaw changes above 0.5 rad")
        return self


class Camera(_Model):
    """Pinhole camera. Camera frame: x right, y down, z forward (metres); image u right, v down (pixels)."""

    fx: PositiveFloat = Field(le=MAX_PIXELS, description="Focal length along u, pixels")
    fy: PositiveFloat = Field(le=MAX_PIXELS, description="Focal length along v, pixels")
    cx: Pixels = Field(description="Principal point u, pixels")
    cy: Pixels = Field(description="Principal point v, pixels")
    distortion: list[Distortion] = Field(
        default_factory=list, description="OpenCV distortion coefficients k1,k2,p1,p2[,k3]"
    )
    height_m: PositiveFloat = Field(
        default=1.3, le=MAX_CAMERA_HEIGHT_M, description="Camera height above the road, metres"
    )
    pitch_rad: FiniteFloat = Field(
        default=0.0, ge=-math.pi / 2, le=math.pi / 2, description="Downward pitch of the optical axis, radians"
    )
    roll_rad: FiniteFloat = Field(
        default=0.0, ge=-math.pi, le=math.pi, description="Roll about the optical axis, radians"
    )
    yaw_rad: FiniteFloat = Field(
        default=0.0,
        ge=-math.pi,
        le=math.pi,
        description="Yaw of the optical axis to the left of the ego's heading, radians (schema 1.5)",
    )
    forward_offset_m: FiniteFloat = Field(
        default=0.5,
        ge=-MAX_SIZE_M,
        le=MAX_SIZE_M,
        description="Camera position ahead of the ego vehicle's centre, metres",
    )
    intrinsics_source: Literal["user", "chessboard", "fov", "default", "kitti_calib", "self_calibration"] = "default"
    pitch_source: Literal["user", "vanishing_point", "flow_foe", "default", "kitti_calib", "self_calibration"] = (
        "default"
    )
    height_source: Literal["user", "default", "kitti_calib", "self_calibration"] = "default"
    focal_sigma_px: NonNegFloat | None = Field(
        default=None, description="1-sigma uncertainty of fx/fy, pixels (None: not estimated)"
    )
    horizon_sigma_px: NonNegFloat | None = Field(
        default=None, description="1-sigma uncertainty of the horizon row (the pitch), pixels (None: not estimated)"
    )
    height_sigma_m: NonNegFloat | None = Field(
        default=None, description="1-sigma uncertainty of height_m, metres (None: not estimated)"
    )
    attitude: CameraAttitude | None = Field(
        default=None, description="Per-frame pitch/roll changes (None: the camera keeps pitch_rad/roll_rad)"
    )

    def matrix(self) -> np.ndarray:
        """3x3 intrinsic matrix K."""
        return np.array([[self.fx, 0.0, self.cx], [0.0, self.fy, self.cy], [0.0, 0.0, 1.0]])

    def horizon_v(self) -> float:
        """Image row of the horizon, pixels (downward pitch puts the horizon above ``cy``)."""
        return self.cy - self.fy * math.tan(self.pitch_rad)

    def at_video_time(self, video_t: float) -> Camera:
        """This camera with its pitch, roll and yaw at video time ``video_t`` (s) and no attitude series."""
        if self.attitude is None:
            return self
        a = self.attitude
        dp = float(np.interp(video_t, a.video_t, a.pitch_rad))
        dr = float(np.interp(video_t, a.video_t, a.roll_rad))
        dy = float(np.interp(video_t, a.video_t, a.yaw_rad)) if a.yaw_rad is not None else 0.0
        update = {"pitch_rad": self.pitch_rad + dp, "roll_rad": self.roll_rad + dr, "attitude": None}
        return self.model_copy(update=update | ({"yaw_rad": self.yaw_rad + dy} if dy else {}))


class SplineParams(_Model):
    """A 2D B-spline in time: x(t), y(t) = BSpline(knots, cx|cy, degree). The search perturbs cx, cy."""

    knots: list[TimeItem] = Field(description="Knot vector, seconds (scipy.interpolate.BSpline layout)")
    cx: list[CoordItem] = Field(description="Control-point x coordinates, metres (world frame)")
    cy: list[CoordItem] = Field(description="Control-point y coordinates, metres (world frame)")
    degree: Integer = Field(default=3, ge=1, le=5)

    @model_validator(mode="after")
    def _shape(self) -> SplineParams:
        n = len(self.knots) - self.degree - 1
        if n < self.degree + 1 or len(self.cx) != n or len(self.cy) != n:
            raise ValueError(
                f"spline needs len(cx) == len(cy) == len(knots) - degree - 1 >= degree + 1 "
                f"(got knots={len(self.knots)}, cx={len(self.cx)}, cy={len(self.cy)}, degree={self.degree})"
            )
        if any(b < a for a, b in zip(self.knots, self.knots[1:], strict=False)):
            raise ValueError("spline knots must be non-decreasing")
        return self


class Trajectory(_Model):
    """Time-indexed states of one vehicle's centre, column-wise (all lists have the same length)."""

    t: list[TimeItem] = Field(description="Time, seconds, strictly increasing")
    x: list[CoordItem] = Field(description="World x (forward), metres")
    y: list[CoordItem] = Field(description="World y (left), metres")
    yaw: list[YawItem] = Field(description="Heading, radians CCW from world +x, unwrapped")
    speed: list[SpeedItem] = Field(description="Speed along the heading, m/s")
    observed: list[bool] | None = Field(
        default=None, description="Per sample: true where seen in the video, false where extrapolated"
    )

    @model_validator(mode="after")
    def _consistent(self) -> Trajectory:
        n = len(self.t)
        if n == 0:
            raise ValueError("trajectory has no samples")
        for name in ("x", "y", "yaw", "speed"):
            if len(getattr(self, name)) != n:
                raise ValueError(f"{name} has {len(getattr(self, name))} samples but t has {n}")
        if self.observed is not None and len(self.observed) != n:
            raise ValueError(f"observed has {len(self.observed)} samples but t has {n}")
        t = np.asarray(self.t)
        bad = np.nonzero(np.diff(t) <= 0)[0]
        if bad.size:
            i = int(bad[0]) + 1
            raise ValueError(f"t must increase strictly: t[{i}]={t[i]} follows t[{i - 1}]={t[i - 1]}")
        v = np.asarray(self.speed)
        if v.size and v.max() > MAX_SPEED_MPS:
            i = int(v.argmax())
            raise ValueError(f"speed[{i}]={v[i]:.1f} m/s exceeds the physical limit {MAX_SPEED_MPS} m/s")
        return self

    def __len__(self) -> int:
        return len(self.t)

    def arrays(self) -> dict[str, np.ndarray]:
        """Columns as float64 arrays: t, x, y, yaw, speed."""
        return {k: np.asarray(getattr(self, k), dtype=float) for k in ("t", "x", "y", "yaw", "speed")}

    @classmethod
    def from_arrays(
        cls,
        t: Any,
        x: Any,
        y: Any,
        yaw: Any,
        speed: Any,
        observed: Any | None = None,
    ) -> Trajectory:
        """Build from array-likes (converted to plain Python floats)."""

        def fl(a: Any) -> list[float]:
            return [float(v) for v in np.asarray(a, dtype=float).ravel()]

        return cls(
            t=fl(t),
            x=fl(x),
            y=fl(y),
            yaw=fl(yaw),
            speed=fl(speed),
            observed=None if observed is None else [bool(b) for b in np.asarray(observed).ravel()],
        )

    def max_abs_accel(self) -> tuple[float, int]:
        """Largest |dv/dt| between consecutive samples (m/s^2) and the index where it occurs."""
        if len(self.t) < 2:
            return 0.0, 0
        a = np.abs(np.diff(np.asarray(self.speed)) / np.diff(np.asarray(self.t)))
        i = int(a.argmax())
        return float(a[i]), i + 1

    def accel_problem(self, label: str) -> str | None:
        """Why a processed Scenario refuses this trajectory as road user ``label``'s (its largest |dv/dt| above
        ``MAX_ACCEL_MPS2`` m/s^2), or None: the text of the Scenario's own check."""
        amax, i = self.max_abs_accel()
        if amax > MAX_ACCEL_MPS2:
            return (
                f"{label}.trajectory: |acceleration| {amax:.1f} m/s^2 at sample {i} exceeds the "
                f"physical limit {MAX_ACCEL_MPS2} m/s^2"
            )
        return None

    def state_at(self, t: float) -> dict[str, float]:
        """Linearly interpolated state at time ``t`` (clamped to the trajectory's span)."""
        a = self.arrays()
        yaw = np.interp(t, a["t"], a["yaw"])
        return {
            "t": float(t),
            "x": float(np.interp(t, a["t"], a["x"])),
            "y": float(np.interp(t, a["t"], a["y"])),
            "yaw": float(yaw),
            "speed": float(np.interp(t, a["t"], a["speed"])),
        }


class Vehicle(_Model):
    """One vehicle (the ego or an agent) with its size, class and trajectory."""

    id: Integer = Field(ge=0, le=10**9, description="Unique within the scenario; the ego is 0")
    category: VehicleCategory = "car"
    length: Size = Field(default=4.5, description="Metres")
    width: Size = Field(default=1.8, description="Metres")
    height: Size = Field(default=1.5, description="Metres")
    confidence: Number = Field(default=1.0, ge=0.0, le=1.0, description="Mean detection confidence")
    trajectory_class: TrajectoryClass | None = Field(
        default=None, description="D0T1..D1T4 for agents (see trajectory.classify); None for the ego"
    )
    first_frame: Integer = Field(
        default=0, ge=0, le=10**9, description="First video frame where the vehicle is observed"
    )
    last_frame: Integer = Field(default=0, ge=0, le=10**9, description="Last video frame where the vehicle is observed")
    start_delay_s: NonNegFloat = Field(
        default=0.0, le=MAX_TIME_S, description="Seconds after t=0 at which the vehicle enters the simulation"
    )
    trajectory: Trajectory
    spline: SplineParams | None = Field(
        default=None, description="Spline parameterisation of the path (perturbed by the search)"
    )

    @model_validator(mode="after")
    def _frames(self) -> Vehicle:
        if self.last_frame < self.first_frame:
            raise ValueError(f"last_frame {self.last_frame} is before first_frame {self.first_frame}")
        return self


class LaneTimeline(_Model):
    """The ego's lane over time, from the lane stage."""

    t: list[TimeItem] = Field(description="Seconds")
    lane_index: list[Annotated[Integer, Field(ge=0, le=100)]] = Field(description="0 = rightmost lane")
    lateral_offset: list[LaneOffset] = Field(description="Ego centre left of its lane centre, metres")

    @model_validator(mode="after")
    def _same_length(self) -> LaneTimeline:
        if not (len(self.t) == len(self.lane_index) == len(self.lateral_offset)):
            raise ValueError("t, lane_index and lateral_offset must have the same length")
        return self


class Road(_Model):
    """Road centre line and lanes, world frame.

    The ego's carriageway: ``lane_count`` lanes of ``lane_width`` in the ego's direction (0 = rightmost).
    Beyond its edge next to the other direction (the left edge in right-hand traffic, the right edge where
    ``driving_side`` is ``left``), ``median_width`` metres on, ``oncoming_lane_count`` lanes of the same width
    carry the opposite direction.
    """

    centerline_x: list[CoordItem] = Field(description="Waypoint x, metres")
    centerline_y: list[CoordItem] = Field(description="Waypoint y, metres")
    lane_width: PositiveFloat = Field(default=3.5, ge=1.0, le=20.0, description="Metres")
    lane_count: Integer = Field(default=2, ge=1, le=12)
    ego_lane: Integer = Field(default=0, ge=0, description="Lane of the ego at t=0, 0 = rightmost")
    oncoming_lane_count: Integer = Field(
        default=0,
        ge=0,
        le=12,
        description="Lanes of the opposite direction, beside the ego's carriageway (0 = a one-way road)",
    )
    driving_side: Literal["right", "left"] = Field(
        default="right",
        description="The side traffic keeps to: right (the oncoming lanes left of the ego's carriageway) or left "
        "(UK, Japan, India, Australia, ...: the oncoming lanes on its right)",
    )
    median_width: NonNegFloat = Field(
        default=0.0,
        le=50.0,
        description="Metres between the ego's carriageway and the oncoming lanes (0 = one line between them)",
    )
    source: Literal["ego_path", "ego_path+oncoming", "lanes", "road_users", "user"] = Field(
        default="ego_path",
        description="ego_path: along the ego path (lane width assumed); lanes: lane lines seen in the video; "
        "road_users: no lanes seen, width and lane count from the spread of the road users' paths; user: edited",
    )
    lane_timeline: LaneTimeline | None = None

    @model_validator(mode="after")
    def _waypoints(self) -> Road:
        if len(self.centerline_x) != len(self.centerline_y):
            raise ValueError("centerline_x and centerline_y must have the same length")
        if len(self.centerline_x) < 2:
            raise ValueError("road needs at least 2 centre-line waypoints")
        if self.ego_lane >= self.lane_count:
            raise ValueError(f"ego_lane {self.ego_lane} is outside lane_count {self.lane_count}")
        return self

    def centerline(self) -> np.ndarray:
        """(N, 2) array of waypoints, metres."""
        return np.column_stack([self.centerline_x, self.centerline_y]).astype(float)


class Collision(_Model):
    """The collision seen in the video (or found by the simulator) between two road users.

    The participants are ``other_id`` and ``agent_id``; either may be the ego (id 0), and a third-party
    crash names two agents.
    """

    time_s: Time = Field(description="Seconds, scenario time")
    agent_id: Integer = Field(ge=0, description="The second participant (the road user the ego hits)")
    other_id: Integer = Field(default=0, ge=0, description="The first participant (the ego unless stated)")
    source: CollisionSource = Field(
        default="video-auto",
        description="video-auto = detected in the video; user = given by the user; simulated = found by the "
        "simulator; labels = from dataset labels",
    )
    confidence: Number | None = Field(default=None, ge=0.0, le=1.0, description="Detection confidence, 0-1")
    x: Coord | None = Field(default=None, description="Impact point x, metres")
    y: Coord | None = Field(default=None, description="Impact point y, metres")
    relative_speed: NonNegFloat | None = Field(default=None, le=2 * MAX_SPEED_MPS, description="m/s at first contact")

    @model_validator(mode="after")
    def _two_participants(self) -> Collision:
        if self.agent_id == self.other_id:
            raise ValueError(f"collision needs two different participants (both are {self.agent_id})")
        return self

    @property
    def participants(self) -> tuple[int, int]:
        """The two road users' ids, (other_id, agent_id)."""
        return (self.other_id, self.agent_id)

    @property
    def involves_ego(self) -> bool:
        """True when the ego (id 0) is one of the participants."""
        return 0 in self.participants


class Provenance(_Model):
    """How the scenario was made, so it can be made again."""

    package_version: Text = __version__
    command: Text = ""
    parameters: dict[str, Any] = Field(default_factory=dict)
    seed: Integer = Field(default=0, ge=0, description="Seed of every random choice (non-negative)")
    history: list[Text] = Field(default_factory=list, description="Edits applied after creation, in order")


class Scenario(_Model):
    """A crash scenario: source, camera, ego, agents, road, collision, provenance."""

    schema_version: str = SCHEMA_VERSION
    name: Name = Field(default="scenario", description="One line, no control characters, at most 200 characters")
    stage: Literal["raw", "processed"] = Field(
        default="processed",
        description="raw = world-frame tracks straight from extraction; processed = after stage 2",
    )
    source: VideoSource
    camera: Camera
    ego: Vehicle
    agents: list[Vehicle] = Field(default_factory=list)
    road: Road
    collision: Collision | None = None
    provenance: Provenance = Field(default_factory=Provenance)
    warnings: list[Text] = Field(default_factory=list, description="Caveats a user should read")

    @field_validator("schema_version")
    @classmethod
    def _version(cls, v: str) -> str:
        check_schema_version(v)
        return v

    @model_validator(mode="after")
    def _ids_and_physics(self, info: ValidationInfo) -> Scenario:
        ids = [self.ego.id] + [a.id for a in self.agents]
        if len(set(ids)) != len(ids):
            dup = sorted({i for i in ids if ids.count(i) > 1})
            raise ValueError(f"vehicle ids must be unique (duplicated: {dup})")
        if self.stage == "processed":
            checked = (info.context or {}).get(_PHYSICS_CHECKED, ())
            for label, veh in [("ego", self.ego)] + [(f"agents[id={a.id}]", a) for a in self.agents]:
                if id(veh.trajectory) in checked:  # evolve: this processed scenario's own, checked when it was made
                    continue
                problem = veh.trajectory.accel_problem(label)
                if problem is not None:
                    raise ValueError(problem)
        if self.collision is not None:
            for field in ("agent_id", "other_id"):
                vid = getattr(self.collision, field)
                if vid not in ids:
                    raise ValueError(f"collision.{field} {vid} is not a road user of this scenario")
        return self

    # ------------------------------------------------------------------ change
    def evolve(self, **changes: Any) -> Scenario:
        """A validated copy with top-level fields replaced: the one way to change a Scenario.

        Values may be models or plain dicts/lists; the result is validated as a whole (every changed field's
        checks and the cross-field physics), so an invalid change raises :class:`ScenarioError` naming the field.
        The fields not changed are this scenario's own, already validated models, taken as they are (the copy
        shares them, as ``model_copy`` does; a search writes one variant per file and re-validating the agents'
        trajectories of each was most of its cost).
        """
        unknown = sorted(set(changes) - set(type(self).model_fields))
        if unknown:
            raise ScenarioError(f"unknown Scenario field(s) {unknown}")
        data = {key: getattr(self, key) for key in type(self).model_fields}
        for key, value in changes.items():
            data[key] = _plain(value)
        # the physics check of a processed scenario's unchanged vehicles passed when this one was validated (their
        # trajectories are the same objects in the copy): a search's variant file checked its ~10 vehicles again
        checked = {id(v.trajectory) for v in [self.ego, *self.agents]} if self.stage == "processed" else set()
        return Scenario.from_dict(data, origin="scenario", context={_PHYSICS_CHECKED: checked})

    # ------------------------------------------------------------------ time
    def video_time(self, t: Any) -> Any:
        """Video time (s, frame / fps) of scenario time ``t`` (s); arrays allowed."""
        if isinstance(t, int | float | np.floating | np.integer):
            return float(t) - self.source.time_offset_s
        return np.asarray(t, dtype=float) - self.source.time_offset_s

    def scenario_time(self, video_t: Any) -> Any:
        """Scenario time (s) of video time ``video_t`` (s); arrays allowed."""
        if isinstance(video_t, int | float | np.floating | np.integer):
            return float(video_t) + self.source.time_offset_s
        return np.asarray(video_t, dtype=float) + self.source.time_offset_s

    def video_frame(self, t: float) -> int | None:
        """Video frame index shown at scenario time ``t``, or None before the first / after the last frame (the
        last frame whose video time is not after ``t``: ``floor(video time x fps)`` at a constant rate, by
        ``source.frame_times`` where the rate varies)."""
        times, vt, fps = self.source.frame_times, float(self.video_time(t)), self.source.fps
        if times is None:
            f = int(math.floor(vt * fps + 1e-6))
        elif vt + 1e-6 >= times[-1] + 1.0 / fps:  # beyond the listed frames: they continue at the mean rate
            f = len(times) - 1 + int(math.floor((vt - times[-1]) * fps + 1e-6))
        else:
            f = int(np.searchsorted(times, vt + 1e-6, side="right")) - 1 if vt >= times[0] - 1e-6 else -1
        if f < 0 or (self.source.frame_count > 0 and f >= self.source.frame_count):
            return None
        return f

    def frame_time(self, frame: int) -> float:
        """Scenario time (s) of video frame ``frame``: ``frame / fps`` of video time, or ``source.frame_times``
        where the rate varies (frames beyond them continue at the mean rate: :func:`frame_video_time`)."""
        return frame_video_time(frame, self.source.fps, self.source.frame_times) + self.source.time_offset_s

    # ------------------------------------------------------------------ access
    def vehicles(self) -> list[Vehicle]:
        """Ego first, then agents."""
        return [self.ego, *self.agents]

    def vehicle(self, vehicle_id: int) -> Vehicle:
        for v in self.vehicles():
            if v.id == vehicle_id:
                return v
        raise KeyError(vehicle_id)

    def class_counts(self) -> dict[str, int]:
        """Agents per trajectory class (D0T1..D1T4, ``unclassified`` for none), sorted by class."""
        counts: dict[str, int] = {}
        for a in self.agents:
            key = a.trajectory_class or "unclassified"
            counts[key] = counts.get(key, 0) + 1
        return dict(sorted(counts.items()))

    def duration(self) -> float:
        """Last sample time over all vehicles, seconds."""
        return max(v.trajectory.t[-1] for v in self.vehicles())

    # ------------------------------------------------------------------ I/O
    def to_json(self) -> str:
        return self.model_dump_json(indent=1) + "\n"

    def save(self, path: str | os.PathLike[str], force: bool = False) -> Path:
        """Write JSON atomically; refuse to overwrite an existing file unless ``force``."""
        return atomic_write_text(path, self.to_json(), force=force)

    @classmethod
    def from_dict(cls, data: Any, origin: str = "scenario", context: dict[str, Any] | None = None) -> Scenario:
        """Validate a decoded JSON object; errors name the field (``agents.2.trajectory.t: ...``). ``context``:
        pydantic's validation context (:meth:`evolve`'s already checked trajectories)."""
        if not isinstance(data, dict):
            raise ScenarioError(f"{origin}: expected a JSON object, got {type(data).__name__}")
        if "schema_version" not in data:
            raise ScenarioError(f"{origin}: missing schema_version (not a DeepCrashTest scenario?)")
        try:
            check_schema_version(str(data["schema_version"]))
            return cls.model_validate(migrate(data), context=context)
        except ValidationError as exc:
            raise ScenarioError(f"{origin}: {format_validation_error(exc)}") from None
        except ValueError as exc:
            raise ScenarioError(f"{origin}: {exc}") from None

    @classmethod
    def load(cls, path: str | os.PathLike[str]) -> Scenario:
        """Read and validate a Scenario JSON file."""
        p = require_file(path, "scenario file")
        try:
            text = p.read_text(encoding="utf-8")
        except UnicodeDecodeError:
            raise ScenarioError(f"{p}: not a text file") from None
        try:
            data = json.loads(text, parse_constant=_reject_constant)
        except json.JSONDecodeError as exc:
            raise ScenarioError(f"{p}: invalid JSON at line {exc.lineno} column {exc.colno}: {exc.msg}") from None
        except ValueError as exc:
            raise ScenarioError(f"{p}: {exc}") from None
        except RecursionError:
            raise ScenarioError(f"{p}: JSON nested too deeply (not a scenario file)") from None
        try:
            return cls.from_dict(data, origin=str(p))
        except RecursionError:
            raise ScenarioError(f"{p}: JSON nested too deeply (not a scenario file)") from None


def _plain(value: Any) -> Any:
    """Models to plain data (recursively through lists/dicts) so a changed field is validated afresh."""
    if isinstance(value, BaseModel):
        return value.model_dump()
    if isinstance(value, list | tuple):
        return [_plain(v) for v in value]
    if isinstance(value, dict):
        return {k: _plain(v) for k, v in value.items()}
    return value


def migrate(data: dict[str, Any]) -> dict[str, Any]:
    """Upgrade a decoded scenario of an older minor schema version to :data:`SCHEMA_VERSION` (a copy).

    1.0 -> 1.1: the video/scenario time mapping moves from ``provenance.parameters.video_time_offset_s``
    (processed files) and the ego's first frame into ``source.time_offset_s``; collisions get
    ``source="video-auto"`` (the default). 1.1 -> 1.2: ``camera.attitude`` (optional) is new; nothing moves.
    1.2 -> 1.3: ``road.oncoming_lane_count`` and ``road.median_width`` are new (default 0: the road as read
    before, the ego's direction only); nothing moves. 1.3 -> 1.4: ``road.driving_side`` is new (default
    ``right``, what every earlier file described); nothing moves. 1.4 -> 1.5: ``camera.yaw_rad`` and
    ``camera.attitude.yaw_rad`` are new (default none: the camera looks along the ego's heading); nothing moves.
    1.5 -> 1.6: ``source.frame_times`` is new (default none: frame / fps, what every earlier file meant); nothing moves.
    """
    if str(data.get("schema_version")) not in ("1.0", "1.1", "1.2", "1.3", "1.4", "1.5"):
        return data
    out = dict(data)
    if str(data.get("schema_version")) in ("1.1", "1.2", "1.3", "1.4", "1.5"):
        out["schema_version"] = SCHEMA_VERSION
        return out
    out["schema_version"] = SCHEMA_VERSION
    src = out.get("source")
    ego = out.get("ego")
    if isinstance(src, dict) and "time_offset_s" not in src:
        fps = src.get("fps")
        first = ego.get("first_frame", 0) if isinstance(ego, dict) else 0
        prov = out.get("provenance")
        params = prov.get("parameters", {}) if isinstance(prov, dict) else {}
        lead = params.get("video_time_offset_s", 0.0) if isinstance(params, dict) else 0.0
        if isinstance(fps, int | float) and fps > 0 and isinstance(first, int) and isinstance(lead, int | float):
            out["source"] = dict(src, time_offset_s=float(lead) - first / float(fps))
    return out


def _reject_constant(name: str) -> float:
    raise ValueError(f"non-finite number {name} is not allowed")


def check_schema_version(version: str) -> None:
    """Raise ValueError unless ``version`` can be read by this package."""
    try:
        major, minor = (int(p) for p in version.split("."))
    except ValueError:
        raise ValueError(f"schema_version {version!r} is not of the form MAJOR.MINOR") from None
    cur_major, cur_minor = (int(p) for p in SCHEMA_VERSION.split("."))
    if major != cur_major or minor > cur_minor:
        raise ValueError(
            f"schema_version {version} is not supported (this deepcrashtest {__version__} reads "
            f"{cur_major}.0-{SCHEMA_VERSION})"
        )


def format_validation_error(exc: ValidationError, limit: int = 3) -> str:
    """One line naming the field(s): ``ego.trajectory.t.3: Input should be a finite number``."""
    parts = []
    for err in exc.errors(include_url=False, include_context=False, include_input=False)[:limit]:
        loc = ".".join(str(p) for p in err["loc"]) or "(root)"
        msg = err["msg"].removeprefix("Value error, ")
        parts.append(f"{loc}: {msg}")
    more = exc.error_count() - limit
    return "; ".join(parts) + (f" (+{more} more)" if more > 0 else "")


def json_schema() -> dict[str, Any]:
    """The JSON Schema of the Scenario file."""
    schema = Scenario.model_json_schema()
    schema["$schema"] = "https://json-schema.org/draft/2020-12/schema"
    schema["title"] = f"DeepCrashTest Scenario {SCHEMA_VERSION}"
    return schema


def wrap_angle(a: Any) -> Any:
    """Wrap radians to (-pi, pi]."""
    return (np.asarray(a) + math.pi) % (2 * math.pi) - math.pi
