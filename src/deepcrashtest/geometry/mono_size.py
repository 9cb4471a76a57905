"""One size per monocular track, and the box geometry its depth cues rest on (steps 1-2 of
:mod:`deepcrashtest.geometry.mono3d`): each detected box's cues (bottom edge on the road, box height, box width), the
track's class and height pooled from its bottom-edge heights against each candidate class's prior (with the box
shape, the detector's class and, where the camera's height is measured or self-calibrated, its near ground
contacts), the roof's far edge in a box's height (:func:`hull_factor`) and a vehicle's apparent width at its view
angle. Camera frame: x right, y down, z forward; pixels, metres, radians."""

from __future__ import annotations

import math

import numpy as np
import pandas as pd

from deepcrashtest.geometry.camera import cut_sides
from deepcrashtest.geometry.mono_config import (
    CANDIDATES,
    MEASURED_HEIGHT_SOURCES,
    Cues,
    MonoConfig,
    RoadProfile,
    class_size,
    size_sigma,
)
from deepcrashtest.scenario import Camera


def bottom_depth(below: np.ndarray, camera: Camera, road: RoadProfile | None) -> np.ndarray:
    """Depth (m) of a ground contact ``below`` px under the horizon: ``fy h / below`` on a flat road, else the
    fixed point of ``Z = fy h ratio(Z) / below`` (a few iterations: the ratio changes slowly with range)."""
    z = camera.fy * camera.height_m / np.maximum(below, 1e-3)
    if road is not None:
        for _ in range(4):
            z = camera.fy * camera.height_m * road.ratio(z) / np.maximum(below, 1e-3)
    return z


def box_cues(
    b: np.ndarray, camera: Camera, image_size: tuple[int, int], vh: np.ndarray, cfg: MonoConfig,
    road: RoadProfile | None = None,
) -> Cues:  # fmt: skip
    below = b[:, 3] - vh
    cut = cut_sides(b, image_size)
    cut_bottom, cut_top, cut_u = cut[:, 3], cut[:, 1], cut[:, 0] | cut[:, 2]
    z_b = np.where((below > 2.0) & ~cut_bottom, bottom_depth(below, camera, road), np.nan)
    r_b = np.hypot(cfg.bottom_sigma_px / np.maximum(below, 1e-3), cfg.road_height_rel)
    return Cues(
        z_bottom=z_b,
        r_bottom=r_b,
        box_h=np.maximum(b[:, 3] - b[:, 1], 1.0),
        box_w=np.maximum(b[:, 2] - b[:, 0], 1.0),
        bearing=(0.5 * (b[:, 0] + b[:, 2]) - camera.cx) / camera.fx,
        cut_v=cut_bottom | cut_top,
        cut_u=cut_u,
    )


def pool_log(samples: np.ndarray, rel_sigma: np.ndarray, prior: float, prior_rel: float, inflation: float):
    """Inverse-variance pooling (log domain) of samples with a prior -> (value, relative sigma, log-lik).

    ``inflation`` multiplies each sample's variance (frames of one track share their errors)."""
    ok = np.isfinite(samples) & np.isfinite(rel_sigma) & (samples > 0)
    s, r = np.log(samples[ok]), rel_sigma[ok]
    w = 1.0 / (inflation * r**2)
    w0 = 1.0 / prior_rel**2
    mean = (np.sum(w * s) + w0 * math.log(prior)) / (np.sum(w) + w0)
    var_each = inflation * r**2 + prior_rel**2
    loglik = float(np.sum(-0.5 * (s - math.log(prior)) ** 2 / var_each - 0.5 * np.log(var_each)))
    return math.exp(mean), 1.0 / math.sqrt(np.sum(w) + w0), loglik


def _free_loglik(samples: np.ndarray, rel_sigma: np.ndarray, prior_rel: float, inflation: float, cost: float) -> float:
    """Log-likelihood of the samples of :func:`pool_log` about their own weighted mean (log domain), less ``cost``
    per sample: the fit of a track whose road or horizon is off by an unknown factor, whatever its class's height."""
    ok = np.isfinite(samples) & np.isfinite(rel_sigma) & (samples > 0)
    s, r = np.log(samples[ok]), rel_sigma[ok]
    if len(s) == 0:
        return -math.inf
    var_each = inflation * r**2 + prior_rel**2
    mu = float(np.sum(s / var_each) / np.sum(1.0 / var_each))
    return float(np.sum(-0.5 * (s - mu) ** 2 / var_each - 0.5 * np.log(var_each) - cost))


