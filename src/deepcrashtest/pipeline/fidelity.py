"""``deepcrashtest evaluate fidelity``: scenario + its video's tracks -> replay -> fidelity outputs.

Chains the simulator (:func:`deepcrashtest.sim.simulate`), the measurement
(:func:`deepcrashtest.eval.fidelity.evaluate_fidelity`) and the overlay video
(:mod:`deepcrashtest.viz.fidelity_video`). Writes into the output folder, as one set from one run
(every target is checked before any work; each file is written atomically):
``fidelity.json`` (the summary), ``fidelity_pairs.csv`` (one row per tracked box) and
``fidelity.mp4`` (the overlay).
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

from deepcrashtest.datasets.crash_labels import CrashLabel, load_crash_labels
from deepcrashtest.errors import UserError
from deepcrashtest.eval.fidelity import FidelityResult, evaluate_fidelity, fidelity_json, read_tracks
from deepcrashtest.fileio import atomic_path, atomic_write_text, check_writable, ensure_output_dir
from deepcrashtest.scenario import Scenario

OUTPUT_NAMES = {"json": "fidelity.json", "pairs": "fidelity_pairs.csv", "video": "fidelity.mp4"}


def default_inputs(scenario_path: Path, scenario: Scenario) -> tuple[Path | None, Path]:
    """(video, tracks) beside a scenario: the source video when it exists, else ``annotated.mp4``; ``tracks.csv``."""
    folder = scenario_path.parent
    src = Path(scenario.source.path)
    if scenario.source.kind == "video" and src.is_file():
        video: Path | None = src
    elif (folder / "annotated.mp4").is_file():
        video = folder / "annotated.mp4"
    else:
        video = None
    return video, folder / "tracks.csv"


def pick_label(labels_path: Path, scenario: Scenario, clip: str | None = None) -> CrashLabel:
    """The label of ``clip`` (default: the scenario's source video name) from a crash-label file, its boxes in the
    scenario's pixels (a video processed scaled: provenance ``frames_scaled_from``, the file's size)."""
    labels = load_crash_labels(labels_path)
    name = clip or Path(scenario.source.path).stem
    if name not in labels:
        raise UserError(f"{labels_path}: no label for clip {name!r} (labelled: {', '.join(sorted(labels))})")
    stored = scenario.provenance.parameters.get("frames_scaled_from")
    if not stored:
        return labels[name]
    return labels[name].scaled(scenario.source.width / stored[0], scenario.source.height / stored[1])


def run_fidelity(
    scenario_path: str | Path,
    output: str | Path | None = None,
    video: str | Path | None = None,
    tracks: str | Path | None = None,
    labels: str | Path | None = None,
    clip: str | None = None,
    controller: str = "replay",
    make_video: bool = True,
    force: bool = False,
    seed: int = 0,
) -> tuple[FidelityResult, dict[str, Any]]:
    """Evaluate the fidelity of a scenario file and write the outputs (see the module docstring).

    Returns the result and a summary dict (the JSON of ``fidelity.json`` plus the written paths).
    """
    from deepcrashtest.sim import simulate

    sc_path = Path(scenario_path)
    scenario = Scenario.load(sc_path)
    default_video, default_tracks = default_inputs(sc_path, scenario)
    tracks_path = Path(tracks) if tracks is not None else default_tracks
    video_path = Path(video) if video is not None else default_video
    if make_video and video_path is None:
        raise UserError(f"no video found beside {sc_path} (source {scenario.source.path}): pass --video or --no-video")
    if video_path is not None and not video_path.exists():
        raise UserError(f"{video_path}: video not found")
    label = pick_label(Path(labels), scenario, clip) if labels is not None else None
    out = Path(output) if output is not None else sc_path.parent
    targets = {k: out / v for k, v in OUTPUT_NAMES.items() if k != "video" or make_video}
    for p in targets.values():
        check_writable(p, force)
    table = read_tracks(tracks_path)
    sim = simulate(scenario, controller=controller, seed=seed)
    result = evaluate_fidelity(scenario, table, sim, label, name=sc_path.stem)
    ensure_output_dir(out)
    summary = result.to_dict()
    summary["inputs"] = {
        "scenario": str(sc_path),
        "tracks": str(tracks_path),
        "video": str(video_path) if video_path else None,
        "labels": str(labels) if labels else None,
        "controller": controller,
    }
    summary["outputs"] = {k: str(p) for k, p in targets.items()}
    if make_video and video_path is not None:
        from deepcrashtest.viz.fidelity_video import write_fidelity_video

        write_fidelity_video(scenario, result, sim, video_path, table, targets["video"], label, force=force)
    with atomic_path(targets["pairs"], force=force) as tmp:
        pairs_table(result).to_csv(tmp, index=False, float_format="%.4f")
    atomic_write_text(targets["json"], fidelity_json(summary), force)
    return result, summary


def pairs_table(result: FidelityResult) -> Any:
    """The per-pair table with each projected box as four columns ``{src}_x1 .. {src}_y2`` (empty when none)."""
    import numpy as np

    df = result.pairs.copy()
    for col in [c for c in df.columns if c.endswith("_box")]:
        src = col.removesuffix("_box")
        boxes = np.array([b if b is not None else [np.nan] * 4 for b in df[col]], dtype=float).reshape(-1, 4)
        for j, name in enumerate(("x1", "y1", "x2", "y2")):
            df[f"{src}_{name}"] = boxes[:, j]
        df = df.drop(columns=col)
    return df


__all__ = ["OUTPUT_NAMES", "default_inputs", "fidelity_json", "pairs_table", "pick_label", "run_fidelity"]
