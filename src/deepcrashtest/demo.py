"""``make demo``: the whole pipeline, as far as it is built, on the bundled sample clip.

Each stage that lands adds a step here; every output goes under the demo folder.
"""

from __future__ import annotations

import shutil
from dataclasses import dataclass
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
    _step_geometry(out, summary)
    return summary


def _step_geometry(out: Path, summary: dict[str, Any]) -> None:
    """Ego path + lanes from the clip (every 4th frame, at most 50: keeps the demo fast) -> raw Scenario."""
    import av
    import pandas as pd

    from deepcrashtest.geometry.camera import default_camera
    from deepcrashtest.geometry.extract_geometry import extract_geometry

    src = Path(summary["video"])
    with av.open(str(src)) as container:
        stream = container.streams.video[0]
        fps = float(stream.average_rate or 25)
        width, height = stream.codec_context.width, stream.codec_context.height

        @dataclass
        class _Frame:
            index: int
            time: float
            image: Any

        def frames() -> Any:
            for i, frame in enumerate(container.decode(stream)):
                if i >= 200:
                    break
                if i % 4 == 0:
                    yield _Frame(i, i / fps, frame.to_ndarray(format="bgr24")), pd.DataFrame()

        meta = {"path": str(src), "fps": fps, "frame_count": 0, "width": width, "height": height}
        res = extract_geometry(frames(), meta, default_camera(width, height), max_width=640)
    ensure_output_dir(out / "geometry")
    path = res.scenario.save(out / "geometry" / "scenario_raw.json")
    ego = res.scenario.ego.trajectory
    summary["steps"].append(
        {
            "step": "geometry (ego-motion + lanes, default camera)",
            "scenario": str(path),
            "ego_path_m": round(ego.x[-1], 1),
            "lane_width_m": res.lanes.median_lane_width() if res.lanes is not None else None,
            "warnings": res.scenario.warnings,
        }
    )
