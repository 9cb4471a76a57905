"""KITTI runs: labels -> raw and processed Scenario, and writing an evaluation's results (json + markdown).

Used by the CLI (``scenario from-kitti``, ``evaluate kitti``) and the demo, so the chain is written once.
"""

from __future__ import annotations

import json
import math
from pathlib import Path
from typing import Any

from deepcrashtest.datasets.kitti.scenario import scenario_from_kitti
from deepcrashtest.fileio import atomic_write_text, check_writable, ensure_output_dir
from deepcrashtest.pipeline.stage2 import processed_scenario
from deepcrashtest.scenario import Scenario
from deepcrashtest.trajectory.params import Stage2Params

RESULT_FILES = ("results.json", "results.md")


def kitti_scenarios(
    data: str | Path, sequence: int, seed: int = 0, params: Stage2Params | None = None
) -> tuple[Scenario, Scenario]:
    """The raw Scenario of a KITTI tracking sequence (labels + poses + calib) and its stage-2 processing."""
    raw = scenario_from_kitti(data, sequence)
    return raw, processed_scenario(raw, seed=seed, params=params)


def check_results_writable(folder: str | Path, force: bool) -> None:
    """Refuse before any work when ``results.json``/``results.md`` exist in ``folder`` and not ``force``."""
    for name in RESULT_FILES:
        check_writable(Path(folder) / name, force=force)


def write_results(result: dict[str, Any], folder: str | Path, markdown: str, force: bool = False) -> list[Path]:
    """Write an evaluation's ``results.json`` (non-finite numbers as null) and ``results.md`` into ``folder``."""
    out = ensure_output_dir(folder)
    text = json.dumps(_finite(result), indent=1) + "\n"
    return [
        atomic_write_text(out / "results.json", text, force),
        atomic_write_text(out / "results.md", markdown, force),
    ]


def _finite(value: Any) -> Any:
    """JSON-safe copy: numpy scalars/arrays to Python, NaN/inf to None (recursively)."""
    if isinstance(value, dict):
        return {str(k): _finite(v) for k, v in value.items()}
    if isinstance(value, list | tuple):
        return [_finite(v) for v in value]
    if hasattr(value, "tolist"):
        return _finite(value.tolist())
    if isinstance(value, Path):
        return str(value)
    if isinstance(value, float) and not math.isfinite(value):
        return None
    return value