def track_size(
    category: str,
    cues: Cues,
    rows: np.ndarray,
    det: np.ndarray,
    camera: Camera,
    cfg: MonoConfig,
    scale: float,
    choose_class: bool = True,
):
    """(class, length, width, height, height rel sigma, width scale, width-scale rel sigma) of one track.

    ``scale``: the box source's size convention (see :func:`size_scale`), multiplies the priors."""
    use = rows[det[rows] & ~cues.cut_v[rows] & np.isfinite(cues.z_bottom[rows])]
    h_samples = cues.box_h[use] * cues.z_bottom[use] / camera.fy
    h_rel = np.hypot(cues.r_bottom[use], cfg.height_sigma_px / cues.box_h[use])
    best: tuple[float, str] | None = None
    candidates = CANDIDATES.get(category, (category,)) if choose_class else (category,)

    def near_face(cls: str) -> np.ndarray:  # the samples as near-face heights of class ``cls``
        if not (cfg.hull_height and cfg.hull_in_class):
            return h_samples
        ln, wd, ht = (v * scale for v in class_size(cls))
        return h_samples / hull_factor(ht, ln, wd, camera.height_m, cues.z_bottom[use], cues.bearing[use])

    inflation = cfg.class_sample_inflation
    measured = camera.height_source in MEASURED_HEIGHT_SOURCES  # (see MonoConfig.class_free_height_cost)
    free_cost = cfg.class_free_height_cost if measured else None
    for cls in candidates:  # the class: the likeliest prior given the samples
        prior_h, prior_rel = class_size(cls)[2] * scale, size_sigma(cls)
        samples = near_face(cls)
        _, _, loglik = pool_log(samples, h_rel, prior_h, prior_rel, inflation)
        if free_cost is not None:  # heights far from every class's prior: no class evidence
            loglik = float(np.logaddexp(loglik, _free_loglik(samples, h_rel, prior_rel, inflation, free_cost)))
        loglik -= 0.0 if cls == category else cfg.class_switch_cost  # the detector's own class is likelier
        if cfg.aspect_sigma > 0:
            loglik += _aspect_loglik(cls, cues, rows[det[rows]], camera, scale, cfg)
        if best is None or loglik > best[0]:
            best = (loglik, cls)
    assert best is not None
    cls = best[1]
    height, h_rel_post, _ = pool_log(
        near_face(cls), h_rel, class_size(cls)[2] * scale, size_sigma(cls), cfg.size_sample_inflation
    )
    height, h_rel_post = contact_height(cls, height, h_rel_post, cues, use, camera, cfg, scale)
    length, width, prior_h = class_size(cls)
    length, width = length * cfg.length_scale, width * cfg.width_scale
    scale = height / prior_h  # the posterior height scales the class's length and width
    # width cue scale: apparent width against the class's, for a vehicle parallel to the ego
    use_w = rows[det[rows] & ~cues.cut_u[rows] & np.isfinite(cues.z_bottom[rows])]
    app = width_m(length * scale, width * scale, cues, use_w, camera, cfg)
    w_samples = cues.box_w[use_w] * cues.z_bottom[use_w] / camera.fx / app
    w_rel = np.hypot(cues.r_bottom[use_w], cfg.width_sigma_rel)
    w_scale, w_scale_rel, _ = pool_log(w_samples, w_rel, 1.0, cfg.width_sigma_rel, cfg.size_sample_inflation)
    return cls, length * scale, width * scale, height, h_rel_post, w_scale, w_scale_rel


def contact_floor(camera: Camera, cfg: MonoConfig) -> float | None:
    """The relative error all of a track's near ground contacts share (road shape, the camera's height): the
    configured floor where the camera's height is measured, widened by ``contact_self_calibrated_sigmas`` of its
    relative 1-sigma where it is self-calibrated; None where the contacts measure nothing (a default height)."""
    if camera.height_source in MEASURED_HEIGHT_SOURCES:
        return cfg.contact_floor_rel
    k, sigma = cfg.contact_self_calibrated_sigmas, camera.height_sigma_m
    if camera.height_source != "self_calibration" or k is None or sigma is None or not math.isfinite(sigma):
        return None
    return math.hypot(cfg.contact_floor_rel, k * sigma / camera.height_m)


