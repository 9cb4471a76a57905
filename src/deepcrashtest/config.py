"""One configuration file (YAML) merged over the defaults, for the commands that take ``--config``.

The defaults live once, in the stages' typed dataclasses (:class:`~deepcrashtest.trajectory.params.Stage2Params`,
:class:`~deepcrashtest.search.run.SearchConfig`); a file overrides any of their fields by section::

    stage2:
      stepback_accel_mps2: 2.5
      road_sigma_m: 0.4
    search:
      starts: 64
      box_lateral: 3.0

Precedence: an option given on the command line > the file > the defaults. Unknown sections or keys and
wrongly typed values are refused with one line naming them. The merged configuration is recorded in the
outputs' provenance (``Config.as_dict``).
"""

from __future__ import annotations

import dataclasses
import math
import os
from dataclasses import dataclass, field
from typing import Any

from deepcrashtest.errors import UserError
from deepcrashtest.fileio import require_file
from deepcrashtest.search.run import SearchConfig
from deepcrashtest.trajectory.params import Stage2Params


@dataclass(frozen=True)
class Config:
    """Every configurable section, each a stage's own typed defaults."""

    stage2: Stage2Params = field(default_factory=Stage2Params)
    search: SearchConfig = field(default_factory=SearchConfig)
    source: str | None = None
    """Path of the file the values came from (None: the defaults)."""

    def as_dict(self) -> dict[str, Any]:
        """Plain dict of every section (for provenance and ``--json``)."""
        return {"stage2": dataclasses.asdict(self.stage2), "search": dataclasses.asdict(self.search)}

    def with_search(self, **given: Any) -> SearchConfig:
        """The search section with the options given on the command line (not None) on top."""
        return _replace(self.search, "search", {k: v for k, v in given.items() if v is not None})


SECTIONS = ("stage2", "search")


def load_config(path: str | os.PathLike[str] | None) -> Config:
    """The defaults, with the YAML file at ``path`` (if any) merged over them."""
    if path is None:
        return Config()
    import yaml  # only with a file (~15 ms of start-up otherwise)

    p = require_file(path, "config file")
    try:
        data = yaml.safe_load(p.read_text(encoding="utf-8"))
    except UnicodeDecodeError:
        raise UserError(f"{p}: not a text file") from None
    except yaml.YAMLError as exc:
        mark = getattr(exc, "problem_mark", None)
        where = f" at line {mark.line + 1} column {mark.column + 1}" if mark is not None else ""
        raise UserError(f"{p}: invalid YAML{where}") from None
    return merge_config(Config(), data if data is not None else {}, origin=str(p))


def merge_config(base: Config, data: Any, origin: str = "config") -> Config:
    """``base`` with the sections of ``data`` (a mapping of section -> mapping of field -> value) on top."""
    if not isinstance(data, dict):
        raise UserError(f"{origin}: expected a mapping of sections ({', '.join(SECTIONS)}), got {type(data).__name__}")
    unknown = sorted(str(k) for k in data if k not in SECTIONS)
    if unknown:
        raise UserError(f"{origin}: unknown section(s) {unknown}; known: {', '.join(SECTIONS)}")
    values = {}
    for name in SECTIONS:
        section = data.get(name) or {}
        if not isinstance(section, dict):
            raise UserError(f"{origin}: section {name!r} must be a mapping of field: value")
        values[name] = _replace(getattr(base, name), f"{origin}: {name}", section)
    return Config(stage2=values["stage2"], search=values["search"], source=origin)


def _replace(obj: Any, where: str, changes: dict[str, Any]) -> Any:
    """``dataclasses.replace`` with every key and value type checked against the field's default."""
    known = {f.name: f for f in dataclasses.fields(obj)}
    unknown = sorted(str(k) for k in changes if k not in known)
    if unknown:
        raise UserError(f"{where}: unknown field(s) {unknown}; known: {', '.join(sorted(known))}")
    for key, value in changes.items():
        _check_type(f"{where}.{key}", getattr(obj, key), value)
    try:
        return dataclasses.replace(obj, **changes)
    except (TypeError, ValueError) as exc:
        raise UserError(f"{where}: {exc}") from None


def _check_type(name: str, default: Any, value: Any) -> None:
    """Refuse a value whose type does not fit the field (judged by its default; None means optional)."""
    if value is None:
        if default is not None:
            raise UserError(f"{name}: must not be empty")
        return
    if isinstance(default, bool) or isinstance(value, bool):
        ok = isinstance(default, bool) and isinstance(value, bool)
    elif isinstance(default, int):
        ok = isinstance(value, int)
    elif isinstance(default, float) or default is None:
        ok = isinstance(value, int | float) and math.isfinite(float(value))
    elif isinstance(default, str):
        ok = isinstance(value, str)
    else:
        ok = True
    if not ok:
        kind = "a number" if default is None else type(default).__name__
        raise UserError(f"{name}: expected {kind}, got {value!r}")
