"""Process-wide tuning of the emulator's entry points, one named profile each: glibc heap, BLAS threads, OpenCV
threads, garbage collector.

A library never tunes the process it is imported into: each entry point calls :func:`apply_profile` once, as early
as it can (BLAS threads only take effect before numpy is imported). Applying a profile again is a no-op; a setting
the caller made explicitly is kept (``OPENBLAS_NUM_THREADS`` in the environment, glibc malloc tunables in
``GLIBC_TUNABLES``, a collector the caller disabled or already collects less often).

Why each setting:

- heap ``reuse`` (``emulate``): every closed-loop step allocates and frees many full-frame arrays (4-37 MB). glibc
  serves each from a fresh ``mmap`` and unmaps it when freed, so every step faults its pages in again (about a
  million page faults, a fifth of the CPU time of a 15-sequence 1920x1200 run, all in the kernel). Large allocations
  come from the heap and freed memory is kept for the next step. A batch process: its workers are forked from it
  and inherit it. CPython's own arena allocator is left as it is: keeping the frame data-stack chunks it unmaps
  (CPython gh-142183, fixed in 3.14.4 and backported to 3.13) saved no time in ``bracketry emulate`` (paired runs
  of 7 methods on a synthetic trajectory, CPU-time ratio 1.01).
- heap ``bounded`` (benchmark tasks, local or Dask): Dask's nanny sets ``MALLOC_TRIM_THRESHOLD_=65536`` for its
  workers, which also freezes glibc's mmap threshold at 128 KiB: every image-sized temporary is then an mmap, page
  faults and munmap (2x the CPU time of a VO task). Long-lived workers, so free heap above 256 MiB still goes back.
- BLAS 1 thread (``emulate``, ``benchmark``, ``demo``): their work is already spread over processes and the AE
  methods' matrices are tiny (Kim's GP fits): OpenBLAS's pool only spins and takes CPU from the other processes (the
  default demo's closed loops: 11.4 CPU-s with one thread, 20.7 with the pool; the same exposures and images). Set
  in the environment, so the processes they start inherit it.
- OpenCV 1 thread (benchmark tasks, SLAM child processes, timing scripts): one core per task, the tasks run side by
  side. The closed loop's forked workers get theirs from the scheduler, set just before forking (a forked child
  must not change OpenCV's thread count: that waits forever on the pool its parent had running).
- GC young generation every 20 000 net allocations (``emulate``; Python's default 700): the run creates few cycles
  but many containers while it imports matplotlib and scipy; the collector traversed the growing heaps again and
  again (~0.2 CPU-s of a 15-sequence 1920x1200 run). Cyclic garbage is still collected, later.
"""

from __future__ import annotations

import gc
import os
import sys
from collections.abc import Callable
from dataclasses import dataclass
from typing import Literal

# glibc's mallopt parameters (malloc.h)
M_TRIM_THRESHOLD = -1
M_TOP_PAD = -2
M_MMAP_THRESHOLD = -3
M_MMAP_MAX = -4

#: mallopt settings of each heap policy
HEAP_POLICIES: dict[str, tuple[tuple[int, int], ...]] = {
    # no allocation is an mmap of its own; freed memory is never given back; the heap grows 64 MiB at a time
    "reuse": ((M_MMAP_MAX, 0), (M_TRIM_THRESHOLD, 2**31 - 1), (M_TOP_PAD, 64 << 20)),
    # allocations up to 64 MiB from the heap; free heap above 256 MiB given back
    "bounded": ((M_MMAP_THRESHOLD, 64 << 20), (M_TRIM_THRESHOLD, 256 << 20)),
}

#: net container allocations between young-generation collections in a batch run (Python's default: 700)
BATCH_GC_GEN0 = 20_000


@dataclass(frozen=True)
class Profile:
    """What one entry point sets; None leaves that part of the process as it is."""

    heap: Literal["reuse", "bounded"] | None = None
    blas_threads: int | None = None
    opencv_threads: int | None = None
    gc_gen0: int | None = None


PROFILES: dict[str, Profile] = {
    # bracketry emulate: a batch process whose closed-loop workers are forked from it
    "emulate": Profile(heap="reuse", blas_threads=1, gc_gen0=BATCH_GC_GEN0),
    # bracketry benchmark / demo: closed loops in worker processes beside the SLAM child processes
    "benchmark": Profile(blas_threads=1),
    "demo": Profile(blas_threads=1),
    # one benchmark task (local worker or Dask worker): closed loop + SLAM + metrics of one (trajectory, method)
    "task": Profile(heap="bounded", opencv_threads=1),
    # one SLAM run's child process (python -m bracketry_emulator.slam.orbslam3_child)
    "slam_child": Profile(opencv_threads=1),
    # a benchmark script that times one core (benchmarks/)
    "timing": Profile(opencv_threads=1),
}

_applied: set[str] = set()


def apply_profile(name: str) -> Profile:
    """Apply the named profile to this process (once: again is a no-op) and return it. Unknown names raise
    KeyError."""
    profile = PROFILES[name]
    if name in _applied:
        return profile
    if profile.blas_threads is not None:
        set_blas_threads(profile.blas_threads)
    if profile.gc_gen0 is not None:
        collect_less_often(profile.gc_gen0)
    if profile.opencv_threads is not None:
        set_opencv_threads(profile.opencv_threads)
    if profile.heap is not None:
        set_heap_policy(profile.heap)
    _applied.add(name)
    return profile


def applied_profiles() -> frozenset[str]:
    return frozenset(_applied)


def set_blas_threads(n: int) -> None:
    """``OPENBLAS_NUM_THREADS=n`` for this process and the ones it starts, unless the caller's environment sets it.
    Takes effect in this process only when numpy is not imported yet."""
    os.environ.setdefault("OPENBLAS_NUM_THREADS", str(n))


def set_opencv_threads(n: int) -> int:
    """OpenCV's thread count (where OpenCV is installed); returns the previous one (0 without OpenCV)."""
    try:
        import cv2
    except ImportError:
        return 0
    previous = int(cv2.getNumThreads())
    cv2.setNumThreads(n)
    return previous


def collect_less_often(gen0: int) -> None:
    """A young-generation collection every ``gen0`` net allocations, never more often than now (a collector the
    caller disabled stays disabled); the older generations' thresholds stay as they are."""
    t0, t1, t2 = gc.get_threshold()
    if t0 != 0:
        gc.set_threshold(max(t0, gen0), t1, t2)


def set_heap_policy(policy: str) -> bool:
    """Apply one of :data:`HEAP_POLICIES` with glibc's ``mallopt``. False where the C library has no ``mallopt``
    (not glibc) or the caller set glibc's malloc tunables (``GLIBC_TUNABLES=glibc.malloc...``): the heap is left as
    it is then."""
    settings = HEAP_POLICIES[policy]
    if "glibc.malloc." in os.environ.get("GLIBC_TUNABLES", ""):
        return False
    mallopt = _mallopt()
    if mallopt is None:
        return False
    return all([bool(mallopt(param, value)) for param, value in settings])


def _mallopt() -> Callable[[int, int], int] | None:
    if not sys.platform.startswith("linux"):
        return None
    import ctypes
    import ctypes.util

    name = ctypes.util.find_library("c")
    try:
        libc = ctypes.CDLL(name) if name else ctypes.CDLL(None)
        mallopt = libc.mallopt
    except (OSError, AttributeError):
        return None
    mallopt.argtypes = [ctypes.c_int, ctypes.c_int]
    mallopt.restype = ctypes.c_int
    return mallopt

