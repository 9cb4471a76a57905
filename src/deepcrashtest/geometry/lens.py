"""A dashcam's radial lens distortion from the video itself: straight edges of the scene must come out straight.

Most dashcams film through wide-angle lenses that bow straight lines outwards (barrel distortion: poles and
building edges at the frame's sides curve, the frame's outer parts are pulled in). Without a calibration the
pinhole geometry then misplaces every road user away from the image centre. This is the plumb-line method on
the one-parameter division model (Fitzgibbon 2001; Bukhari & Dailey 2013): a pixel at radius ``r_d`` from the
image centre is undistorted to radius ``r_u = r_d / (1 + lam (r_d / s)^2)``, ``s`` the half diagonal (px), so a
straight scene line is a circle in the image and ``lam < 0`` is barrel.

Edge pieces (Canny, contour runs of ``PIECE_PX`` pixels that run nearly straight end to end) away from the
image centre and above the car's bonnet are collected from a few frames. For each candidate ``lam`` on a grid,
each piece's straightness is the RMS (px) of its points from the best line of the undistorted image, measured
in the frame: each point against its foot on that line mapped back through the lens (so that a lens that
shrinks or stretches the picture is not favoured); capped at ``CAP_PX`` (a tree's outline or a bent kerb is no
line for any ``lam``). The estimate is the grid's minimum of the mean; its 1-sigma is the spread of that
minimum over bootstrap resamplings of the pieces (seeded). It is used only when it is clearly a lens
(:func:`accepted`): KITTI's rectified frames read 0.

The camera keeps OpenCV's model (``Camera.distortion``: the rational model's k1, k2, p1, p2, k3, k4, k5, k6 in the
focal length's normalised coordinates): :func:`opencv_coefficients` fits it to the division model, and
:func:`refocused` keeps the pixel-space distortion when the focal length is later self-calibrated.
Image coordinates: u right, v down, pixels of the frame; the distortion centre is the principal point.
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np

#: Contour run length (px) of one edge piece, and how straight it must run (end-to-end span / length).
PIECE_PX = 200
MIN_SPAN = 0.9
#: Pieces whose mean radius is under this share of the half diagonal carry almost no curvature: left out.
MIN_RADIUS = 0.35
#: A piece's straightness residual is capped at this (px): outlines that no lens makes straight count alike.
CAP_PX = 1.0
#: Candidate division-model coefficients (radius over the half diagonal).
GRID = np.round(np.arange(-0.6, 0.305, 0.02), 4)
#: Use a lens only when at least MIN_PIECES pieces say so, its coefficient is at least MIN_LAM off zero and at
#: least SIGMAS bootstrap sigmas, and straightening them lowers their mean residual by MIN_GAIN (relative).
MIN_PIECES = 40
MIN_LAM = 0.1
SIGMAS = 3.0
MIN_GAIN = 0.05
BOOTSTRAP = 200
#: At most this many pieces (a seeded random choice), each every POINT_STEP-th of its points: ~0.1 s in all.
MAX_PIECES = 300
POINT_STEP = 4


@dataclass
class LensEstimate:
    """The division-model coefficient ``lam`` (radius over the half diagonal ``s`` px; < 0 barrel), its
    bootstrap 1-sigma, the pieces it rests on, the relative drop of their mean residual against ``lam = 0``,
    and whether it is used (:func:`accepted`)."""

    lam: float
    sigma: float
    pieces: int
    gain: float
    used: bool

    def summary(self) -> dict[str, object]:
        return {
            "lambda": round(self.lam, 3), "sigma": round(self.sigma, 3), "pieces": self.pieces,
            "gain": round(self.gain, 3), "used": self.used,
        }  # fmt: skip


def edge_pieces(image: np.ndarray, bottom_row: int | None = None) -> list[np.ndarray]:
    """(PIECE_PX, 2) float arrays of (u, v) px: nearly straight runs of the image's edges, none reaching
    ``bottom_row`` (the bonnet's edge, px) or below it."""
    grey = cv2.cvtColor(image, cv2.COLOR_BGR2GRAY) if image.ndim == 3 else image
    edges = cv2.Canny(cv2.GaussianBlur(grey, (5, 5), 1.2), 60, 150)
    if bottom_row is not None and 0 < bottom_row < edges.shape[0]:
        edges[max(0, bottom_row - 8) :] = 0  # the bonnet's own curved edge is no straight line
    contours, _ = cv2.findContours(edges, cv2.RETR_LIST, cv2.CHAIN_APPROX_NONE)
    out = []
    for c in contours:
        pts = c[:, 0, :].astype(np.float64)
        for k in range(0, len(pts) - PIECE_PX + 1, PIECE_PX):
            p = pts[k : k + PIECE_PX]
            if np.hypot(*(p[-1] - p[0])) > MIN_SPAN * PIECE_PX:
                out.append(p)
    return out


def _distort(q: np.ndarray, lam: float) -> np.ndarray:
    """Undistorted -> distorted points (radius over the half diagonal) of the division model ``lam``."""
    if abs(lam) < 1e-12:
        return q
    ru = np.hypot(q[..., 0], q[..., 1])
    disc = np.maximum(1.0 - 4.0 * lam * ru**2, 0.0)
    rd = np.where(ru > 1e-12, (1.0 - np.sqrt(disc)) / (2.0 * lam * np.maximum(ru, 1e-12)), 0.0)
    return q * (rd / np.maximum(ru, 1e-12))[..., None]


def residuals(pieces: np.ndarray, size: tuple[int, int], grid: np.ndarray = GRID) -> np.ndarray:
    """(n, len(grid)) straightness RMS (px, capped at CAP_PX) of each (n, m, 2) piece under each ``lam``: the
    piece undistorted, its best line fitted there, and each point's distance in the frame (distorted pixels) from
    its foot on that line mapped back through the lens: the same pixel noise weighs alike under every ``lam``."""
    w, h = size
    s = float(np.hypot(w / 2, h / 2))
    q = (pieces - np.array([w / 2, h / 2])) / s
    r2 = (q**2).sum(-1, keepdims=True)
    out = np.empty((len(q), len(grid)))
    for j, lam in enumerate(grid):
        u = q / (1.0 + lam * r2)
        mean = u.mean(1, keepdims=True)
        d = u - mean
        cov = np.einsum("nmi,nmj->nij", d, d)
        _, vecs = np.linalg.eigh(cov)
        direction = vecs[:, :, 1][:, None, :]  # the line's direction (largest eigenvalue)
        foot = mean + (d * direction).sum(-1, keepdims=True) * direction
        back = _distort(foot, float(lam))
        out[:, j] = np.sqrt(((back - q) ** 2).sum(-1).mean(1)) * s
    return np.minimum(out, CAP_PX)


def estimate_lens(
    images: list[np.ndarray], bottom_row: int | None = None, seed: int = 0, max_images: int = 8
) -> LensEstimate:
    """The lens's division-model coefficient from a few frames (module docstring); ``bottom_row``: the first
    row of the bonnet / dashboard (px), left out."""
    if not images:
        return LensEstimate(0.0, float("nan"), 0, 0.0, False)
    h, w = images[0].shape[:2]
    step = max(1, len(images) // max_images)
    centre, s = np.array([w / 2, h / 2]), float(np.hypot(w / 2, h / 2))
    pieces = [
        p
        for img in images[::step][:max_images]
        for p in edge_pieces(img, bottom_row)
        if np.hypot(*((p.mean(0) - centre) / s)) >= MIN_RADIUS
    ]
    if len(pieces) < MIN_PIECES:
        return LensEstimate(0.0, float("nan"), len(pieces), 0.0, False)
    rng = np.random.default_rng(seed)
    chosen = np.stack(pieces)[:, ::POINT_STEP]
    if len(chosen) > MAX_PIECES:
        chosen = chosen[np.sort(rng.choice(len(chosen), MAX_PIECES, replace=False))]
    res = residuals(chosen, (w, h))
    mean = res.mean(0)
    best = int(np.argmin(mean))
    zero = int(np.argmin(np.abs(GRID)))
    boot = [GRID[int(np.argmin(res[rng.integers(0, len(res), len(res))].mean(0)))] for _ in range(BOOTSTRAP)]
    est = LensEstimate(
        float(GRID[best]), float(np.std(boot)), len(pieces), float(1.0 - mean[best] / max(mean[zero], 1e-9)), False
    )
    est.used = accepted(est)
    return est


def accepted(est: LensEstimate) -> bool:
    """Whether ``est`` is clearly a lens (thresholds in the module's constants)."""
    return bool(
        est.pieces >= MIN_PIECES
        and abs(est.lam) >= MIN_LAM
        and np.isfinite(est.sigma)
        and abs(est.lam) >= SIGMAS * est.sigma
        and est.gain >= MIN_GAIN
        and GRID[0] < est.lam < GRID[-1]  # a minimum at the grid's end is not located
    )


def opencv_coefficients(lam: float, size: tuple[int, int], fx: float) -> list[float]:
    """OpenCV's rational model ``[k1, k2, p1, p2, k3, k4, k5, k6]`` (radius over the focal length ``fx`` px,
    centre at the frame's centre, no tangential terms) that distorts as the division model ``lam`` does, fitted
    over the frame's radii and a fifth beyond its corners (boxes partly outside the frame are projected there).
    The polynomial model alone (k1, k2) misses a strong wide-angle lens by tens of pixels at the corners."""
    w, h = size
    s = float(np.hypot(w / 2, h / 2))
    top = 1.2 if lam >= 0 else min(1.2, 0.9 / np.sqrt(-lam))
    r_d = np.linspace(0.02, top, 120) * s
    r_u = r_d / (1.0 + lam * (r_d / s) ** 2)
    rho2 = (r_u / fx) ** 2
    q = r_d / r_u  # (1 + k1 p + k2 p^2 + k3 p^3) / (1 + k4 p + k5 p^2 + k6 p^3), p = rho^2: linear in the k
    A = np.column_stack([rho2, rho2**2, rho2**3, -q * rho2, -q * rho2**2, -q * rho2**3])
    k, *_ = np.linalg.lstsq(A, q - 1.0, rcond=None)
    return [float(k[0]), float(k[1]), 0.0, 0.0, float(k[2]), float(k[3]), float(k[4]), float(k[5])]


def refocused(distortion: list[float], fx_old: float, fx_new: float) -> list[float]:
    """The same pixel-space radial distortion for a camera whose focal length changed from ``fx_old`` to
    ``fx_new`` (k1, k2, k3 act on the radius over the focal length; the tangential terms are kept)."""
    if not distortion:
        return []
    g = (fx_new / fx_old) ** 2
    d = list(distortion)
    out = [d[0] * g, d[1] * g**2, *d[2:4]]
    if len(d) > 4:
        out.append(d[4] * g**3)
    if len(d) > 5:
        out += [d[5] * g, d[6] * g**2, d[7] * g**3, *d[8:]]
    return out
