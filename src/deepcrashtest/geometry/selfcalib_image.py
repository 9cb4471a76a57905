"""Focal-length evidence from the image alone: the level-camera prior on the horizon.

A dashcam is mounted near level. With the principal point at the image centre, a horizon ``d_h``
pixels below (above) the centre row is a camera pitched ``theta = atan(d_h / f)`` down (up): the same
horizon means a steep pitch at a short focal length and a small one at a long focal length. A prior on
the mounting pitch, ``theta ~ N(0, LEVEL_PITCH_SIGMA_RAD)``, therefore weighs the focal lengths: over a
grid of ``log f`` the focal-length prior (the unknown-dashcam default and its spread) times the pitch
prior at ``atan(d_h / f)`` (the horizon's own 1-sigma ``s_v`` adds ``s_v / f`` to the pitch's) gives a
posterior; what the horizon added to the prior is returned as one Gaussian term in ``log f`` (the
posterior's precision less the prior's), so :func:`deepcrashtest.geometry.selfcalib.combine_focal`
fuses it with the prior and the other estimates like any other. A level-looking horizon (``d_h`` within
a few pixels, KITTI) adds nothing and the term is None: this cue cannot say a focal length is *shorter*
than the prior, only that a horizon far from the centre is more likely a longer focal length than a
steep camera. It cannot tell a longer focal length from a cropped frame (principal point off the
centre row), which keeps its sigma wide.

Measured per clip (issue 14 item 5; horizon rows from the boxes, :mod:`deepcrashtest.geometry.selfcalib`):
the README's "Image-only focal length" notes under the ego speed on dashcam clips. Candidates measured
and not kept (image-only, no poses): the vertical vanishing point (``bench/vertical_lines.py``; lens
distortion dominates the few-degree pitch tilt: the Udacity clip 781 px with a distortion term against
the chessboard 1154, ccd_000014 968 against ~2,400 implied), and epipolar self-calibration of tracked
corners (degenerate on straight drives: ``bench/focal_epipolar.py``).
"""

from __future__ import annotations

import math

import numpy as np

#: 1-sigma (rad) of a dashcam's mounting pitch. Set from the clips whose focal length is known:
#: KITTI's camera 0-1 deg (horizon within ~6 px of cy at 721 px), the Udacity highway clip 3.5 deg
#: (horizon 70 px below the centre at its chessboard 1154 px); not chosen on any crash clip.
LEVEL_PITCH_SIGMA_RAD = math.radians(3.0)
#: The term is dropped when it is weaker than this relative (log) sigma, i.e. carries under a third of
#: the 35 % prior's weight: a horizon within ~45-50 px of the centre row at 640 px (KITTI's
#: self-calibrated horizons lie 0-22 px from cy) leaves the prior alone. Chosen on the fidelity clips'
#: guard rail (issue 16), not on a focal length: at 1.0 the term also acted on dad_000528 (0.67, its
#: replay IoU 0.62 -> 0.28, a contact of its unlabelled crash 0.9 s later) and ccd_000340 (0.66, IoU
#: 0.69 -> 0.62); the clips whose focal length is known or implied are not near it (the Udacity
#: highway 0.45-0.49, ccd_000014 0.30).
MAX_TERM_REL = 0.6
#: The grid of ``log f``: this many prior sigmas either side of the prior, this many points.
GRID_SIGMAS = 6.0
GRID_POINTS = 601


def focal_from_level_horizon(
    horizon_below_cy: float, horizon_sigma_px: float, prior_f: float, prior_rel: float
) -> tuple[float, float, int] | None:
    """What a level camera says of the focal length -> (f px, relative 1-sigma, 1), or None.

    ``horizon_below_cy``: the horizon row minus the principal point's row (px, > 0: below);
    ``horizon_sigma_px``: its 1-sigma (px; NaN or missing counts as 0); ``prior_f`` (px) and
    ``prior_rel`` (relative 1-sigma): the focal-length prior the result is to be fused with (it is
    divided out again, so the term is the horizon's evidence only)."""
    if not (math.isfinite(horizon_below_cy) and prior_f > 0 and prior_rel > 0):
        return None
    sig_v = horizon_sigma_px if math.isfinite(horizon_sigma_px) else 0.0
    mu0 = math.log(prior_f)
    logf = mu0 + np.linspace(-GRID_SIGMAS, GRID_SIGMAS, GRID_POINTS) * prior_rel
    f = np.exp(logf)
    theta = np.arctan(abs(horizon_below_cy) / f)
    var = LEVEL_PITCH_SIGMA_RAD**2 + (sig_v / f) ** 2
    log_post = -0.5 * ((logf - mu0) / prior_rel) ** 2 - 0.5 * theta**2 / var - 0.5 * np.log(var)
    p = np.exp(log_post - log_post.max())
    p /= p.sum()
    mean = float(np.sum(p * logf))
    var_post = float(np.sum(p * (logf - mean) ** 2))
    precision = 1.0 / var_post - 1.0 / prior_rel**2
    if precision <= 1.0 / MAX_TERM_REL**2:
        return None
    mu = (mean / var_post - mu0 / prior_rel**2) / precision
    return math.exp(mu), float(1.0 / math.sqrt(precision)), 1
