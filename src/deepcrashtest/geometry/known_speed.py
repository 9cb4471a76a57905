"""The ego's speed known apart from image motion (a user's ``--ego-speed``, the GPS speed burned into the picture)
and the focal length it gives an uncalibrated camera.

Image ego-motion's metric scale is the road plane's, proportional to focal length x camera height; every road
user's distance (box sizes, bottom rows) goes with the same focal length. Once the camera height is read from the
boxes, the focal length that gives the image ego-motion the known speed is one more term of the focal-length
fusion (:func:`deepcrashtest.geometry.selfcalib.combine_focal`), and the whole scene takes the metric scale.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np

from deepcrashtest.geometry.egomotion import EgoMotion
from deepcrashtest.scenario import Camera

#: Relative 1-sigma of the focal length read from a known speed: a GPS speed to +-1-2 km/h, and the median of the
#: image ego-motion's speed readings, which the focal length scales.
USER_SPEED_REL = 0.05
#: Speed readings (m/s) under this are the ego standing: they tell nothing of the scale.
USER_SPEED_MIN_MPS = 1.0


@dataclass(frozen=True)
class KnownSpeed:
    """The ego's speed known apart from the images: ``mps`` (m/s) from each of ``times_s`` (video time, s) until
    the next reading (the first also before it). ``source``: ``"user"`` (``extract --ego-speed``, one constant) or
    ``"overlay"`` (read off the picture, :mod:`deepcrashtest.perception.overlay_speed`); ``what``: the speed as the
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
    ego: EgoMotion, camera: Camera, height_m: float, speed: KnownSpeed | float
) -> tuple[float, float, int] | None:
    """(focal length px, relative sigma, frames used) that gives image ego-motion the known speed.

    ``ego`` was measured with ``camera``'s focal length and height; at the calibrated height ``height_m`` its
    median speed over the frames where both it and the known speed move is ``v``, against the known speed's median
    ``s`` over the same frames: the focal length ``camera.fy x s / v`` gives it the known speed. None where the
    video shows the ego standing (fewer than 3 such frames). ``speed``: a :class:`KnownSpeed` or one m/s figure."""
    known = speed if isinstance(speed, KnownSpeed) else KnownSpeed.constant(speed)
    along = known.at(ego.t)
    moving = np.isfinite(ego.speed) & (ego.speed >= USER_SPEED_MIN_MPS) & (along >= USER_SPEED_MIN_MPS)
    if int(moving.sum()) < 3:
        return None
    measured = float(np.median(ego.speed[moving])) * height_m / camera.height_m
    return camera.fy * float(np.median(along[moving])) / measured, USER_SPEED_REL, int(moving.sum())


def ego_speed_term(
    ego: EgoMotion | None,
    camera: Camera,
    speed: KnownSpeed | None,
    scaled_by_height: bool,
    height_m: float,
    notes: list[str],
    warnings: list[str],
) -> tuple[float, float, int] | None:
    """:func:`focal_from_ego_speed`'s term at the calibrated camera height ``height_m`` (m): None without a known
    speed or an image ego-motion scaled by the camera height, or where the ego stands; said in ``notes`` (and in
    ``warnings`` where a speed the user gave cannot be used)."""
    if speed is None or ego is None or not scaled_by_height:
        return None
    found = focal_from_ego_speed(ego, camera, height_m, speed)
    given = "given" if speed.source == "user" else "read off the picture's overlay"
    if found is not None:
        notes.append(
            f"the ego's speed {given}, {speed.what}: focal length {found[0]:.0f} px from the image "
            f"ego-motion's median speed over {found[2]} moving frames at a camera height of {height_m:.2f} m"
        )
        return found
    notes.append(f"the ego's speed {given}, {speed.what}, not used: the ego stands")
    if speed.source == "user":
        warnings.append(
            f"--ego-speed {speed.what} not used: the video shows the ego standing (its image "
            f"ego-motion under {USER_SPEED_MIN_MPS:g} m/s), which tells nothing of the scale"
        )
    return None
