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
    _step_eval(out, summary)
    return summary


def _step_eval(out: Path, summary: dict) -> None:
    """World-frame tracking evaluation of KITTI sequence 8 (PointRCNN detections, 2 m matching)."""
    if not KITTI_TRACKING.exists():
        return
    import json

    from deepcrashtest.eval.kitti import evaluate_kitti, results_markdown
    from deepcrashtest.fileio import atomic_write_text

    result = evaluate_kitti(KITTI_TRACKING, [8])
    folder = ensure_output_dir(out / "eval")
    atomic_write_text(folder / "results.json", json.dumps(result, indent=1, allow_nan=True) + "\n")
    atomic_write_text(folder / "results.md", results_markdown(result))
    row = result["sequences"]["0008"]
    summary["steps"].append(
        {"step": "evaluate kitti 8", "table": str(folder / "results.md"), "MOTA": row["MOTA"], "HOTA": row["HOTA"]}
    )
