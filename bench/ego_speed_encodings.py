"""The ego's speed across encodings of one clip: does a re-encoding, a smaller frame, half the frame rate or another
lens change what the geometry stage reads?

Reads the extracts that ``bench/fidelity_crashes.py --work A`` (the clips as filmed) and
``bench/fidelity_perturbed.py --work B`` (their variants: mirrored, 854x480, half frame rate, re-encoded, wide-angle,
longer lens) left, and prints per clip the median ego speed (km/h, over the raw scenario's ego path) as filmed and in
each variant set, then three figures:

* ``spread``: per clip the median over its variants of ``|ln((v + 3) / (v0 + 3))|`` (v0 as filmed, v a variant, km/h;
  3 km/h keeps a stopped ego from dividing by zero), averaged over the clips: 0 when every encoding reads the same
  speed, 0.69 when they are a factor of two apart;
* ``collapses``: variants that read under a quarter of the speed as filmed where that is at least 10 km/h (the
  ego-motion lost the road and called the ego stopped or crawling);
* ``jumps``: variants that read over four times the speed as filmed where that is at least 10 km/h.

None of these needs the true speed (only two clips show theirs: ``bench/ego_speed_overlays.py``); they measure how
much of a clip's speed is the measurement's own noise. A clip missing from a work folder is left out.

Run: PYTHONPATH=src python bench/ego_speed_encodings.py --original A --variants-work B [--variants mirror,small,...]
"""

from __future__ import annotations

import argparse
import math
from pathlib import Path

import numpy as np

from deepcrashtest.scenario import Scenario

VARIANTS = ("mirror", "small", "halffps", "copy", "fisheye", "zoom")
#: km/h added to both speeds before their log ratio (a stopped ego reads 0).
SOFT_KMH = 3.0
#: A variant's speed under COLLAPSE_SHARE (over 1 / COLLAPSE_SHARE) of the speed as filmed is a collapse (a jump),
#: counted where the clip as filmed reads at least MOVING_KMH.
COLLAPSE_SHARE = 0.25
MOVING_KMH = 10.0


def median_ego_speed_kmh(out_dir: Path) -> float | None:
    """Median speed (km/h) along the ego's path in ``out_dir/scenario_raw.json``; None where there is none."""
    path = out_dir / "scenario_raw.json"
    if not path.exists():
        return None
    ego = Scenario.load(path).ego.trajectory.arrays()
    dt = np.diff(ego["t"])
    if not len(dt):
        return None
    speed = np.hypot(np.diff(ego["x"]), np.diff(ego["y"])) / np.maximum(dt, 1e-6)
    return float(np.median(speed)) * 3.6


def spread(original: float, variants: list[float]) -> float:
    """Median ``|ln((v + SOFT_KMH) / (original + SOFT_KMH))|`` over the variants' speeds (km/h)."""
    return float(np.median([abs(math.log((v + SOFT_KMH) / (original + SOFT_KMH))) for v in variants]))


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--original", type=Path, required=True, help="bench/fidelity_crashes.py's --work folder")
    ap.add_argument("--variants-work", type=Path, required=True, help="bench/fidelity_perturbed.py's --work folder")
    ap.add_argument("--variants", default=",".join(VARIANTS), help="comma-separated variant sets")
    args = ap.parse_args()
    sets = [v for v in args.variants.split(",") if v]
    for folder in (args.original, args.variants_work):
        if not folder.is_dir():
            ap.error(f"{folder} is not a folder")
    clips = sorted(p.name for p in args.original.iterdir() if (p / "scenario_raw.json").exists())
    print(f"{'clip':24s} {'filmed':>7s} " + " ".join(f"{v:>8s}" for v in sets) + "   spread")
    spreads: list[float] = []
    collapses = jumps = compared = 0
    for clip in clips:
        v0 = median_ego_speed_kmh(args.original / clip)
        speeds = [median_ego_speed_kmh(args.variants_work / v / "out" / clip) for v in sets]
        found = [s for s in speeds if s is not None]
        if v0 is None or not found:
            continue
        s = spread(v0, found)
        spreads.append(s)
        compared += len(found)
        if v0 >= MOVING_KMH:
            collapses += sum(v < COLLAPSE_SHARE * v0 for v in found)
            jumps += sum(v > v0 / COLLAPSE_SHARE for v in found)
        cells = " ".join(f"{x:8.1f}" if x is not None else f"{'-':>8s}" for x in speeds)
        print(f"{clip:24s} {v0:7.1f} {cells}   {s:.2f}")
    if not spreads:
        ap.error(f"no clip has a scenario_raw.json in both {args.original} and {args.variants_work}/<set>/out")
    print(
        f"\n{len(spreads)} clips, {compared} variants: "
        f"spread mean {np.mean(spreads):.3f} median {np.median(spreads):.3f}; "
        f"collapses {collapses}, jumps {jumps} (speed as filmed >= {MOVING_KMH:.0f} km/h)"
    )


if __name__ == "__main__":
    main()
