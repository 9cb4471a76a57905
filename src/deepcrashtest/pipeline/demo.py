"""``make demo``: the whole pipeline, as far as it is built, on the bundled sample clip.

Each stage that lands adds a step here; every output goes under the demo folder.
"""

from __future__ import annotations

import shutil
from pathlib import Path
from typing import Any

from deepcrashtest.errors import UserError
from deepcrashtest.fileio import ensure_output_dir, require_file
from deepcrashtest.scenario import Scenario

SAMPLE_VIDEO = Path(__file__).resolve().parents[3] / "examples" / "highway_sample.mp4"
KITTI_TRACKING = Path(__file__).resolve().parents[3].parent / "shared" / "data" / "kitti_tracking"


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
        from deepcrashtest.pipeline.kitti import kitti_scenarios

        raw, sc = kitti_scenarios(KITTI_TRACKING, 8, seed=0)
        path = sc.save(ensure_output_dir(out / "kitti_0008") / "scenario.json")
        summary["steps"].append({"step": "scenario from-kitti 8", "scenario": str(path), "agents": len(sc.agents)})
        _step_export(out, summary)
        _step_sim(out, summary, raw)
        _step_search(out, summary)
        _step_report(out, summary)
        _step_trajectory(out, summary, raw, sc)
    _step_eval(out, summary)
    return summary


def _step_export(out: Path, summary: dict) -> None:
    """Export the KITTI 0008 scenario written above to OpenSCENARIO + OpenDRIVE, CommonRoad and CSV."""
    from deepcrashtest.export import FORMATS, export_scenario

    src = out / "kitti_0008" / "scenario.json"
    if not src.exists():
        return
    sc = Scenario.load(src)
    for fmt in FORMATS:
        res = export_scenario(sc, fmt, out / "export")
        summary["steps"].append({"step": f"export {fmt}", "files": res["files"], "seconds": res["seconds"]})


def _step_sim(out: Path, summary: dict[str, Any], base: Scenario) -> None:
    """Simulate the raw KITTI 0008 scenario (replay, aeb) and a crash made from it; bird's-eye videos in out/sim."""
    from deepcrashtest.sim import replay_error, simulate
    from deepcrashtest.sim.testcases import meet_ego
    from deepcrashtest.viz.birdseye import write_birdseye

    folder = ensure_output_dir(out / "sim")
    # agent 11 (a real oncoming car) moved to meet the ego at t = 10 s: a crash that KITTI lacks
    crash = meet_ego(base, 11, 10.0)
    crash.save(folder / "kitti_0008_crash_scenario.json")
    runs = []
    for name, sc, duration in (("kitti_0008", base, None), ("kitti_0008_crash", crash, 14.0)):
        for ctrl in ("replay", "aeb"):
            res = simulate(sc, controller=ctrl, duration=duration)
            entry = {"scenario": name, "controller": ctrl, **res.metrics, "replay_rms_m": replay_error(sc, res)["all"]}
            if name == "kitti_0008_crash":
                entry["video"] = write_birdseye(sc, res, folder / f"{name}_{ctrl}.mp4")
            runs.append(entry)
    summary["steps"].append({"step": "simulate", "runs": runs})


def _step_search(out: Path, summary: dict[str, Any]) -> None:
    """128 random variants + CEM + boundary scan on the demo's KITTI scenario with a crash injected.

    KITTI drives have no crash: the oncoming car 10 is shifted to meet the ego front to front at
    t = 8.8 s (``sim.testcases.meet_ego``; recorded in the scenario's provenance and warnings).
    """
    from deepcrashtest.search.run import SearchConfig, run_search
    from deepcrashtest.sim.testcases import meet_ego

    src = out / "kitti_0008" / "scenario.json"
    if not src.exists():
        return
    base = Scenario.load(src)
    # 8.8 s into the video; a processed scenario starts t_max earlier (step-back initialisation)
    sc = meet_ego(base, 10, 8.8 + float(base.provenance.parameters.get("t_max_s", 0.0)))
    folder = ensure_output_dir(out / "search")
    sc.save(folder / "crash_scenario.json")
    res = run_search(sc, folder, SearchConfig(duration=(sc.collision.time_s if sc.collision else 0.0) + 2.5))
    summary["steps"].append(
        {
            "step": "search (128 random variants + CEM)",
            "output": str(folder),
            "random_safe": res["methods"].get("random", {}).get("safe"),
            "first_safe_random": res["methods"].get("random", {}).get("first_safe_at"),
            "first_safe_cem": res["methods"].get("cem", {}).get("first_safe_at"),
            "best_change_m": (res["best_safe"] or {}).get("change_m"),
        }
    )


