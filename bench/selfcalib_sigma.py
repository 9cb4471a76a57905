"""Is the self-calibration's stated 1-sigma honest? Error / sigma per quantity and per focal source.

    PYTHONPATH=src nice -n 10 python bench/selfcalib_sigma.py [--sequences 0,1,2] [--cache DIR]

On the KITTI tracking training sequences (never 3, 8, 10; image tracks cached like
``bench/selfcalib_diag.py``, whose ``--cache`` it can share) the unknown camera is self-calibrated with the
ORB-SLAM3 poses and each quantity is compared with the calibration file's truth: focal length ``fy``
(``P2``), horizon row ``cy`` (the KITTI camera is level to ~1 deg) and camera height 1.65 m; the horizon
and height also with the road plane under the labelled cars (``bench/selfcalib_diag.py``'s line through
their bottom centres, 5-60 m: the plane the localiser assumes, tilted a few px where the road climbs or
falls). For each the error, the stated 1-sigma and ``z = error / sigma``; for the focal length also each
source (parked, moving, turns, bounce) at the relative sigma that
:func:`~deepcrashtest.geometry.selfcalib.combine_focal` gives it. At the end, per quantity, the median
``|z|`` (about 0.67 for an honest Gaussian sigma) and the share within 1 and 2 sigmas (68 % and 95 %).
Only sequences where the quantity was measured count.
"""

from __future__ import annotations

import argparse
import math

import numpy as np
from selfcalib_diag import _calib_parts, _label_road, load_sequence, training_args

from deepcrashtest.geometry import selfcalib as sc_mod

KITTI_HEIGHT_M = 1.65


def _used_rel(name: str, est: tuple[float, float, int]) -> float:
    """The relative sigma :func:`combine_focal` gives a focal source (its thin-support branches included)."""
    if name == "motion":
        return max(est[1], 0.04) if est[2] >= sc_mod.MOTION_MIN_TRACKS else 0.25
    if name == "moving":
        return max(est[1], sc_mod.MOVING_MIN_REL)
    if name == "bounce":
        return max(sc_mod.PITCH_SE_INFLATION * est[1], sc_mod.PITCH_MIN_REL)
    if est[2] >= sc_mod.ROTATION_MIN_PAIRS:
        return max(3 * est[1], sc_mod.ROTATION_MIN_REL)
    return 0.3


def _summary(name: str, z: list[float]) -> str:
    a = np.abs(np.array(z, float))
    a = a[np.isfinite(a)]
    if not len(a):
        return f"{name:>14}: none measured"
    return (
        f"{name:>14}: n {len(a):2d}  median |z| {np.median(a):5.2f} (honest 0.67)  within 1 sigma "
        f"{100 * np.mean(a <= 1):3.0f} % (68)  within 2 {100 * np.mean(a <= 2):3.0f} % (95)  max {a.max():.1f}"
    )


def main() -> None:
    ap = argparse.ArgumentParser()
    args, seqs, cache = training_args(ap, "/tmp/selfcalib_diag")
    keys = ("fy", "horizon", "horizon_road", "height", "height_road", "motion", "moving", "bounce", "rotation")
    zs: dict[str, list[float]] = {k: [] for k in keys}
    for s in seqs:
        prep, tracks, ego, start = load_sequence(s, cache)
        cal = sc_mod.self_calibrate(tracks, start, prep.size, ego)
        true = prep.camera
        line = [f"{s:04d}"]
        measured = cal.camera.intrinsics_source == "self_calibration"
        e = math.log(cal.fy / true.fy)
        z = e / (cal.fy_sigma / cal.fy) if measured else float("nan")
        zs["fy"].append(z)
        line.append(f"fy {100 * e:+5.1f} % +- {100 * cal.fy_sigma / cal.fy:4.1f} (z {z:+5.1f})")
        for k, est in _calib_parts(tracks, start, prep.size, ego).items():
            if est is None:
                continue
            rel = _used_rel(k, est)
            ek = math.log(est[0] / true.fy)
            zs[k].append(ek / rel)
            line.append(f"{k} {100 * ek:+.1f}+-{100 * rel:.0f}")
        vh_road, hc_road = _label_road(s, true)
        for key, truth in (("horizon", true.cy), ("horizon_road", vh_road)):
            ev = cal.horizon_v - truth
            zs[key].append(ev / cal.horizon_sigma_px)
            line.append(f"| {key} {ev:+5.1f} px +- {cal.horizon_sigma_px:.1f} (z {zs[key][-1]:+5.1f})")
        for key, truth in (("height", KITTI_HEIGHT_M), ("height_road", hc_road)):
            eh = cal.height_m - truth
            zs[key].append(eh / cal.height_sigma_m)
            line.append(f"| {key} {eh:+.2f} m +- {cal.height_sigma_m:.2f} (z {zs[key][-1]:+5.1f})")
        print(" ".join(line), flush=True)
    for k, z in zs.items():
        print(_summary(k, z))


if __name__ == "__main__":
    main()
