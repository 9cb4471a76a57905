"""Keep freed heap memory for reuse during batch simulation (glibc only; elsewhere nothing happens).

A batch allocates and frees many arrays of tens of megabytes per chunk. glibc hands each one back to
the kernel (``munmap``) and maps fresh, zeroed pages for the next, which costs page faults: about a
fifth of a search's CPU time on KITTI 0003 was system time. Raising the mmap and trim thresholds
keeps the pages in the process and reuses them (memory is still bounded by the batch's peak).

NumPy also asks the kernel for transparent huge pages (``madvise``) on every array of 4 MB or more; the
kernel then zeroes 2 MB pages on first touch. For the search's short-lived arrays that cost more than it
saved: with it off, building 2,000 KITTI 0003 variant paths took 0.67-0.81 s of CPU instead of 1.33-1.39 s
and the whole batch 3.7-4.5 s instead of 4.7-5.1 s (system time 1.3 -> 0.6 s; loaded 2-core machine, 2026-12-01).
"""

from __future__ import annotations

import ctypes
import ctypes.util
import sys

_M_TRIM_THRESHOLD = -1
_M_TOP_PAD = -2
_M_MMAP_THRESHOLD = -3
_done = False


def retain_freed_memory() -> None:
    """Once per process: large allocations from the heap, freed memory kept up to 1 GiB (glibc's mallopt), and no
    huge pages for NumPy's arrays."""
    global _done
    if _done or not sys.platform.startswith("linux"):
        return
    _done = True
    _no_huge_pages()
    try:
        mallopt = _libc().mallopt
    except (OSError, AttributeError):  # not glibc (musl, ...): leave the allocator as it is
        return
    mallopt.argtypes, mallopt.restype = [ctypes.c_int, ctypes.c_int], ctypes.c_int
    mallopt(_M_MMAP_THRESHOLD, 512 << 20)
    mallopt(_M_TRIM_THRESHOLD, 1 << 30)
    mallopt(_M_TOP_PAD, 64 << 20)


def _libc() -> ctypes.CDLL:
    """The C library: glibc by its soname, else whatever ``find_library`` names. ``find_library`` runs
    ``ldconfig -p`` in a subprocess (~10 ms of wall and CPU in every search worker), so it is only the fallback."""
    try:
        return ctypes.CDLL("libc.so.6")
    except OSError:
        return ctypes.CDLL(ctypes.util.find_library("c") or "libc.so")


def _no_huge_pages() -> None:
    """Stop NumPy asking for transparent huge pages on large arrays (``NUMPY_MADVISE_HUGEPAGE=0``, in-process)."""
    import importlib

    for module in ("numpy._core.multiarray", "numpy.core.multiarray"):  # NumPy 2, NumPy 1
        try:
            setter = getattr(importlib.import_module(module), "_set_madvise_hugepage", None)
        except ImportError:
            continue
        if setter is not None:
            setter(False)
            return
