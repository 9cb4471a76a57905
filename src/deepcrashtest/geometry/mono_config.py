"""Settings and shared types of the monocular 3D tracker (:mod:`deepcrashtest.geometry.mono3d`): its noise and
motion models (:class:`MonoConfig`, chosen on the KITTI tracking training sequences other than 3, 8 and 10), the
classes a detector's category may really be and their size priors, one box's depth cues (:class:`Cues`) and the
road's height profile ahead (:class:`RoadProfile`). Pixels, metres, seconds."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from deepcrashtest.geometry.localize import CLASS_DIMENSIONS, SIZE_PRIOR_SIGMA

#: Classes a detector's category may really be (the size decides among them).
CANDIDATES: dict[str, tuple[str, ...]] = {
    "car": ("car", "van"),
    "van": ("van", "car"),
    "truck": ("truck", "van", "bus"),
    "bus": ("bus", "truck"),
    "motorcycle": ("motorcycle", "bicycle"),
    "bicycle": ("bicycle", "motorcycle"),
    "pedestrian": ("pedestrian",),
}


#: ``Camera.height_source`` values of a measured camera height (the near ground contacts need one).
MEASURED_HEIGHT_SOURCES = ("user", "kitti_calib")


@dataclass(frozen=True)
class MonoConfig:
    """Noise models and motion model of :func:`localize_tracks` (pixels, metres, seconds).

    Chosen on the KITTI tracking training sequences other than 3, 8 and 10 (``bench/tune_mono.py``)."""

    bottom_sigma_px: float = 2.0
    road_height_rel: float = 0.5
    height_sigma_px: float = 0.4
    width_sigma_rel: float = 0.2
    # the width cue's relative sigma for a road user the detector calls a bicycle (None: ``width_sigma_rel``): its box
    # is 0.6-1.9 m wide with its heading (end-on to side-on), which a bicycle standing at a kerb, crossing or ridden on
    # the pavement does not reveal (KITTI 0015's standing cyclist seen end-on 30 deg right read 47 % far on its width;
    # 0002's, side-on, half as near). Round wid42, the tune split of bench/mono_vru.py, cyclist MOTA KITTI / unknown
    # camera: 0.2 (width_sigma_rel) 2.87 / -13.48, 0.5 11.56, 1.0 25.70, 2.0 27.54, 3.0 28.35 / 39.18, 5.0 28.65 /
    # 39.32, 10.0 28.65 / 39.40 (for bicycles and motorcycles alike, by the size-chosen class). Not for motorcycles:
    # scooters on the crash clips run along the lanes like cars, and there it moved dad_000550's crash (re-encoded at
    # crf 35) 0.3 s early and lowered all five DAD clips' reprojection (no motorcycle truth to choose it on).
    # Pedestrians keep width_sigma_rel (0.12 / 0.4 / 5.0: pedestrian MOTA 72.61 / 71.08 / 69.92 against 72.74)
    bicycle_width_sigma_rel: float | None = 5.0
    bearing_sigma_px: float = 3.0
    accel_std: float = 3.0
    init_speed_std: float = 15.0
    size_sample_inflation: float = 100.0
    class_sample_inflation: float = 1.5
    class_switch_cost: float = 1.0
    # a track whose bottom-edge heights fit no candidate class (the road under it or the horizon off: a car 30-70 m
    # away whose box is wide like a car's reads 2.2-3.8 m tall) carries no class evidence in its heights: each class's
    # height log-likelihood is floored at the fit about the samples' own mean less this per sample (None: off), and
    # the box shape and the detector's class decide (round mono13, 18 training sequences, KITTI camera: 65.37 ->
    # 65.92; 0.1 / 0.15 / 0.3: 65.41 / 65.92 / 65.53; a cost per track, not per sample, 2 / 4 / 8: 57.34 / 59.05 /
    # 60.83, flipping long car tracks to van). Only where the camera's height is measured (MEASURED_HEIGHT_SOURCES):
    # with a self-calibrated one (unknown camera 60.98 -> 61.49 on the training sequences) it typed two vans of
    # dad_000512 car (mean reprojection IoU 0.655 -> 0.621) and dad_000487's crash motorcycle bicycle -> motorcycle
    class_free_height_cost: float | None = 0.2
    gate_chi2: float = 25.0
    # a track whose measurements have all been gated out for this long (s; two at least) restarts at the next one: its
    # prediction has left the road user (mirrored dad_000550: a pickup turning across the junction coasted on at its
    # old velocity, 12 m from its boxes, for 2.5 s); None: never. Training sequences: never 70.20 / 64.31 (KITTI /
    # unknown camera), 0.3 s 70.38 / 64.56, 0.5 s 70.34 / 64.45, 1 s 70.52 / 64.63, 2 s 70.49 / 64.59
    gate_reset_s: float | None = 1.0
    frame_horizon: bool = True
    horizon_shrink: float = 1.0
    hull_height: bool = True  # the height cue with hull_factor (tuning MOTA 55.83 against 54.75 without)
    hull_in_class: bool = False  # the class choice on the plain heights (with: 54.75)
    prior_scale: float = 1.0  # multiplies the class size priors (0.98: 52.70, 1.02: 51.43)
    size_scale_min_below_px: float = 0.0  # off: 60 px gave tuning MOTA 24.6 against 54.75
    length_scale: float = 1.0  # multiplies the class length priors (the centre offset, hull factor, width cue)
    width_scale: float = 1.0  # multiplies the class width priors (the width cue, hull factor)
    aspect_sigma: float = 0.15  # box height/width against the class's in the class choice (0: unused)
    aspect_inflation: float = 30.0  # tuning MOTA 60.23 (off: 58.65; sigma^2 x inflation 0.4: 59.82, 0.9: 59.71)
    extend_s: float = 4.0  # a receding track is carried this long past its end (tuning MOTA 58.65 vs 56.22 off)
    extend_min_range_m: float = 45.0  # (40 m: 58.42, 50 m: 57.96, 30 m with 1 s: 55.05)
    # tuning MOTA 60.68 -> 62.52 (100 px: 62.22, 125: 62.35, 175: 61.92, 200: 60.67; row 0.1: 61.82, 0.3: 62.10;
    # floor 0.04: 62.53, 0.09: 62.38; at least 3 / 6 contacts: 61.99 / 61.22; not for the horizon: 62.33)
    # near ground contacts (bottom edge this far below the horizon; None: unused) ... Used where the camera's height is
    # measured (``Camera.height_source`` in :data:`MEASURED_HEIGHT_SOURCES`) or self-calibrated (below): they measure a
    # vehicle's height in units of the camera's, so with a default height they measure nothing. With the KITTI camera
    # (round mono8) 150 px lifts KITTI training MOTA 62.04 -> 63.84; on the dashcam fidelity clips (heights
    # self-calibrated or default) the same weights as the KITTI camera's had lost two reproduced crashes (dad_000478's
    # pair no longer close in 3D; ccd_000014's replay missed): there the self-calibrated height's own error counts
    contact_min_below_px: float | None = 150.0
    # ... and where the camera's height is self-calibrated (``height_source`` "self_calibration"), the contacts measure
    # a vehicle's height against the fleet's (the box line's slope is the fleet's height in units of the camera's), a
    # tall van's or a low saloon's own: used there too, with the camera height's relative 1-sigma x this many added to
    # their floor (``contact_floor_rel``: every contact shares the camera's height error; None: a self-calibrated
    # height has no contacts). Round cont43, 18 training sequences, unknown camera: off 64.52, 1 / 2 / 3 sigmas 65.30 /
    # 65.46 / 65.46 (with the class-free height cost as well, 1 / 2 / 3 / 4 / 6 / 10 sigmas: 65.56 / 65.78 / 65.84 /
    # 65.76 / 65.27 / 64.96; the floor not widened 64.99): the stated 1-sigma of the self-calibrated height is
    # short of its error by 2-4x on those sequences (0000 1.40 +- 0.06 m against 1.65, 0004 1.45 +- 0.15 against 1.72)
    contact_self_calibrated_sigmas: float | None = 3.0
    contact_row_rel: float = 0.2  # ... each measure the track's height to this (1 sigma, relative) ...
    contact_floor_rel: float = 0.06  # ... and all of them together no better than this (road shape)
    # ... and a track without such contacts uses its nearest ones, bottom edge this far below the horizon (None:
    # unused), with the same errors, in its final size only, not in the sizes the per-frame horizon rests on (round
    # mono10, 18 tuning sequences: 64.55 -> 65.37; 60 / 75 / 80 / 100 / 110 px: 62.51 / 64.94 / 65.14 / 65.18 / 64.96;
    # in the horizon's sizes too, 100 px: 65.38 from 0004 +19 against 0014 -11.5, one track's class flipping with
    # the horizon; 90 / 75 px: 65.33 / 64.81; their own floor 0.04 / 0.08 / 0.1 at 100 px: 65.57 / 65.16 / 64.89)
    contact_far_below_px: float | None = 90.0
    # detected boxes cut at the bottom and a side (no depth cue: a car the ego passes) at a track's ends are
    # carried by the motion model for at most this long (s)
    carry_cut_s: float = 0.5
    # the road's drop below the camera as a function of range (not one plane through the ego), estimated from the
    # tracks themselves (:func:`road_profile`): off; round mono12, 18 training sequences: KITTI camera 65.37 -> 65.13,
    # unknown camera 60.98 -> 61.02 (with the bottom-edge cue weighted up, road_height_rel 0.2: 58.09 / 58.37)
    road_profile: bool = False
    road_ref_m: float = 12.0  # the profile is 0 (the camera's height) up to this range (m) ...
    road_knots_m: tuple[float, ...] = (20.0, 30.0, 45.0, 60.0, 80.0)  # ... piecewise linear through these (flat past)
    road_knot_sigma: float = 0.1  # prior 1-sigma of each knot's log drop (pulls it to the camera's height)
    road_min_rows: int = 200  # fewer usable rows: no profile
    # the per-frame horizon's depths with the roof's far edge removed (hull_factor); off (round mono12: 65.22 / 60.99)
    horizon_hull: bool = False
    # the width cue's geometry (:func:`width_m`): the box's edges as a vehicle parallel to the optical axis projects
    # them (its side's far end at the near face's depth plus its length), not its extent across the line of sight at
    # the box centre's bearing, which reads a car 10 m ahead and 3 m aside 18 % too far, one at 30 m 7 %. Off: round
    # mono14, 18 training sequences, median position error at 0-20 m lower on 12 of 14 sequences with the KITTI
    # camera, 10 of 14 with the unknown one, MOTA 65.92 -> 65.75 (unknown 60.98 -> 60.97), held-out 85.93 / 66.96 /
    # 88.97 -> 89.22 / 67.66 / 88.28 (unknown 86.83 / 53.37 / 92.07 -> 83.83 / 55.36 / 92.24), but on the 20 dashcam
    # clips the mean reprojection IoU fell 0.652 / 0.627 -> 0.645 / 0.616 (ccd_000080 0.715 -> 0.607: crash cars
    # turn towards the ego, not parallel to the axis; 19 of 19 outcomes kept)
    width_box_edges: bool = False
    # ... or only where a vehicle heads along the camera's axis (or against it) within this angle (degrees; 0: off),
    # its heading from a first pass of the track with the centre-bearing geometry; a vehicle slower than
    # ``along_min_speed`` (m/s) counts as along (parked and queued vehicles line the road). Crossing and turning
    # vehicles keep the centre-bearing geometry, which the box edges of a car seen obliquely fit better. Round
    # mono13i, 18 training sequences (10 / 20 / 30 deg alike; 20 chosen): n-weighted median position error 0-20 m
    # 4.57 -> 4.39 % (unknown camera 5.10 -> 4.87 %), MOTA 65.92 -> 65.75 (unknown 61.00 -> 60.87); 20 dashcam
    # clips: 18/18 kept, mean IoU 0.652 / 0.628 -> 0.653 / 0.628 (ccd_000080 0.715 -> 0.714)
    width_edges_along_deg: float = 20.0
    along_min_speed: float = 1.5
    # the other moving vehicles' width cue from their footprint turned by their heading from the first pass
    # (:func:`oblique_width`: the box spans the rotated rectangle's corners) instead of the centre-bearing geometry.
    # Exact with the true heading (KITTI labels of cars turned > 20 deg, 18 training sequences: centre depth median
    # |error| 0.4 % against 30 %), but the first pass's heading is too noisy. Off: round mono13, 18 training
    # sequences, from 1.5 / 5 / 10 m/s MOTA 65.75 -> 64.68 / 64.98 / 65.78 (unknown 60.87 -> 61.04 / 60.81 / 60.75);
    # fresh extracts at 1.5 m/s: ccd_000080 IoU 0.714 -> 0.545, dad_000528 replay 0.622 -> 0.565; at 10 m/s no row
    # of either clip changes
    width_oblique: bool = False
    oblique_min_speed: float = 10.0  # ... the vehicles at least this fast (m/s): a slower one's heading is noise
    # a standing vehicle's position from the parallax the ego's own motion gives (:func:`_static_fit`): one ground
    # point whose bearings and box heights (one height for the track, pulled to its class size by ``static_size_rel``)
    # fit every detected, uncut box; kept where the track's first pass is slower than ``static_max_speed`` (m/s),
    # the fit's mean squared normalised residual is under ``static_max_chi2``, its height within
    # ``static_max_size_dev`` (log) of the track's size and the line of sight to it turned by at least
    # ``static_min_parallax_rad`` over the track (less parallax: the class size knows the range better). A queue
    # creeping at 1-2 m/s past a moving ego fits a standing point as well as a parked car does (round mono14s, 18
    # training sequences: 0020's queue lost 75.0 -> 47.3 without the parallax and speed gates), so the gates were
    # chosen on the 18 training sequences for both cameras: MOTA 65.75 -> 69.86 (KITTI camera), 60.87 -> 61.15
    # (unknown); see docs/kitti-mono.md
    static_fit: bool = True
    static_max_speed: float = 1.5
    static_min_rows: int = 5
    static_height_rel: float = 0.05
    static_size_rel: float = 0.15
    static_max_chi2: float = 1.0
    static_max_size_dev: float = 0.3
    static_min_parallax_rad: float = 0.3
    # ... and a standing vehicle's class (car or van) from the height its standing fit measures with a loose size
    # prior (relative sigma ``static_class_rel``; a class other than the detector's costs ``static_class_switch`` in
    # log height): round mono14s, 18 training sequences, MOTA 69.86 -> 70.20 (0001 66.6 -> 69.9), unknown camera
    # 64.10 -> 64.33 (0009 69.2 -> 70.9); no sequence lower; 0.3 / 0.5 alike, switch cost 0: 69.86 / 64.33
    static_class: bool = True
    static_class_rel: float = 0.5
    static_class_switch: float = 0.1


def class_size(category: str) -> tuple[float, float, float]:
    """(length, width, height) metres of a class (cars for unknown ones)."""
    return CLASS_DIMENSIONS.get(category, CLASS_DIMENSIONS["car"])


def width_cue_sigma(detector_class: str, cfg: MonoConfig) -> float:
    """Relative 1-sigma of one box's width cue for a track the detector calls ``detector_class``."""
    if detector_class == "bicycle" and cfg.bicycle_width_sigma_rel is not None:
        return cfg.bicycle_width_sigma_rel
    return cfg.width_sigma_rel


def size_sigma(category: str) -> float:
    return SIZE_PRIOR_SIGMA.get(category, 0.1)


@dataclass
class Cues:
    """Per-row depth cues: depth (m) and relative 1-sigma error (NaN: cue unavailable)."""

    z_bottom: np.ndarray
    r_bottom: np.ndarray
    box_h: np.ndarray
    box_w: np.ndarray
    bearing: np.ndarray  # tan of the line of sight's angle right of the optical axis
    cut_v: np.ndarray
    cut_u: np.ndarray


@dataclass(frozen=True)
class RoadProfile:
    """The road's drop below the camera against range: ``log(drop / camera height)`` at ``knots_m`` (m), linear
    between them, 0 at and before the first knot, flat past the last."""

    knots_m: tuple[float, ...]
    log_drop: tuple[float, ...]

    def ratio(self, z: np.ndarray) -> np.ndarray:
        """Road drop over the camera's height at depths ``z`` (m)."""
        return np.exp(np.interp(np.nan_to_num(z, nan=0.0), self.knots_m, self.log_drop))