def _step_report(out: Path, summary: dict[str, Any]) -> None:
    """report.html of the KITTI 0008 scenario (+ its replay in the simulator, files beside it when present)."""
    from deepcrashtest.viz.report import build_report

    scenario = out / "kitti_0008" / "scenario.json"
    if not scenario.exists():
        return
    from deepcrashtest.sim import simulate

    metrics = simulate(Scenario.load(scenario), controller="replay", seed=0).metrics
    res = build_report(scenario, out / "report.html", sim_metrics=metrics)
    summary["steps"].append({"step": "report", "report": res["report"], "sections": len(res["sections"])})


def _step_eval(out: Path, summary: dict) -> None:
    """World-frame tracking evaluation of KITTI sequence 8 (PointRCNN detections, 2 m matching)."""
    if not KITTI_TRACKING.exists():
        return
    from deepcrashtest.eval.kitti import evaluate_kitti, results_markdown
    from deepcrashtest.pipeline.kitti import write_results

    result = evaluate_kitti(KITTI_TRACKING, [8])
    folder = out / "eval"
    write_results(result, folder, results_markdown(result))
    row = result["sequences"]["0008"]
    summary["steps"].append(
        {"step": "evaluate kitti 8", "table": str(folder / "results.md"), "MOTA": row["MOTA"], "HOTA": row["HOTA"]}
    )


def _step_trajectory(out: Path, summary: dict[str, Any], raw: Scenario, sc: Scenario) -> None:
    """Stage 2 on KITTI 0008 (real labels + poses): bird's-eye PNG of raw vs processed tracks and road."""
    from deepcrashtest.viz.plots import plot_birdseye

    png = plot_birdseye(sc, raw, out / "trajectory_kitti_0008_birdseye.png", force=True)
    summary["steps"].append(
        {
            "step": "trajectory (stage 2) KITTI 0008",
            "birdseye": str(png),
            "t_max_s": round(float(sc.provenance.parameters["t_max_s"]), 3),
            "classes": sc.class_counts(),
        }
    )


def _step_perception(out: Path, summary: dict[str, Any]) -> None:
    """Stage 1 + 2 on the demo clip in one pass (detect + track, ego-motion, lanes, 3D, stage 2) -> extract/.

    Then the extracted scenario is replayed in the simulator (bird's-eye video) and exported.
    """
    from deepcrashtest.export import export_scenario
    from deepcrashtest.pipeline.extract import run_extract
    from deepcrashtest.sim import simulate
    from deepcrashtest.viz.birdseye import write_birdseye

    r = run_extract(summary["video"], out / "extract", force=True)
    step: dict[str, Any] = {
        "step": "extract (stage 1 + 2 on the video)",
        **{k: r.get(k) for k in ("frames", "tracks", "fps_achieved", "agents", "classes", "collision")},
        **{k: r.get(k) for k in ("tracks_csv", "annotated_mp4", "scenario", "report")},
    }
    if r.get("scenario"):
        sc = Scenario.load(r["scenario"])
        res = simulate(sc, controller="replay")
        step["simulate_replay"] = {k: res.metrics[k] for k in ("collided", "min_distance", "min_ttc")}
        step["birdseye_mp4"] = str(write_birdseye(sc, res, out / "extract" / "birdseye.mp4"))
        step["export"] = export_scenario(sc, "openscenario", out / "extract" / "export")["files"]
    summary["steps"].append(step)
