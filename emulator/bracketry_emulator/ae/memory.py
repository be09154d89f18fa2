"""Process memory policy of a closed-loop run: freed memory is reused instead of being unmapped and faulted in again.

Every step allocates and frees many full-frame arrays (4-37 MB: gray images, gradients, the long-double terms of
Zhang). glibc serves each from a fresh ``mmap`` and unmaps it when freed, so every step faults its pages in again
(about a million page faults and a fifth of the CPU time of a 15-sequence 1920x1200 run, all in the kernel).
:func:`reuse_freed_memory` asks glibc to serve them from its heap and to keep freed memory for the next step, and
puts a cache in front of CPython's own arena allocator (the compiled ``_arena_cache``, where it was built): CPython
unmaps every object-allocator arena and frame data-stack chunk it frees, and a thread whose call depth keeps crossing
a chunk boundary (an import made deep in a call stack) mapped, faulted in and unmapped a fresh 16 KiB chunk thousands
of times per worker. Called by ``bracketry emulate`` (a batch process; forked workers inherit it), not by the library
on its own.
"""

from __future__ import annotations

import ctypes
import ctypes.util

from ..extensions import optional_extension

# glibc's mallopt parameters (malloc.h)
_M_TRIM_THRESHOLD = -1
_M_TOP_PAD = -2
_M_MMAP_MAX = -4


def reuse_freed_memory() -> bool:
    """Large allocations from the heap (no per-allocation ``mmap``), freed memory kept for reuse (no trimming), and
    CPython's freed arenas and data-stack chunks kept for reuse (a few MiB at most). Returns False where the C library
    has no ``mallopt`` (not glibc): the heap policy does not change then."""
    cache = optional_extension("bracketry_emulator.ae._arena_cache")
    if cache is not None:
        cache.install()
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
