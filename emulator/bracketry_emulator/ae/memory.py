"""Process memory policy of a closed-loop run: large temporary arrays reuse freed memory instead of fresh pages.

Every step allocates and frees many full-frame arrays (4-37 MB: gray images, gradients, the long-double terms of
Zhang). glibc serves each from a fresh ``mmap`` and unmaps it when freed, so every step faults its pages in again
(about a million page faults and a fifth of the CPU time of a 15-sequence 1920x1200 run, all in the kernel).
:func:`reuse_freed_memory` asks glibc to serve them from its heap and to keep freed memory for the next step. Called
by ``bracketry emulate`` (a batch process; forked workers inherit it), not by the library on its own.
"""

from __future__ import annotations

import ctypes
import ctypes.util

# glibc's mallopt parameters (malloc.h)
_M_TRIM_THRESHOLD = -1
_M_TOP_PAD = -2
_M_MMAP_MAX = -4


def reuse_freed_memory() -> bool:
    """Large allocations from the heap (no per-allocation ``mmap``), freed memory kept for reuse (no trimming).
    Returns False where the C library has no ``mallopt`` (not glibc): nothing changes then."""
    name = ctypes.util.find_library("c")
    try:
        libc = ctypes.CDLL(name) if name else ctypes.CDLL(None)
        mallopt = libc.mallopt
    except (OSError, AttributeError):
        return False
    mallopt.argtypes = [ctypes.c_int, ctypes.c_int]
    mallopt.restype = ctypes.c_int
    return bool(mallopt(_M_MMAP_MAX, 0) and mallopt(_M_TRIM_THRESHOLD, 2**31 - 1)
                and mallopt(_M_TOP_PAD, 64 << 20))