def contact_height(
    cls: str, height: float, rel: float, cues: Cues, use: np.ndarray, camera: Camera, cfg: MonoConfig,
    scale: float,
) -> tuple[float, float]:  # fmt: skip
    """The track's height (m) and relative sigma, fused with what its near ground contacts imply.

    Where the camera's height is measured or self-calibrated (:func:`contact_floor`), boxes whose bottom edge lies
    at least ``contact_min_below_px`` below the horizon (None: unused) give the depth
    of the vehicle's near face to a few per cent, hence its height ``box_h Z_bottom / fy /
    hull_factor`` (the roof's far edge removed); each such frame errs by ``contact_row_rel`` (road
    height under the car) and the bottom edge's and top edge's pixel errors, their inverse-variance
    mean no better than :func:`contact_floor` (the road's shape is shared by the frames). That mean
    and ``height`` (the class prior's posterior) are fused by inverse variance in log."""
    floor_rel = contact_floor(camera, cfg)
    if cfg.contact_min_below_px is None or floor_rel is None:
        return height, rel
    below = camera.fy * camera.height_m / cues.z_bottom[use]
    near = use[below >= cfg.contact_min_below_px]
    if len(near) == 0 and cfg.contact_far_below_px is not None:  # a track that never comes that near: its nearest
        near = use[below >= cfg.contact_far_below_px]
    if len(near) == 0:
        return height, rel
    ln, wd, ht = (v * scale for v in class_size(cls))
    z = cues.z_bottom[near]
    h = cues.box_h[near] * z / camera.fy / hull_factor(ht, ln, wd, camera.height_m, z, cues.bearing[near])
    b = camera.fy * camera.height_m / z
    w = 1.0 / ((cfg.bottom_sigma_px / b) ** 2 + cfg.contact_row_rel**2 + (cfg.height_sigma_px / cues.box_h[near]) ** 2)
    mean = float(np.sum(w * np.log(h)) / np.sum(w))
    var = floor_rel**2 + 1.0 / float(np.sum(w))
    w_prior = 1.0 / rel**2
    log_h = (w_prior * math.log(height) + mean / var) / (w_prior + 1.0 / var)
    return math.exp(log_h), 1.0 / math.sqrt(w_prior + 1.0 / var)


def _aspect_loglik(cls: str, cues: Cues, rows: np.ndarray, camera: Camera, scale: float, cfg: MonoConfig) -> float:
    """Log-likelihood of a track's box shapes (height over width, free of the range) under class ``cls``.

    A van's box is taller for its width than a car's: the expected ratio is the class's height
    (times :func:`hull_factor`, the roof's far edge) over its apparent width at the box's view angle
    (a vehicle parallel to the ego); each uncut box's log ratio misses it by ``aspect_sigma``
    (1 sigma), the frames' sum divided by ``aspect_inflation`` (frames of one track share errors)."""
    use = rows[~cues.cut_v[rows] & ~cues.cut_u[rows]]
    if len(use) == 0:
        return 0.0
    ln, wd, ht = (v * scale for v in class_size(cls))
    z = camera.fy * ht / cues.box_h[use]
    expected = ht * hull_factor(ht, ln, wd, camera.height_m, z, cues.bearing[use])
    expected /= apparent_width(ln * cfg.length_scale, wd * cfg.width_scale, cues.bearing[use])
    resid = np.log(cues.box_h[use] / cues.box_w[use]) - np.log(expected)
    return float(-0.5 * np.sum(resid**2) / cfg.aspect_sigma**2 / cfg.aspect_inflation)


def size_scale(tracks: pd.DataFrame, cues: Cues, det: np.ndarray, camera: Camera, min_below_px: float) -> float:
    """How much taller the boxes are than the class priors say, over the whole video (one number).

    Box conventions differ (a detector's tight visible box, a projected 3D box's hull): the heights
    the bottom-edge cue implies for near boxes (bottom edge at least ``min_below_px`` below the
    horizon, uncut) are divided by their class prior; the median ratio (clipped to 0.85-1.2; 1 with
    fewer than 20 boxes or ``min_below_px`` <= 0) scales every prior of this video."""
    below = camera.fy * camera.height_m / np.where(np.isfinite(cues.z_bottom), cues.z_bottom, np.inf)
    ok = det & ~cues.cut_v & (below >= min_below_px)
    if min_below_px <= 0 or ok.sum() < 20:
        return 1.0
    prior = np.array([class_size(str(c))[2] for c in tracks["category"].to_numpy()[ok]])
    ratio = cues.box_h[ok] * cues.z_bottom[ok] / camera.fy / prior
    return float(np.clip(np.median(ratio), 0.85, 1.2))


