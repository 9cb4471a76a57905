"""The ego speed filter's readings per clip: what it fused, gated or re-started on, and what it output.

Runs :class:`~deepcrashtest.geometry.egomotion.EgoMotionEstimator` as ``bench/ego_speed_overlays.py`` does
(camera estimated from the first 2 s, road users masked with ``--tracks DIR``/<clip>/tracks.csv, e.g. a
fidelity extract) on the fidelity clips (``bench/fidelity_crashes.py``'s labels and the Udacity highway clip)
and prints per clip the road-scale readings of ``SpeedFilter`` (frame step, km/h, 1-sigma km/h, outcome:
start / fused / gated / restart) and the smoothed output (median, every 10th frame). A first reading that
the later ones disagree with is held until ``max_rejects`` come in a row (README, ego speed on real
dashcam clips). ``--fx PX --height M``: another camera for the estimator (as the overlay bench).

Run: PYTHONPATH=src python bench/speed_filter_readings.py --tracks /work/cache/fid_s7 [--clips a,b] [--fx PX --height M]
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from ego_speed_overlays import DATA, run_clip  # noqa: E402
from fidelity_crashes import all_labels  # noqa: E402

HIGHWAY = "highway_project_video"


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--tracks", required=True, help="folder with <clip>/tracks.csv (a fidelity extract)")
    ap.add_argument("--clips", default="", help="comma-separated clip names (default: every folder in --tracks)")
    ap.add_argument("--fx", type=float, default=None, help="focal length (px) for the estimator")
    ap.add_argument("--height", type=float, default=None, help="camera height (m) for the estimator")
    args = ap.parse_args()
    tracks = Path(args.tracks)
    labels = all_labels()
    names = args.clips.split(",") if args.clips else sorted(p.name for p in tracks.iterdir() if p.is_dir())
    for name in names:
        video = DATA / "dashcam_udacity" / f"{HIGHWAY}.mp4" if name == HIGHWAY else DATA / labels[name][1].video
        r = run_clip(video, False, 300, tracks / name / "tracks.csv", {}, camera=(args.fx, args.height))
        readings = r.readings or []
        outcomes = [o for *_, o in readings]
        counts = ", ".join(f"{outcomes.count(o)} {o}" for o in ("fused", "gated", "restart"))
        print(
            f"{name}: {len(readings)} readings ({counts}); output median {np.median(r.speed[1:]) * 3.6:.1f} km/h "
            f"(camera fx {r.fx:.0f} px, height {r.height_m:.2f} m, before extract's rescale x{r.ego_scale:.2f})"
        )
        marks = {"start": "S", "restart": "R", "gated": "*", "fused": ""}
        line = " ".join(f"{s + 1}:{z * 3.6:.0f}+-{np.sqrt(v) * 3.6:.0f}{marks[o]}" for s, z, v, o in readings)
        print(f"   readings (frame:km/h+-sd, S start, * gated, R restart): {line}")
        print(f"   output every 10th frame, km/h: {np.round(r.speed[::10] * 3.6, 1).tolist()}")


if __name__ == "__main__":
    main()
