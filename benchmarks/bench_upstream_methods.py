"""The authors' Shim, Kim and Zhang (``--parity upstream``) per step: our fast paths vs the formulas as written, side
by side in one run, on the same emulated 1920x1200 frames.

Usage: .venv/bin/python benchmarks/bench_upstream_methods.py [--dataset DIR] [--frames N] [--repeats N]

Each part is timed in CPU time of the calling thread (``time.thread_time``; the compiled kernels run on it), median
over the frames and repeats, both paths on the same inputs, interleaved; the load average is printed with them (the
machine is shared). The reference paths are the formulas as the authors write them, with the speed-ups our code had
before the fast paths (per-code tables of Kim's metric; scipy's ``cho_factor``/``cho_solve`` objective driven by
``scipy.optimize.minimize``; Zhang's sorted terms with numpy's sort and sum). Both paths give the same values (checked
here as in tests/bracketry_emulator/ae/test_ae_upstream_fast_paths.py, the GP and Shim formulas shared with it:
tests/bracketry_emulator/ae/upstream_formulas.py).

- Shim: the 7 gamma scores of one step (``upstream_shim_scores`` vs ``upstream_shim_metric(img01 ** g)`` per gamma);
- Kim metric (``upstream_kim_metric`` vs ``upstream_kim_metric_exact``) and Kim's GP fits (11 L-BFGS-B starts on
  windows of up to 5 points; ``GaussianProcess1D.fit`` vs the minimize formulation) on the windows of Kim's own
  closed loop over the sequences (the emulate workload);
- Zhang: the weighted sum of the sorted terms (compiled ``weighted_sum`` vs numpy's sort and sum of ``_terms``).
"""

from __future__ import annotations

import argparse
import copy
import os
import statistics
import sys
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")  # as bracketry emulate (before numpy loads OpenBLAS)

import numpy as np

from bracketry_base import paths
from bracketry_emulator.ae import gp as GP
from bracketry_emulator.ae import upstream as U
from bracketry_emulator.ae.base import bayer_gray
from bracketry_emulator.dataset import open_dataset
from bracketry_emulator.emulation import Emulator
from bracketry_emulator.emulation.settings import emulator_config

# the formulas as written, shared with the tests (tests/bracketry_emulator/ae/upstream_formulas.py)
sys.path.insert(0, str(paths.repo_root() / "tests" / "bracketry_emulator" / "ae"))
from upstream_formulas import fit_formula, shim_scores_formula


def cpu_ms(fn: Callable[..., Any], *args: Any) -> tuple[float, Any]:
    t0 = time.thread_time()
    out = fn(*args)
    return (time.thread_time() - t0) * 1e3, out


def zhang_reference(zhang: U.UpstreamZhangAE, gray: np.ndarray, meta: dict[str, Any]) -> np.longdouble:
    w = U.upstream_zhang_weights(gray.size)
    return np.sum(w * U.sort_longdouble(zhang._terms(gray, 6.0, meta)))


def rng_at(state: dict[str, Any]) -> np.random.Generator:
    rng = np.random.default_rng(0)
    rng.bit_generator.state = copy.deepcopy(state)
    return rng


