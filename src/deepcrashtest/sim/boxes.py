"""Oriented-box geometry, vectorised: separating-axis gaps, exact distances, contact times.

A box is its centre ``(x, y)``, heading ``yaw`` (rad) and half extents ``(hl, hw)`` (metres,
half length along the heading, half width). All functions broadcast over leading dimensions.
"""

from __future__ import annotations

import numpy as np


def sat_gap(
    xa: np.ndarray,
    ya: np.ndarray,
    yawa: np.ndarray,
    hla: np.ndarray,
    hwa: np.ndarray,
    xb: np.ndarray,
    yb: np.ndarray,
    yawb: np.ndarray,
    hlb: np.ndarray,
    hwb: np.ndarray,
) -> np.ndarray:
    """Signed separating-axis gap between two boxes (m).

    For each of the four face normals the gap is the distance between the boxes' projections;
    the result is the largest. Positive: the boxes are apart (a lower bound of their distance,
    exact when the closest features are a face and a corner); zero or negative: they touch or
    overlap, and ``-gap`` is the penetration depth.
    """
    return gap_of_axes(*axis_gaps(xa, ya, yawa, hla, hwa, xb, yb, yawb, hlb, hwb))


def gap_of_axes(g1: np.ndarray, g2: np.ndarray, g3: np.ndarray, g4: np.ndarray) -> np.ndarray:
    """:func:`sat_gap` (m) from the boxes' :func:`axis_gaps`: the largest of the four."""
    return np.maximum(np.maximum(g1, g2), np.maximum(g3, g4))


def axis_gaps(*boxes: np.ndarray | float) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """The gaps (m) between the boxes' projections on A's length and width axes and on B's (:func:`sat_gap` is
    their largest); ``boxes``: :func:`sat_gap`'s arguments, in its order."""
    xa, ya, yawa, hla, hwa, xb, yb, yawb, hlb, hwb = (np.asarray(v) for v in boxes)
    ca, sa, cb, sb = np.cos(yawa), np.sin(yawa), np.cos(yawb), np.sin(yawb)
    dx, dy = xb - xa, yb - ya
    # |cos| and |sin| of the relative heading give all cross projections of the unit axes
    c = np.abs(ca * cb + sa * sb)
    s = np.abs(sa * cb - ca * sb)
    g1 = np.abs(dx * ca + dy * sa) - hla - (hlb * c + hwb * s)
    g2 = np.abs(-dx * sa + dy * ca) - hwa - (hlb * s + hwb * c)
    g3 = np.abs(dx * cb + dy * sb) - hlb - (hla * c + hwa * s)
    g4 = np.abs(-dx * sb + dy * cb) - hwb - (hla * s + hwa * c)
    return g1, g2, g3, g4


def distance_lower_bound(g1: np.ndarray, g2: np.ndarray, g3: np.ndarray, g4: np.ndarray) -> np.ndarray:
    """A lower bound (m) of the distance between two boxes from their :func:`axis_gaps`, at least their separating-
    axis gap: every point of B lies beyond both of A's slabs by at least ``g1`` and ``g2`` where these are positive,
    so its distance to A is at least ``hypot(max(g1, 0), max(g2, 0))``; the same on B's axes."""
    z = 0.0
    on_a = np.hypot(np.maximum(g1, z), np.maximum(g2, z))
    return np.maximum(on_a, np.hypot(np.maximum(g3, z), np.maximum(g4, z)))


def corners(x: np.ndarray, y: np.ndarray, yaw: np.ndarray, hl: np.ndarray, hw: np.ndarray) -> np.ndarray:
    """(..., 4, 2) corners, counter-clockwise from front-left."""
    c, s = np.cos(yaw)[..., None], np.sin(yaw)[..., None]
    lx = np.array([1.0, -1.0, -1.0, 1.0]) * np.asarray(hl)[..., None]
    ly = np.array([1.0, 1.0, -1.0, -1.0]) * np.asarray(hw)[..., None]
    return np.stack([np.asarray(x)[..., None] + lx * c - ly * s, np.asarray(y)[..., None] + lx * s + ly * c], axis=-1)


def _point_segment_dist(p: np.ndarray, a: np.ndarray, b: np.ndarray) -> np.ndarray:
    ab = b - a
    t = np.clip(np.sum((p - a) * ab, axis=-1) / np.maximum(np.sum(ab * ab, axis=-1), 1e-12), 0.0, 1.0)
    return np.hypot(*np.moveaxis(a + t[..., None] * ab - p, -1, 0))


def box_distance(ca: np.ndarray, cb: np.ndarray) -> np.ndarray:
    """Euclidean distance between two separated boxes given by their (..., 4, 2) corners."""
    ea, eb = np.roll(ca, -1, axis=-2), np.roll(cb, -1, axis=-2)
    d1 = _point_segment_dist(ca[..., :, None, :], cb[..., None, :, :], eb[..., None, :, :])
    d2 = _point_segment_dist(cb[..., :, None, :], ca[..., None, :, :], ea[..., None, :, :])
    return np.minimum(d1.min(axis=(-1, -2)), d2.min(axis=(-1, -2)))


