"""BLAS threads of a command that spreads its work over processes.

numpy's OpenBLAS starts a pool of threads (one per CPU) when numpy is imported. The commands that already run their
work in parallel processes (``bracketry emulate``, ``benchmark``, ``demo``) gain nothing from it: the AE methods'
matrices are tiny (Kim's GP fits), so the pool's threads only waited on each other and spun, taking CPU from the
other processes (a GP fit spent 2/3 of its time there; the default demo's closed loops 20.7 -> 11.4 CPU-s with one
thread, the same exposures and images). Imports nothing heavy: it must run before numpy is loaded.
"""

from __future__ import annotations

import os


def one_blas_thread() -> None:
    """One OpenBLAS thread in this process and in the processes it starts (``OPENBLAS_NUM_THREADS=1`` unless the
    caller's environment sets it). Takes effect only when called before numpy is imported."""
    os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")
