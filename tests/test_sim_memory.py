"""``sim.memory``: a batch simulation turns NumPy's huge-page requests off (their zeroing cost the search CPU)."""

from __future__ import annotations

import importlib

import numpy as np
import pytest

from deepcrashtest.sim.memory import retain_freed_memory


def _setter():
    for module in ("numpy._core.multiarray", "numpy.core.multiarray"):
        setter = getattr(importlib.import_module(module), "_set_madvise_hugepage", None)
        if setter is not None:
            return setter
    pytest.skip(f"NumPy {np.__version__} has no _set_madvise_hugepage")


def test_numpy_asks_for_no_huge_pages_after_the_first_batch():
    retain_freed_memory()
    previous = _setter()(False)  # returns the setting it replaces
    assert previous is False
