"""The one place that imports the metric libraries, with what they need to run here.

* ``motmetrics`` 1.4 still calls ``np.asfarray``, removed in NumPy 2: a shim is installed first.
* ``trackeval`` prints a line on stdout when an optional dataset's dependency (pycocotools) is
  missing; that line would corrupt ``--json`` output, so the import runs with stdout captured.
"""

from __future__ import annotations

import contextlib
import io
from types import ModuleType

import numpy as np


def _asfarray(a, dtype=float):  # type: ignore[no-untyped-def]
    return np.asarray(a, dtype=dtype)


def motmetrics() -> ModuleType:
    """``import motmetrics`` with the NumPy-2 shim (``np.asfarray``) installed first."""
    if not hasattr(np, "asfarray"):
        setattr(np, "asfarray", _asfarray)  # noqa: B010
    import motmetrics as mm

    return mm


def trackeval_metrics() -> ModuleType:
    """``trackeval.metrics`` (CLEAR, HOTA, Identity ...), imported without printing on stdout."""
    with contextlib.redirect_stdout(io.StringIO()):
        import trackeval.metrics

    return trackeval.metrics
