"""Test helpers for the exporters: an independent OpenSCENARIO polyline reader and the ASAM checkers.

The reader is deliberately small and separate from ``deepcrashtest.export``: it parses the .xosc
with lxml, resolves the declared parameters (and the ``${$P +/- number}`` expressions the ego's
start uses), and interpolates each entity's polyline vertices linearly in time.
"""

from __future__ import annotations

import re
import subprocess
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
from lxml import etree

ROOT = Path(__file__).resolve().parents[1]
QC_VENV = ROOT / ".venv-qc"

_EXPR = re.compile(r"^\$\{\$([A-Za-z_]\w*) ([+-]) ([0-9]+(?:\.[0-9]+)?)\}$")


def resolve(value: str, params: dict[str, float]) -> float:
    """A number, ``$Param`` or ``${$Param + 1.5}`` / ``${$Param - 1.5}`` as a float."""
    m = _EXPR.match(value)
    if m:
        base = params[m.group(1)]
        num = float(m.group(3))
        return base + num if m.group(2) == "+" else base - num
    if value.startswith("$"):
        return params[value[1:]]
    return float(value)


@dataclass
class EntityReplay:
    """One entity as read back: bounding-box centre offset, start time, polyline vertices."""

    name: str
    center_x: float
    start_trigger: float | None = None
    start_rule: str | None = None
    times: np.ndarray = field(default_factory=lambda: np.zeros(0))
    ref_xyh: np.ndarray = field(default_factory=lambda: np.zeros((0, 3)))
    init_teleport: tuple[float, float, float] | None = None
    deleted_at_init: bool = False
    added_at: tuple[float, float, float] | None = None

    def centre_at(self, t: np.ndarray) -> np.ndarray:
        """Box centre (x, y) at times ``t``: reference point interpolated in time + offset along h."""
        x = np.interp(t, self.times, self.ref_xyh[:, 0])
        y = np.interp(t, self.times, self.ref_xyh[:, 1])
        h = np.interp(t, self.times, np.unwrap(self.ref_xyh[:, 2]))
        return np.column_stack([x + self.center_x * np.cos(h), y + self.center_x * np.sin(h)])


def _world(pos: etree._Element, params: dict[str, float]) -> tuple[float, float, float]:
    wp = pos.find("WorldPosition")
    assert wp is not None, "expected a WorldPosition"
    return (resolve(wp.get("x"), params), resolve(wp.get("y"), params), resolve(wp.get("h", "0"), params))


def read_xosc(path: Path, overrides: dict[str, float] | None = None) -> dict[str, EntityReplay]:
    """Entities of an exported .xosc, with parameters at their defaults unless overridden."""
    root = etree.parse(str(path)).getroot()
    params = {p.get("name"): float(p.get("value")) for p in root.iterfind("ParameterDeclarations/ParameterDeclaration")}
    params.update(overrides or {})
    ents: dict[str, EntityReplay] = {}
    for obj in root.iterfind("Entities/ScenarioObject"):
        centre = obj.find("Vehicle/BoundingBox/Center")
        centre = centre if centre is not None else obj.find("Pedestrian/BoundingBox/Center")
        ents[obj.get("name")] = EntityReplay(obj.get("name"), float(centre.get("x")))
    for priv in root.iterfind("Storyboard/Init/Actions/Private"):
        tele = priv.find("PrivateAction/TeleportAction/Position")
        if tele is not None:
            ents[priv.get("entityRef")].init_teleport = _world(tele, params)
    for ga in root.iterfind("Storyboard/Init/Actions/GlobalAction/EntityAction"):
        if ga.find("DeleteEntityAction") is not None:
            ents[ga.get("entityRef")].deleted_at_init = True
    for group in root.iter("ManeuverGroup"):
        actor = group.find("Actors/EntityRef").get("entityRef")
        ent = ents[actor]
        for event in group.iter("Event"):
            cond = event.find(".//StartTrigger//SimulationTimeCondition")
            ent.start_trigger = float(cond.get("value"))
            ent.start_rule = cond.get("rule")
            add = event.find(".//AddEntityAction/Position")
            if add is not None:
                ent.added_at = _world(add, params)
            verts = event.findall(".//FollowTrajectoryAction//Polyline/Vertex")
            if verts:
                ent.times = np.array([float(v.get("time")) for v in verts])
                ent.ref_xyh = np.array([_world(v.find("Position"), params) for v in verts])
    return ents


# --------------------------------------------------------------------------- ASAM Quality Checkers
def qc_available() -> bool:
    return (QC_VENV / ".installed").exists() and (QC_VENV / "bin" / "qc_opendrive").exists()


def run_qc(kind: str, input_file: Path, workdir: Path) -> dict:
    """Run the ASAM checker bundle ``kind`` (``xodr`` | ``xosc``) on ``input_file``.

    Returns {"errors": [...descriptions], "warnings": [...], "checkers": {id: status}}.
    """
    bundle, exe = {"xodr": ("xodrBundle", "qc_opendrive"), "xosc": ("xoscBundle", "qc_openscenario")}[kind]
    workdir.mkdir(parents=True, exist_ok=True)
    result = workdir / f"{input_file.stem}_{kind}.xqar"
    config = workdir / f"{input_file.stem}_{kind}_config.xml"
    config.write_text(
        '<?xml version="1.0" encoding="UTF-8"?>\n<Config>\n'
        f'  <Param name="InputFile" value="{input_file.resolve()}"/>\n'
        f'  <CheckerBundle application="{bundle}">\n'
        f'    <Param name="resultFile" value="{result.resolve()}"/>\n'
        "  </CheckerBundle>\n</Config>\n",
        encoding="utf-8",
    )
    proc = subprocess.run(
        [str(QC_VENV / "bin" / exe), "-c", str(config)], cwd=workdir, capture_output=True, text=True, timeout=300
    )
    assert proc.returncode == 0, f"{exe} failed: {proc.stderr[-2000:]}"
    tree = etree.parse(str(result)).getroot()
    out: dict = {"errors": [], "warnings": [], "checkers": {}}
    for checker in tree.iter("Checker"):
        out["checkers"][checker.get("checkerId")] = checker.get("status")
        for issue in checker.iter("Issue"):
            text = f"{checker.get('checkerId')}: {issue.get('description')}"
            (out["errors"] if issue.get("level") == "1" else out["warnings"]).append(text)
    return out
