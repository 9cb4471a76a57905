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


def test_the_allocator_is_set_up_without_a_subprocess(monkeypatch):
    """Every search worker sets glibc's thresholds: finding the C library must not run ``ldconfig -p`` (what
    ``ctypes.util.find_library`` does, ~10 ms a worker) where glibc's soname loads directly."""
    import subprocess
    import sys

    from deepcrashtest.sim import memory

    if not sys.platform.startswith("linux"):
        pytest.skip("glibc's allocator settings apply on Linux only")
    try:
        memory.ctypes.CDLL("libc.so.6")
    except OSError:
        pytest.skip("no glibc here (the find_library fallback is the only way)")

    def no_subprocess(self, args, *rest, **kwargs):  # an AssertionError: retain_freed_memory lets it through
        raise AssertionError(f"subprocess started: {args}")

    monkeypatch.setattr(subprocess.Popen, "__init__", no_subprocess)
    monkeypatch.setattr(memory, "_done", False)
    memory.retain_freed_memory()
    assert memory._done