def hull_factor(
    height: float, length: float, width: float, camera_height: float, z_near: np.ndarray, bearing: np.ndarray
) -> np.ndarray:
    """Box height over ``fy height / z_near``: how much taller a vehicle's box is than its near face.

    A vehicle lower than the camera shows its roof: the box's top edge is the roof's far edge, at
    depth ``z_near + D`` (``D = L |cos a| + W |sin a|`` its extent along the line of sight), so
    ``box_h = fy (hc / z_near - (hc - H) / (z_near + D))`` = ``fy H / z_near`` times
    ``1 + (hc - H) / H * D / (z_near + D)``. Taller vehicles show their near top edge (factor 1).
    On the KITTI 0001 labels (cars 5 m and more away) it narrows the gap between the box heights and
    ``fy H / z_near`` (median |log| 0.018 against 0.023; ``tests/test_mono.py``)."""
    a = np.arctan(bearing)
    extent = length * np.abs(np.cos(a)) + width * np.abs(np.sin(a))
    z = np.maximum(np.nan_to_num(z_near, nan=1e6), 0.5)
    return 1.0 + max(camera_height - height, 0.0) / height * extent / (z + extent)


def width_m(
    length: float, width: float, cues: Cues, rows: np.ndarray, camera: Camera, cfg: MonoConfig,
    edges: np.ndarray | None = None, rel_yaw: np.ndarray | None = None,
) -> np.ndarray:  # fmt: skip
    """What the width cue divides by: ``Z_near = fx width_m / box_w`` (m) for a vehicle of ``length`` x ``width``
    parallel to the optical axis, per row.

    With ``cfg.width_box_edges`` the box's edges as they project: a vehicle wholly right of the optical axis shows
    its rear (or front) face and its left side, the box runs from the side's far end, at ``Z_near + L``, to the
    face's outer corner, at ``Z_near``, so ``box_w / fx = W / Z_near + t_in L / (Z_near + L)``, ``t_in`` the tangent
    of the box's inner edge, and ``Z_near = (W + t_in L) / (box_w / fx)`` exactly (``t_in`` 0 for a box across the
    axis: the face alone). Else :func:`apparent_width` at the box centre's bearing. ``edges`` (per row): where
    to use the box edges instead of ``cfg.width_box_edges`` everywhere; ``rel_yaw`` (per row, rad; NaN: unknown):
    the other rows' heading against the camera's axis, read with :func:`oblique_width`."""
    centre = apparent_width(length, width, cues.bearing[rows])
    if rel_yaw is not None:
        ok = np.isfinite(rel_yaw)
        centre[ok] = oblique_width(length, width, cues.bearing[rows][ok], cues.box_w[rows][ok] / camera.fx,
                                    rel_yaw[ok])  # fmt: skip
    use = np.full(len(rows), cfg.width_box_edges) if edges is None else np.asarray(edges, bool)
    if not use.any():
        return centre
    half = 0.5 * cues.box_w[rows] / camera.fx
    t_in = np.maximum(0.0, np.maximum(cues.bearing[rows] - half, -(cues.bearing[rows] + half)))
    return np.where(use, width + length * t_in, centre)


def oblique_width(
    length: float, width: float, bearing: np.ndarray, box_tan: np.ndarray, rel_yaw: np.ndarray
) -> np.ndarray:
    """``Z_near box_tan`` (m) for a vehicle of ``length`` x ``width`` turned by ``rel_yaw`` (rad, left of the
    camera's axis) whose centre lies on the ray at ``bearing`` (tan) and whose footprint's corners span
    ``box_tan`` (the box width over fx): the centre's depth solved by fixed-point iteration (the span falls
    as 1 / depth), ``Z_near`` the depth of the near face as :func:`_measurements` offsets it to the centre."""
    fwd = np.column_stack([-np.sin(rel_yaw), np.cos(rel_yaw)])  # heading in camera x (right), z (forward)
    side = np.column_stack([fwd[:, 1], -fwd[:, 0]])
    corners = [0.5 * (i * length * fwd + j * width * side) for i in (-1, 1) for j in (-1, 1)]
    dx = np.column_stack([c[:, 0] for c in corners])
    dz = np.column_stack([c[:, 1] for c in corners])
    a = np.arctan(bearing)
    off_z = 0.5 * (length * np.abs(np.cos(a)) + width * np.abs(np.sin(a))) * np.cos(a)
    zc = np.maximum((length + width) / np.maximum(box_tan, 1e-4), 1.0)
    for _ in range(8):
        z = np.maximum(zc[:, None] + dz, 0.3)
        t = (bearing[:, None] * zc[:, None] + dx) / z
        zc = np.maximum(zc * (t.max(axis=1) - t.min(axis=1)) / np.maximum(box_tan, 1e-4), 1.0)
    return np.maximum(zc - off_z, 0.5) * box_tan


def apparent_width(length: float, width: float, bearing: np.ndarray) -> np.ndarray:
    """Width (m) across the line of sight of a vehicle parallel to the optical axis, seen at ``bearing``."""
    a = np.arctan(bearing)
    return length * np.abs(np.sin(a)) + width * np.abs(np.cos(a))
