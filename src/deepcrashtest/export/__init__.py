"""Export a Scenario for other tools: OpenSCENARIO 1.2 + OpenDRIVE 1.7, CommonRoad, CSV.

``export_scenario(sc, fmt, out_dir)`` writes into ``out_dir``:

* ``openscenario``: ``scenario.xosc`` + ``road.xodr`` (esmini, CARLA ScenarioRunner, VTD ...);
  see :mod:`.openscenario` and :mod:`.opendrive`;
* ``commonroad``: ``commonroad.xml`` (CommonRoad tools); see :mod:`.commonroad`;
* ``csv``: ``trajectories.csv``; see :mod:`.csv` for the columns and units.

All files use the Scenario's world frame (x forward, y left, metres, origin at the ego's start).
"""

from __future__ import annotations

import os
import time
from pathlib import Path
from typing import Any

from deepcrashtest.errors import UserError
from deepcrashtest.fileio import output_set
from deepcrashtest.scenario import Scenario

FORMATS = ("openscenario", "commonroad", "csv")
FILES = {
    "openscenario": ("scenario.xosc", "road.xodr"),
    "commonroad": ("commonroad.xml",),
    "csv": ("trajectories.csv",),
}


def export_scenario(
    sc: Scenario,
    fmt: str,
    out_dir: str | os.PathLike[str],
    ego_free: bool = False,
    force: bool = False,
) -> dict[str, Any]:
    """Write ``sc`` in format ``fmt`` into ``out_dir``; return a summary (files, counts, seconds)."""
    fmt = fmt.strip().lower()
    if fmt not in FORMATS:
        raise UserError(f"--format must be one of {', '.join(FORMATS)} (got {fmt!r})")
    if ego_free and fmt != "openscenario":
        raise UserError("--ego-free applies to --format openscenario only")
    out = Path(out_dir)
    with output_set(out, FILES[fmt], force) as stage:  # all files of one export, or none
        result = _export(sc, fmt, [stage / name for name in FILES[fmt]], ego_free)
    result["files"] = [str(out / name) for name in FILES[fmt]]
    return result


def _export(sc: Scenario, fmt: str, paths: list[Path], ego_free: bool) -> dict[str, Any]:
    force = False  # the staging folder starts empty
    start = time.perf_counter()
    result: dict[str, Any] = {"format": fmt, "scenario": sc.name, "files": [str(p) for p in paths]}
    if fmt == "openscenario":
        from deepcrashtest.export.opendrive import write_opendrive
        from deepcrashtest.export.openscenario import write_openscenario

        write_opendrive(sc.road, paths[1], name=sc.name, force=force)
        write_openscenario(sc, paths[0], road_file=paths[1].name, ego_free=ego_free, force=force)
        result["ego_free"] = ego_free
        result["entities"] = len(sc.vehicles())
    elif fmt == "commonroad":
        from deepcrashtest.export.commonroad import COMMONROAD_DT_S, write_commonroad

        _, skipped = write_commonroad(sc, paths[0], force=force)
        result["dt_s"] = COMMONROAD_DT_S
        result["obstacles"] = len(sc.agents) - len(skipped)
        result["agents_left_out"] = skipped
    else:
        from deepcrashtest.export.csv import write_csv

        write_csv(sc, paths[0], force=force)
        result["rows"] = sum(len(v.trajectory) for v in sc.vehicles())
    result["seconds"] = round(time.perf_counter() - start, 3)
    return result


__all__ = ["FILES", "FORMATS", "export_scenario"]
