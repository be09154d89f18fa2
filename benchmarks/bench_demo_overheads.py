"""Benchmark: two per-call costs of ``make demo`` that its results do not depend on, the way they were paid side by
side with the way they are paid.

* The lockstep wait's sample of ORB-SLAM3's threads (:mod:`bracketry_emulator.slam.quiescence`): a demo run samples
  1,000-5,000 times (``lockstep_polls`` in its ``slam.json``). Each sample of three idle threads (ORB-SLAM3's
  count) as :func:`~bracketry_emulator.slam.quiescence.sample_threads` reads them (open, read, close two /proc files
  a thread) against a :class:`~bracketry_emulator.slam.quiescence.ThreadSampler` (the files kept open, re-read with
  ``pread``); both read the same states (checked).
* The report's Wilcoxon signed-rank p-value where scipy's ``auto`` runs its exact sign-flip permutation test (ties
  or zeros, up to 13 pairs; the demo's 11 trajectories with worst-rank imputation and equal failure times): scipy's
  ``wilcoxon`` against :func:`~bracketry_emulator.stats.paired.wilcoxon_p` (the same permutation test with its
  statistic vectorised); the same p-value (checked).

CPU seconds of this thread per call, medians of ``--reps`` rounds (the two ways alternate in each round), and the
ratios side by side.

    .venv/bin/python benchmarks/bench_demo_overheads.py [--reps 5]
"""

from __future__ import annotations

import argparse
import os
import statistics
import threading
import time
import warnings
from collections.abc import Callable

import numpy as np


def cpu_per_call(fn: Callable[[], object], calls: int) -> float:
    """CPU seconds of this thread per call of ``fn`` over ``calls`` calls."""
    c0 = time.thread_time()
    for _ in range(calls):
        fn()
    return (time.thread_time() - c0) / calls


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--reps", type=int, default=5, help="rounds (each times both ways)")
    ap.add_argument("--samples", type=int, default=2000, help="thread samples per way and round")
    args = ap.parse_args()

    from scipy.stats import wilcoxon

    from bracketry_emulator.slam.quiescence import ThreadSampler, sample_threads, thread_ids
    from bracketry_emulator.stats.paired import wilcoxon_p

    own = thread_ids()
    stop = threading.Event()
    workers = [threading.Thread(target=stop.wait) for _ in range(3)]  # idle, as ORB-SLAM3's threads between frames
    for w in workers:
        w.start()
    d = np.array([0.0, 9.8, 9.8, -1.2, 3.4, -0.7, 41.0, 2.2, -2.2, 0.5, 1.1])  # 11 pairs, a tie and a zero
    rows: dict[str, list[float]] = {k: [] for k in ("open", "pread", "scipy", "vectorised")}
    loads = [os.getloadavg()[0]]
    try:
        with ThreadSampler(own) as sampler:
            tids = thread_ids() - own
            assert {t: s.state for t, s in sampler().items()} == {t: s.state for t, s in sample_threads(tids).items()}
            with warnings.catch_warnings():
                warnings.simplefilter("ignore")
                p_scipy = float(wilcoxon(d, method="auto").pvalue)
            assert wilcoxon_p(d) == p_scipy, (wilcoxon_p(d), p_scipy)
            for rep in range(args.reps):
                order = ("open", "pread") if rep % 2 == 0 else ("pread", "open")
                for way in order:
                    fn = (lambda: sample_threads(thread_ids() - own)) if way == "open" else sampler
                    rows[way].append(cpu_per_call(fn, args.samples))
                for way in ("scipy", "vectorised") if rep % 2 == 0 else ("vectorised", "scipy"):
                    with warnings.catch_warnings():
                        warnings.simplefilter("ignore")
                        if way == "scipy":
                            rows[way].append(cpu_per_call(lambda: wilcoxon(d, method="auto"), 1))
                        else:
                            rows[way].append(cpu_per_call(lambda: wilcoxon_p(d), 20))
                loads.append(os.getloadavg()[0])
    finally:
        stop.set()
        for w in workers:
            w.join()

    med = {k: statistics.median(v) for k, v in rows.items()}
    print(f"{args.reps} rounds, CPU of this thread per call (median; each round's value after the comma list)")
    print(f"{'what':52s} {'before':>10s} {'after':>10s} {'before/after':>13s}")
    print(f"{'sample of 3 idle threads (ms)':52s} {med['open'] * 1e3:10.4f} {med['pread'] * 1e3:10.4f} "
          f"{med['open'] / med['pread']:13.2f}")
    print(f"{'signed-rank p, 11 pairs with ties, permutation (ms)':52s} {med['scipy'] * 1e3:10.1f} "
          f"{med['vectorised'] * 1e3:10.1f} {med['scipy'] / med['vectorised']:13.1f}")
    for k, v in rows.items():
        print(f"  {k}: {', '.join(f'{x * 1e3:.4f}' for x in v)} ms")
    print(f"the same p-value both ways: {p_scipy}; 1-min load {min(loads):.1f}..{max(loads):.1f} on "
          f"{os.cpu_count()} CPUs")


if __name__ == "__main__":
    main()
