"""Monocular 3D localisation of detected vehicles (one frame, many boxes).

Every localiser returns, per 2D box, the vehicle's centre on the road in the camera frame
(``x`` right, ``z`` forward, metres; the road is ``height_m`` below the camera) and its
dimensions from class priors. Two implementations share the :class:`Localizer` protocol:

* :class:`GroundPlaneLocalizer` - the bottom edge of the box touches the road: with the horizon
  row ``v_h`` and the camera height ``h`` the nearest point is ``Z = fy h / (v_bottom - v_h)``
  ahead. A size prior gives a second estimate, ``Z = fy H_class / box_height`` (and the box width
  when the box is not much wider than a vehicle's rear). The two are fused by inverse variance:
  the ground-plane error grows with distance (``dZ/Z = Z sigma_v / (fy h)``, sigma_v
  covering the bottom edge and the road's unknown slope), the size prior's
  error is the class's size spread (~8 %). Boxes cut by the bottom image border use the size
  prior only.
* :class:`DepthMapLocalizer` - given a metric depth map (a learned monocular depth model, or
  stereo), the box's foreground pixels are back-projected and averaged.

Both turn the visible near face into the vehicle's centre by adding half its extent along the
line of sight (length when seen from behind, width when seen side-on; the view angle comes from
the box's apparent width in metres).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Protocol

import numpy as np

from deepcrashtest.scenario import Camera

#: Class dimension priors: length, width, height (metres) of typical road users. A two-wheeler is
#: measured with its rider (the detection box runs from the rider's head to the wheels): a scooter or
#: motorcycle with a seated rider stands ~1.6 m tall, a bicycle with its rider ~1.75 m. A pedestrian
#: is an adult (mean stature ~1.7 m) seen as a 0.6 m wide, 0.5 m deep body.
CLASS_DIMENSIONS: dict[str, tuple[float, float, float]] = {
    "car": (4.4, 1.8, 1.5),
    "van": (5.0, 1.95, 2.1),
    "truck": (8.0, 2.5, 3.2),
    "bus": (11.0, 2.55, 3.1),
    "motorcycle": (2.1, 0.8, 1.6),
    "bicycle": (1.8, 0.6, 1.75),
    "pedestrian": (0.5, 0.6, 1.7),
}
#: Relative spread of the class height prior (1 sigma); pedestrians include children and bent walkers.
SIZE_PRIOR_SIGMA = {
    "car": 0.07,
    "van": 0.12,
    "truck": 0.15,
    "bus": 0.1,
    "motorcycle": 0.12,
    "bicycle": 0.12,
    "pedestrian": 0.12,
}
#: Assumed 1-sigma error of a box's bottom edge, pixels.
BOTTOM_EDGE_SIGMA_PX = 3.0
#: Assumed 1-sigma slope of the road under a vehicle relative to the camera's road (pitch and grade
#: changes), degrees. Real roads are not flat: on the KITTI labels the ground under a car 30 m ahead
#: lies anywhere from 1.1 m to 3.2 m below the camera.
ROAD_SLOPE_SIGMA_DEG = 1.5


@dataclass
class Placement:
    """Per-box localisation results (arrays of length N). Camera frame, metres."""

    x: np.ndarray  # right of the optical axis (centre of the vehicle)
    z: np.ndarray  # ahead of the camera (centre of the vehicle)
    length: np.ndarray
    width: np.ndarray
    height: np.ndarray
    valid: np.ndarray  # False where no distance could be measured

    @property
    def distance(self) -> np.ndarray:
        """Ground distance from the camera to the vehicle centre, metres."""
        return np.hypot(self.x, self.z)


class Localizer(Protocol):
    """Anything that places 2D boxes (x1, y1, x2, y2 px) on the road, in the camera frame."""

    def localize(
        self,
        boxes: np.ndarray,
        categories: Sequence[str],
        camera: Camera,
        image_size: tuple[int, int],
        depth: np.ndarray | None = None,
    ) -> Placement: ...


def class_dimensions(category: str) -> tuple[float, float, float]:
    """(length, width, height) metres for a category (cars for unknown ones)."""
    return CLASS_DIMENSIONS.get(category, CLASS_DIMENSIONS["car"])


def centre_offset(apparent_width_m: np.ndarray, length: np.ndarray, width: np.ndarray) -> np.ndarray:
    """Half the vehicle's extent along the line of sight, from its apparent width (metres).

    A box of apparent width ``W = l |sin a| + w |cos a|`` (a = view angle off the vehicle's axis)
    hides ``l |cos a| + w |sin a|`` of depth; half of it separates the visible face from the centre.
    """
    a = np.linspace(0.0, math.pi / 2, 91)
    app = length[:, None] * np.sin(a)[None, :] + width[:, None] * np.cos(a)[None, :]
    best = np.abs(app - apparent_width_m[:, None]).argmin(axis=1)
    ang = a[best]
    return 0.5 * (length * np.cos(ang) + width * np.sin(ang))


def _dims(categories: Sequence[str]) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    d = np.array([class_dimensions(c) for c in categories], dtype=float).reshape(-1, 3)
    return d[:, 0], d[:, 1], d[:, 2]


class GroundPlaneLocalizer:
    """Bottom-edge-on-the-road distance fused with a class size prior (see the module docstring)."""

    def __init__(
        self,
        horizon_v: float | None = None,
        bottom_sigma_px: float = BOTTOM_EDGE_SIGMA_PX,
        slope_sigma_deg: float = ROAD_SLOPE_SIGMA_DEG,
    ) -> None:
        self.horizon_v = horizon_v
        self.bottom_sigma_px = bottom_sigma_px
        self.slope_sigma_deg = slope_sigma_deg

    def localize(
        self,
        boxes: np.ndarray,
        categories: Sequence[str],
        camera: Camera,
        image_size: tuple[int, int],
        depth: np.ndarray | None = None,
    ) -> Placement:
        b = np.asarray(boxes, dtype=float).reshape(-1, 4)
        length, width, height = _dims(categories)
        _, img_h = image_size
        vh = self.horizon_v if self.horizon_v is not None else camera.horizon_v()
        box_h = np.maximum(b[:, 3] - b[:, 1], 1.0)
        below = b[:, 3] - vh
        cut_bottom = b[:, 3] >= img_h - 2
        z_ground = np.where(below > 1.0, camera.fy * camera.height_m / np.maximum(below, 1.0), np.nan)
        z_ground[cut_bottom] = np.nan
        z_size = camera.fy * height / box_h
        sig_size = np.array([SIZE_PRIOR_SIGMA.get(c, 0.1) for c in categories]).reshape(-1) + 2.0 / box_h
        sigma_v = self.bottom_sigma_px + camera.fy * math.tan(math.radians(self.slope_sigma_deg))
        sig_ground = z_ground * sigma_v / (camera.fy * camera.height_m)
        w_g = np.where(np.isfinite(z_ground), 1.0 / np.maximum(sig_ground, 1e-3) ** 2, 0.0)
        w_s = 1.0 / sig_size**2
        log_z = (w_g * np.log(np.where(np.isfinite(z_ground), z_ground, 1.0)) + w_s * np.log(z_size)) / (w_g + w_s)
        z_near = np.exp(log_z)
        return _place(b, z_near, camera, length, width, height)


def _place(
    b: np.ndarray, z_near: np.ndarray, camera: Camera, length: np.ndarray, width: np.ndarray, height: np.ndarray
) -> Placement:
    """Visible-face depth -> vehicle centre (camera frame) using the box centre's bearing."""
    bearing = (0.5 * (b[:, 0] + b[:, 2]) - camera.cx) / camera.fx
    near = np.column_stack([bearing * z_near, z_near])
    return _centre_from_face(b, near, camera, length, width, height)


def _centre_from_face(
    b: np.ndarray, near: np.ndarray, camera: Camera, length: np.ndarray, width: np.ndarray, height: np.ndarray
) -> Placement:
    """Visible-face point (x, z) -> vehicle centre, half the extent further along the line of sight."""
    apparent = (b[:, 2] - b[:, 0]) * near[:, 1] / camera.fx
    off = centre_offset(np.nan_to_num(apparent), length, width)
    ray = near / np.maximum(np.linalg.norm(near, axis=1, keepdims=True), 1e-9)
    centre = near + off[:, None] * ray
    valid = np.isfinite(centre).all(axis=1) & (near[:, 1] > 0)
    return Placement(centre[:, 0], centre[:, 1], length, width, height, valid)


class DepthMapLocalizer:
    """Place boxes with a metric depth map (same size as the image, metres; <= 0 or NaN = unknown).

    Foreground pixels of each box (the inner part of the box, depths within ``band_m`` of the
    box's 15th-percentile depth, or the pixels of ``masks[i]`` when given) are back-projected
    and their mean is the visible face; the centre is half the vehicle's extent behind it.
    """

    def __init__(self, band_m: float = 1.5, min_pixels: int = 20) -> None:
        self.band_m = band_m
        self.min_pixels = min_pixels

    def localize(
        self,
        boxes: np.ndarray,
        categories: Sequence[str],
        camera: Camera,
        image_size: tuple[int, int],
        depth: np.ndarray | None = None,
        masks: Sequence[np.ndarray] | None = None,
    ) -> Placement:
        if depth is None:
            raise ValueError("DepthMapLocalizer needs a depth map")
        b = np.asarray(boxes, dtype=float).reshape(-1, 4)
        length, width, height = _dims(categories)
        img_h, img_w = depth.shape[:2]
        face = np.full((len(b), 2), np.nan)
        for i, (x1, y1, x2, y2) in enumerate(b):
            bw, bh = x2 - x1, y2 - y1
            c0, c1 = int(max(0, x1 + 0.15 * bw)), int(min(img_w, x2 - 0.15 * bw))
            r0, r1 = int(max(0, y1 + 0.2 * bh)), int(min(img_h, y2 - 0.1 * bh))
            if c1 <= c0 or r1 <= r0:
                continue
            patch = depth[r0:r1, c0:c1].astype(float)
            good = np.isfinite(patch) & (patch > 0)
            if masks is not None:
                good &= np.asarray(masks[i], dtype=bool)[r0:r1, c0:c1]
            elif good.sum() >= self.min_pixels:
                near = np.percentile(patch[good], 15)
                good &= patch < near + self.band_m
            if good.sum() < self.min_pixels:
                continue
            rows, cols = np.nonzero(good)
            zz = patch[rows, cols]
            xx = (cols + c0 - camera.cx) * zz / camera.fx
            face[i] = (xx.mean(), zz.mean())
        return _centre_from_face(b, face, camera, length, width, height)