def signed_distance(a: np.ndarray, b: np.ndarray, ha: np.ndarray, hb: np.ndarray) -> np.ndarray:
    """Exact signed distance between boxes ``a``/``b`` (..., 3: x, y, yaw) with half extents (..., 2).

    Positive: Euclidean distance between the boxes; negative: minus the penetration depth.
    """
    gap = sat_gap(
        a[..., 0], a[..., 1], a[..., 2], ha[..., 0], ha[..., 1], b[..., 0], b[..., 1], b[..., 2], hb[..., 0], hb[..., 1]
    )
    apart = gap > 0
    if not np.any(apart):
        return gap
    out = np.array(gap, dtype=float, copy=True)
    out[apart] = apart_distance(a, b, ha, hb, apart)
    return out


def apart_distance(a: np.ndarray, b: np.ndarray, ha: np.ndarray, hb: np.ndarray, apart: np.ndarray) -> np.ndarray:
    """The Euclidean distance (m) between the boxes ``a``/``b`` (..., 3: x, y, yaw; half extents ``ha``/``hb``
    (..., 2)) where ``apart`` (their broadcast shape) is True: those boxes' separating-axis gap is positive (the
    caller has it), so this is :func:`signed_distance` there, without computing the gap again."""
    ia = np.broadcast_to(a, np.broadcast_shapes(a.shape, b.shape))[apart]
    ib = np.broadcast_to(b, np.broadcast_shapes(a.shape, b.shape))[apart]
    sh = np.broadcast_shapes(ha.shape, hb.shape, apart.shape + (2,))
    pa, pb = np.broadcast_to(ha, sh)[apart], np.broadcast_to(hb, sh)[apart]
    return box_distance(
        corners(ia[:, 0], ia[:, 1], ia[:, 2], pa[:, 0], pa[:, 1]),
        corners(ib[:, 0], ib[:, 1], ib[:, 2], pb[:, 0], pb[:, 1]),
    )


def contact_fraction(
    a0: np.ndarray, a1: np.ndarray, b0: np.ndarray, b1: np.ndarray, ha: np.ndarray, hb: np.ndarray, iterations: int = 12
) -> np.ndarray:
    """Fraction in [0, 1] of a step at which boxes first touch, by bisection on linear motion.

    ``a0``/``a1`` (K, 3) are box A's x, y, yaw at the start and end of the step (apart at 0,
    overlapping at 1); likewise ``b0``/``b1``. Returns (K,).
    """
    lo, hi = np.zeros(len(a0)), np.ones(len(a0))
    for _ in range(iterations):
        mid = 0.5 * (lo + hi)
        a = a0 + (a1 - a0) * mid[:, None]
        b = b0 + (b1 - b0) * mid[:, None]
        g = sat_gap(a[:, 0], a[:, 1], a[:, 2], ha[:, 0], ha[:, 1], b[:, 0], b[:, 1], b[:, 2], hb[:, 0], hb[:, 1])
        hit = g <= 0
        hi = np.where(hit, mid, hi)
        lo = np.where(hit, lo, mid)
    return hi


def time_to_collision(
    dx: np.ndarray,
    dy: np.ndarray,
    wx: np.ndarray,
    wy: np.ndarray,
    yawa: np.ndarray,
    hla: np.ndarray,
    hwa: np.ndarray,
    yawb: np.ndarray,
    hlb: np.ndarray,
    hwb: np.ndarray,
) -> np.ndarray:
    """Time (s) until two boxes touch if both keep their current velocity and heading.

    ``(dx, dy)``: centre of B minus centre of A (m); ``(wx, wy)``: velocity of B minus velocity of A
    (m/s). Swept separating-axis test: along each face normal the projections overlap during an
    interval of time; the boxes touch when all four intervals overlap. ``inf`` when they never
    touch (e.g. a car passed in the next lane), 0 when they already overlap.
    """
    ca, sa, cb, sb = np.cos(yawa), np.sin(yawa), np.cos(yawb), np.sin(yawb)
    c = np.abs(ca * cb + sa * sb)
    s = np.abs(sa * cb - ca * sb)
    axes = (
        (ca, sa, hla + hlb * c + hwb * s),
        (-sa, ca, hwa + hlb * s + hwb * c),
        (cb, sb, hlb + hla * c + hwa * s),
        (-sb, cb, hwb + hla * s + hwa * c),
    )
    t_in = np.full(np.broadcast(dx, yawa, yawb).shape, -np.inf)
    t_out = np.full_like(t_in, np.inf)
    for nx, ny, r in axes:
        p = dx * nx + dy * ny
        q = wx * nx + wy * ny
        still = np.abs(q) < 1e-9
        qs = np.where(still, 1.0, q)
        t1, t2 = (-r - p) / qs, (r - p) / qs
        lo = np.where(still, np.where(np.abs(p) <= r, -np.inf, np.inf), np.minimum(t1, t2))
        hi = np.where(still, np.where(np.abs(p) <= r, np.inf, -np.inf), np.maximum(t1, t2))
        t_in = np.maximum(t_in, lo)
        t_out = np.minimum(t_out, hi)
    hit = (t_in <= t_out) & (t_out >= 0)
    return np.where(hit, np.maximum(t_in, 0.0), np.inf)
