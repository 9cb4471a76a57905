"""``make demo``: the whole pipeline, as far as it is built, on the bundled sample clip.

Each stage that lands adds a step here; every output goes under the demo folder.
"""

from __future__ import annotations

import shutil
from pathlib import Path
from typing import Any

from deepcrashtest.errors import UserError
from deepcrashtest.fileio import ensure_output_dir, require_file

SAMPLE_VIDEO = Path(__file__).resolve().parents[2] / "examples" / "highway_sample.mp4"
KITTI_TRACKING = Path(__file__).resolve().parents[2].parent / "shared" / "data" / "kitti_tracking"


def run_demo(output: str | Path, video: str | Path | None = None) -> dict[str, Any]:
    """Run every available stage; return a summary of what was written."""
    out = Path(output)
    if out.exists():
        shutil.rmtree(out)  # the demo folder is the demo's own: always rebuilt from scratch
    ensure_output_dir(out)
    src = Path(video) if video is not None else SAMPLE_VIDEO
    if not src.exists():
        raise UserError(f"{src}: demo video not found")
    require_file(src, "video")
    summary: dict[str, Any] = {"output": str(out), "video": str(src), "steps": []}

    # Step: a Scenario from KITTI ground truth (real trajectories), when the shared data is present.
    if KITTI_TRACKING.exists():
        from deepcrashtest.trajectory.from_kitti import scenario_from_kitti

        sc = scenario_from_kitti(KITTI_TRACKING, 8)
        try:
            from deepcrashtest.trajectory.pipeline import process_scenario

            sc = process_scenario(sc, seed=0)
        except ImportError:
            pass
        path = sc.save(out / "kitti_0008" / "scenario.json") if ensure_output_dir(out / "kitti_0008") else None
        summary["steps"].append({"step": "scenario from-kitti 8", "scenario": str(path), "agents": len(sc.agents)})
    _step_trajectory(out, summary)
    return summary


def _step_trajectory(out: Path, summary: dict[str, Any]) -> None:
    """Stage 2 on KITTI 0008 (real labels + poses): bird's-eye PNG of raw vs processed tracks and road."""
    if not KITTI_TRACKING.exists():
        return
    from deepcrashtest.trajectory.from_kitti import scenario_from_kitti
    from deepcrashtest.trajectory.pipeline import process_scenario
    from deepcrashtest.viz.plots import plot_birdseye

    raw = scenario_from_kitti(KITTI_TRACKING, 8)
    sc = process_scenario(raw, seed=0)
    png = plot_birdseye(sc, raw, out / "trajectory_kitti_0008_birdseye.png", force=True)
    classes: dict[str, int] = {}
    for a in sc.agents:
        classes[str(a.trajectory_class)] = classes.get(str(a.trajectory_class), 0) + 1
    summary["steps"].append(
        {
            "step": "trajectory (stage 2) KITTI 0008",
            "birdseye": str(png),
            "t_max_s": round(float(sc.provenance.parameters["t_max_s"]), 3),
            "classes": dict(sorted(classes.items())),
        }
    )
