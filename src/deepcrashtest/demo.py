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
    _step_perception(out, summary)

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
    return summary


def _step_perception(out: Path, summary: dict[str, Any]) -> None:
    """Stage 1a: detect + track vehicles in the demo clip -> extract/tracks.csv, extract/annotated.mp4."""
    from deepcrashtest.extract import run_extract

    r = run_extract(summary["video"], out / "extract", detect_every=10, force=True)
    summary["steps"].append(
        {
            "step": "extract (detect + track)",
            "tracks_csv": r["tracks_csv"],
            "annotated_mp4": r["annotated_mp4"],
            "frames": r["frames"],
            "tracks": r["tracks"],
            "fps_achieved": r["fps_achieved"],
        }
    )