def kim_windows(emu: Emulator, seqs: list[Any]) -> list[tuple[np.ndarray, np.ndarray, dict[str, Any]]]:
    """(exposures ms, metrics, generator state) of every GP fit of the authors' Kim in closed loop from 4 ms over
    the sequences (left camera)."""
    found: list[tuple[np.ndarray, np.ndarray, dict[str, Any]]] = []
    fit = GP.GaussianProcess1D.fit

    def recording(self: GP.GaussianProcess1D, x: np.ndarray, y: np.ndarray) -> GP.GaussianProcess1D:
        found.append((np.array(x, dtype=np.float64), np.array(y, dtype=np.float64),
                      copy.deepcopy(dict(self.rng.bit_generator.state))))
        return fit(self, x, y)

    kim = U.UpstreamKimAE()
    t_us = 4000.0
    GP.GaussianProcess1D.fit = recording  # type: ignore[method-assign]
    try:
        for seq in seqs:
            t_us = kim.next_exposure_us(emu.emulate(seq.load("left"), t_us).image, t_us, {"response": emu.response})
    finally:
        GP.GaussianProcess1D.fit = fit  # type: ignore[method-assign]
    return found


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--dataset", type=Path, default=None, help="a BorealHDR recording folder (default: the sample's)")
    ap.add_argument("--frames", type=int, default=6, help="emulated frames (sequences x 3 exposures)")
    ap.add_argument("--repeats", type=int, default=2)
    args = ap.parse_args()
    if args.dataset is None:
        args.dataset = paths.sample_sequence_dir()
        if args.dataset is None:
            raise SystemExit("the BorealHDR sample was not found (see tests/conftest.py): pass --dataset")
    dataset = open_dataset(args.dataset)
    pcalib = dataset.pcalib_path()
    if pcalib is None:
        raise SystemExit(f"no pcalib under {args.dataset}")
    emu = Emulator(emulator_config("upstream", str(pcalib), "upstream"))
    seqs = dataset.sequences()
    grays = []
    for i in range(args.frames):
        seq = seqs[(i // 3) * max(1, len(seqs) // max(1, args.frames // 3)) % len(seqs)]
        grays.append(bayer_gray(emu.emulate(seq.load("left"), (2000.0, 6000.0, 16000.0)[i % 3]).image))
    meta = {"response": emu.response}
    windows = kim_windows(emu, seqs)
    zhang = U.UpstreamZhangAE()
    GP._minimizer()  # scipy's import and the one-off check of the direct L-BFGS-B drive, outside the timings
    times: dict[str, tuple[list[float], list[float]]] = {k: ([], []) for k in
                                                          ("shim step", "kim metric", "kim GP fit", "zhang sum")}
    load = [os.getloadavg()[0]]
    for _ in range(args.repeats):
        for x, y, state in windows:
            tf, fit = cpu_ms(GP.GaussianProcess1D(0.2, 10, rng_at(state)).fit, x, y)
            tr, theta = cpu_ms(fit_formula, x, y, 0.2, rng_at(state))
            assert np.array_equal(fit.log_theta, theta)
            times["kim GP fit"][0].append(tf)
            times["kim GP fit"][1].append(tr)
        for gray in grays:
            (tf, fast), (tr, ref) = cpu_ms(U.upstream_shim_scores, gray), cpu_ms(shim_scores_formula, gray)
            assert [v.tobytes() for v in fast] == [v.tobytes() for v in ref]
            times["shim step"][0].append(tf)
            times["shim step"][1].append(tr)
            (tf, fast), (tr, ref) = cpu_ms(U.upstream_kim_metric, gray), cpu_ms(U.upstream_kim_metric_exact, gray)
            assert abs(fast - ref) <= 1e-12 * abs(ref)
            times["kim metric"][0].append(tf)
            times["kim metric"][1].append(tr)
            tf, fast = cpu_ms(zhang.weighted_sum, gray, 6.0, meta)
            tr, ref = cpu_ms(zhang_reference, zhang, gray, meta)
            assert fast == ref
            times["zhang sum"][0].append(tf)
            times["zhang sum"][1].append(tr)
        load.append(os.getloadavg()[0])
    h, wd = grays[0].shape
    print(f"the authors' methods per step, {wd}x{h}, {len(grays)} frames (GP: {len(windows)} fits of Kim's loop) x "
          f"{args.repeats} repeats, thread CPU ms (median), load average {min(load):.1f}-{max(load):.1f}; same values "
          "on both paths (checked)")
    print(f"{'part':<12} {'fast':>9} {'formula':>9} {'ratio':>7}")
    for name, (fast_ms, ref_ms) in times.items():
        f, r = statistics.median(fast_ms), statistics.median(ref_ms)
        print(f"{name:<12} {f:9.1f} {r:9.1f} {r / f:6.1f}x")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
