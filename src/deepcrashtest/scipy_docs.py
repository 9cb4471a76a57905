"""SciPy's import-time docstring rewriting, skipped in the console command.

SciPy (1.15+) parses and rewrites the docstrings of ~800 functions while its modules load: every function
decorated for its array-API table (``scipy._lib._array_api.xp_capabilities``), its axis/nan-policy
wrappers (``scipy.stats``), its batching and deprecation wrappers each run a numpydoc parser
(``scipy._lib._docscrape.FunctionDoc``) over the docstring, add a note and print it back. What ``extract``
imports (``scipy.optimize``, ``signal``, ``stats`` through filterpy, ``interpolate``, ``ndimage``) spent
~0.4 s of CPU on it (measured with NumPy: 1.65-1.92 s -> 1.18-1.44 s, one fresh process each, load ~7), i.e.
~1.6 ms a frame of a 10 s 25 fps clip. Only docstrings depend on it: the decorated functions, their signatures
and results are the same, ``help()`` shows them without SciPy's added notes.

:func:`plain_scipy_docs` (called by ``extract`` before anything imports SciPy's submodules) gives those
decorators a stand-in with empty sections that prints the function's own docstring back. It does nothing
when SciPy is absent or its parser is not where this SciPy version keeps it.
"""

from __future__ import annotations

import sys
from typing import Any

#: SciPy modules that bind the parser by name when they load (``from scipy._lib._docscrape import FunctionDoc``).
_USERS = (
    "scipy._lib._docscrape",
    "scipy._lib._array_api",
    "scipy._lib._util",
    "scipy._lib.deprecation",
    "scipy.stats._axis_nan_policy",
)


class PlainDoc(dict[str, list[Any]]):
    """Stands in for ``FunctionDoc(func)``: every section an empty list (what the decorators append to or
    look parameters up in), ``str()`` a signature line (which they cut off) and the function's own docstring."""

    def __init__(self, func: Any, role: str = "func", doc: str | None = None, config: Any = None) -> None:
        super().__init__()
        self.text = (doc if doc is not None else getattr(func, "__doc__", None)) or ""

    def __missing__(self, key: str) -> list[Any]:
        value: list[Any] = []
        self[key] = value
        return value

    def __str__(self) -> str:
        return "\n" + self.text


def plain_scipy_docs() -> bool:
    """Swap SciPy's import-time docstring parser for :class:`PlainDoc` in the modules that use it; True when
    done. SciPy modules loaded before keep their rewritten docstrings."""
    try:
        from scipy._lib import _docscrape
    except ImportError:
        return False
    real = getattr(_docscrape, "FunctionDoc", None)
    if not isinstance(real, type):
        return False
    for name in _USERS:
        module = sys.modules.get(name)
        if module is not None and getattr(module, "FunctionDoc", None) is real:
            module.FunctionDoc = PlainDoc  # type: ignore[attr-defined]
    return True
