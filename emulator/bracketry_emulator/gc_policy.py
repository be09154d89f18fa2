"""Garbage-collector policy of a closed-loop run: fewer collections while the processes import and step.

A run creates few reference cycles but many container objects while its processes import their libraries
(matplotlib for the plot in the parent; scipy in the workers that run Kim's GP or Zhang's spline): with Python's
default threshold (a young-generation collection every 700 net allocations, a full one every 100 of those) the
collector traversed the growing heaps again and again, ~0.2 CPU-s of a 15-sequence 1920x1200 run here.
:func:`fewer_collections` raises the young generation's threshold; cyclic garbage is still collected, later. Called
by ``bracketry emulate`` (a batch process; forked workers inherit it), not by the library on its own.
"""

from __future__ import annotations

import gc

#: net container allocations between young-generation collections in a run (Python's default: 700)
RUN_GEN0_THRESHOLD = 20_000


def fewer_collections(gen0: int = RUN_GEN0_THRESHOLD) -> None:
    """Collect the young generation every ``gen0`` net allocations (never more often than now); the older
    generations' thresholds (collections of the younger one between theirs) stay as they are."""
    t0, t1, t2 = gc.get_threshold()
    if t0 != 0:  # 0: collection disabled by the caller; left so
        gc.set_threshold(max(t0, gen0), t1, t2)
