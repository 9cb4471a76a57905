"""Keep freed heap memory for reuse during batch simulation (glibc only; elsewhere nothing happens).

A batch allocates and frees many arrays of tens of megabytes per chunk. glibc hands each one back to
the kernel (``munmap``) and maps fresh, zeroed pages for the next, which costs page faults: about a
fifth of a search's CPU time on KITTI 0003 was system time. Raising the mmap and trim thresholds
keeps the pages in the process and reuses them (memory is still bounded by the batch's peak).
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
    """Once per process: large allocations from the heap, freed memory kept up to 1 GiB (glibc's mallopt)."""
    global _done
    if _done or not sys.platform.startswith("linux"):
        return
    _done = True
    try:
        libc = ctypes.CDLL(ctypes.util.find_library("c") or "libc.so.6")
        mallopt = libc.mallopt
    except (OSError, AttributeError):  # not glibc (musl, ...): leave the allocator as it is
        return
    mallopt.argtypes, mallopt.restype = [ctypes.c_int, ctypes.c_int], ctypes.c_int
    mallopt(_M_MMAP_THRESHOLD, 512 << 20)
    mallopt(_M_TRIM_THRESHOLD, 1 << 30)
    mallopt(_M_TOP_PAD, 64 << 20)
