"""The ego's speed known apart from image motion (a user's ``--ego-speed``, the GPS speed burned into the picture)
and the focal length it gives an uncalibrated camera.

Image ego-motion's metric scale is the road plane's, proportional to focal length x camera height; every road
user's distance (box sizes, bottom rows) goes with the same focal length. Once the camera height is read from the
boxes, the focal length that gives the image ego-motion the known speed is one more term of the focal-length
fusion (:func:`deepcrashtest.geometry.selfcalib.combine_focal`), and the whole scene takes the metric scale.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace
from typing import Any

import numpy as np

from deepcrashtest.geometry.egomotion import EgoMotion, path_along
from deepcrashtest.scenario import Camera

#: Relative 1-sigma of the focal length read from a known speed: a GPS speed to +-1-2 km/h, and the median of the
#: image ego-motion's speed readings, which the focal length scales.
USER_SPEED_REL = 0.05
#: Speed readings (m/s) under this are the ego standing: they tell nothing of the scale.
USER_SPEED_MIN_MPS = 1.0
#: The horizontal fields of view (deg) a known speed may give the camera. Outside them the image ego-motion's speed is
#: what is off (a snowy or hidden road read as a crawl), not the focal length, and the known speed is not used:
#: cropped dashcam clips reach ~21 deg (ccd_000014: 3,404 px over 1,280), wide-angle lenses ~150.
MIN_HFOV_DEG = 15.0
MAX_HFOV_DEG = 150.0


@dataclass(frozen=True)
class KnownSpeed:
    """The ego's speed known apart from the images: ``mps`` (m/s) from each of ``times_s`` (video time, s) until
    the next reading (the first also before it). ``source``: ``"user"`` (``extract --ego-speed``, one constant) or
    ``"overlay"`` (read off the picture, :mod:`deepcrashtest.perception.overlay`); ``what``: the speed as the
    notes say it."""

    times_s: np.ndarray
    mps: np.ndarray
    source: str
    what: str

    @classmethod
    def constant(cls, mps: float) -> KnownSpeed:
        """A speed the user gave (m/s), about constant over the clip."""
        return cls(np.zeros(1), np.array([mps]), "user", f"{3.6 * mps:g} km/h")

    def summary(self) -> dict[str, Any]:
        """Plain JSON-able figures: the source, what the notes say, and each reading's time (s) and km/h."""
        return {
            "source": self.source,
            "what": self.what,
            "times_s": [round(float(t), 4) for t in self.times_s],
            "kmh": [round(3.6 * float(v), 2) for v in self.mps],
        }

    def at(self, times_s: np.ndarray) -> np.ndarray:
        """The speed (m/s) in force at each of ``times_s`` (s)."""
        idx = np.searchsorted(self.times_s, np.asarray(times_s, dtype=float), side="right") - 1
        return self.mps[np.clip(idx, 0, len(self.mps) - 1)]


def focal_from_ego_speed(
    ego: EgoMotion, camera: Camera, height_m: float, known: KnownSpeed
) -> tuple[float, float, int] | None:
    """(focal length px, relative sigma, frames used) that gives image ego-motion the known speed.

    ``ego`` was measured with ``camera``'s focal length and height; at the calibrated height ``height_m`` its
    median speed over the frames where both it and the known speed move is ``v``, against the known speed's median
    ``s`` over the same frames: the focal length ``camera.fy x s / v`` gives it the known speed. None where the
    video shows the ego standing (fewer than 3 such frames)."""
    along = known.at(ego.t)
    moving = np.isfinite(ego.speed) & (ego.speed >= USER_SPEED_MIN_MPS) & (along >= USER_SPEED_MIN_MPS)
    if int(moving.sum()) < 3:
        return None
    measured = float(np.median(ego.speed[moving])) * height_m / camera.height_m
    return camera.fy * float(np.median(along[moving])) / measured, USER_SPEED_REL, int(moving.sum())


def hfov_deg(focal_px: float, width_px: float) -> float:
    """The horizontal field of view (deg) of a pinhole camera of focal length ``focal_px`` over ``width_px``."""
    return math.degrees(2.0 * math.atan(0.5 * width_px / focal_px))


def ego_speed_term(
    ego: EgoMotion | None,
    camera: Camera,
    speed: KnownSpeed | None,
    scaled_by_height: bool,
    height_m: float,
    notes: list[str],
    warnings: list[str],
    width_px: float | None = None,
) -> tuple[tuple[float, float, int] | None, bool]:
    """:func:`focal_from_ego_speed`'s term at the calibrated camera height ``height_m`` (m), and whether the image
    ego-motion's speed is to be replaced by the known one (:func:`with_known_speed`). No term without a known speed
    or an image ego-motion scaled by the camera height, or where the ego stands. Where the focal length it gives is
    no dashcam's (a field of view over the image's ``width_px`` outside :data:`MIN_HFOV_DEG` - :data:`MAX_HFOV_DEG`)
    the image ego-motion's speed is what is off (a road it could not read): no term, and the speed is replaced.
    Said in ``notes`` (and in ``warnings`` where a speed cannot be used though the ego moves, or the user gave
    it)."""
    if speed is None or ego is None or not scaled_by_height:
        return None, False
    found = focal_from_ego_speed(ego, camera, height_m, speed)
    given = "given" if speed.source == "user" else "read off the picture's overlay"
    hfov = hfov_deg(found[0], width_px) if found is not None and width_px else None
    if found is not None and hfov is not None and not MIN_HFOV_DEG <= hfov <= MAX_HFOV_DEG:
        notes.append(f"the ego's speed {given}, {speed.what}, not used: it would make the field of view {hfov:.0f} deg")
        warnings.append(
            f"the ego's speed {given} ({speed.what}) would make the camera's field of view {hfov:.0f} deg "
            f"(focal length {found[0]:.0f} px): no dashcam's, so the image ego-motion's speed is what is off (road "
            "textureless, hidden or blurred): the ego drives at that speed, the road users' distances keep the "
            "images' scale; check them against the video or give the camera (--camera, --hfov)"
        )
        return None, True
    if found is not None:
        notes.append(
            f"the ego's speed {given}, {speed.what}: focal length {found[0]:.0f} px from the image "
            f"ego-motion's median speed over {found[2]} moving frames at a camera height of {height_m:.2f} m"
        )
        return found, False
    notes.append(f"the ego's speed {given}, {speed.what}, not used: the ego stands")
    if speed.source == "user":
        warnings.append(
            f"--ego-speed {speed.what} not used: the video shows the ego standing (its image "
            f"ego-motion under {USER_SPEED_MIN_MPS:g} m/s), which tells nothing of the scale"
        )
    return None, False


def with_known_speed(ego: EgoMotion, speed: KnownSpeed) -> EgoMotion:
    """``ego`` with its speed replaced by the known one (linear between its readings, held before the first and after
    the last), its path integrated again along its own headings (each step at the mean speed of its frame pair and the
    middle of its yaw)."""
    if len(ego.t) == 0:
        return ego
    v = np.interp(ego.t, speed.times_s, speed.mps)
    if len(ego.t) < 2:
        return replace(ego, speed=v)
    step = 0.5 * (v[1:] + v[:-1]) * np.diff(ego.t)
    x, y = path_along(float(ego.x[0]), float(ego.y[0]), step, 0.5 * (ego.yaw[1:] + ego.yaw[:-1]))
    return replace(ego, x=x, y=y, speed=v)
