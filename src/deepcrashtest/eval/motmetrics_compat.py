"""The one place that imports ``motmetrics``: version 1.4 still calls ``np.asfarray``, gone in NumPy 2."""

from __future__ import annotations

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
