"""Emulation kernel speed: our 4096-entry LUT vs the authors' per-pixel interp1d formula, same frame, same run.

Usage: .venv/bin/python benchmarks/bench_emulation.py [--quick]
Frame: a real 1920x1200 8 ms bracket of the BorealHDR sample when present, else a synthetic frame of the same
size. Both kernels emulate 6 ms from 8 ms (f = 0.75) with the upstream pcalib lifting (bit-identical outputs are
checked), and the default sRGB/rounding kernel, fusion and the motion-blur emulation are timed too. Goal: LUT >=
100x faster than interp1d.
"""

from __future__ import annotations

import argparse
import statistics
import sys
import time
from collections.abc import Callable

import numpy as np

from bracketry_base import paths
from bracketry_emulator.crf import load_pcalib, response_from_pcalib
from bracketry_emulator.dataset import open_dataset
from bracketry_emulator.emulation import Emulator, EmulatorConfig, LutCache, apply_lut, kernel
from bracketry_emulator.emulation.blur import Velocity, add_motion_blur
from bracketry_emulator.emulation.reference import UpstreamFormula
from bracketry_emulator.extensions import extensions_disabled


def _median_ms(fn: Callable[[], object], repeats: int, warmup: int = 2) -> float:
    for _ in range(warmup):
        fn()
    times = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        fn()
        times.append(time.perf_counter() - t0)
    return 1e3 * statistics.median(times)


def _inputs() -> tuple[dict[int, np.ndarray], np.ndarray, str]:
    root = paths.sample_data_dir()
    if root is not None:
        ds = open_dataset(root)
        imgs = ds.sequences()[0].load("left")
        pcalib = load_pcalib(root / "calibration" / "pcalib_inside1.txt")
        return imgs, pcalib, "BorealHDR sample, left, sequence 0"
    rng = np.random.default_rng(0)
    base = rng.gamma(2.0, 0.1, size=(1200, 1920))
    imgs = {e: np.clip(base * e, 0, 4094).astype(np.uint16) for e in (1000, 2000, 4000, 8000, 16000, 32000)}
    pcalib = np.linspace(0.17, 255.0, 256) ** 1.0
    return imgs, pcalib, "synthetic 1920x1200 (sample not found)"


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true", help="fewer repetitions")
    args = ap.parse_args(argv)
    reps_slow, reps_fast = (3, 15) if args.quick else (10, 50)
    imgs, pcalib, what = _inputs()
    src = imgs[8000]
    print(f"frame: {what}, {src.shape[1]}x{src.shape[0]} uint16")
    theirs = UpstreamFormula(pcalib)
    resp = response_from_pcalib(pcalib, lifting="upstream")
    lut = LutCache(resp).get(0.75, "trunc")
    same = np.array_equal(apply_lut(lut, src), theirs.radiance_emulation(src, 6.0, 8.0))
    print(f"bit-identical to the interp1d formula: {same}")
    t_theirs = _median_ms(lambda: theirs.radiance_emulation(src, 6.0, 8.0), reps_slow)
    out = np.empty_like(src)
    t_lut = _median_ms(lambda: apply_lut(lut, src, out), reps_fast)
    with extensions_disabled():
        t_np2 = _median_ms(lambda: apply_lut(lut, src, out), reps_fast)
        t_np1 = _median_ms(lambda: apply_lut(lut, src, out, threads=False), reps_fast)
    t_build = _median_ms(lambda: resp.lut(0.75, "trunc"), reps_fast)
    emu_h = Emulator(EmulatorConfig())
    t_emu = _median_ms(lambda: emu_h.emulate(imgs, 6000.0), reps_fast)
    emu_f = Emulator(EmulatorConfig(selection="fusion"))
    t_fus = _median_ms(lambda: emu_f.emulate(imgs, 6000.0), max(3, reps_slow))
    resp_srgb = emu_h.response
    t_emu_cold = _median_ms(lambda: Emulator(EmulatorConfig(), response=resp_srgb).emulate(imgs, 6000.0), reps_fast)
    t_fus_cold = _median_ms(lambda: Emulator(EmulatorConfig(selection="fusion"), response=resp_srgb)
                            .emulate(imgs, 6000.0), max(3, reps_slow))
    # motion-blur emulation (emulation/blur.py): 4 ms source as 32 ms, a uniform image velocity of 60 half-resolution
    # pixels per second (7 copies, 0.5 px apart)
    h2, w2 = src.shape[0] // 2, src.shape[1] // 2
    velocity = Velocity(np.full((h2, w2), 60.0, np.float32), np.full((h2, w2), 10.0, np.float32))
    linear = resp_srgb.icrf[imgs[4000]].astype(np.float32)
    t_blur = _median_ms(lambda: add_motion_blur(linear, velocity, 0.028, 0.004), max(3, reps_slow))
    print(f"{'kernel':52s} {'median ms':>10s} {'speed-up':>9s}")
    rows = [("authors' formula (2 x interp1d per pixel)", t_theirs),
            (f"LUT kernel apply_lut ({'C gather' if kernel.c_kernel() else 'numpy'})", t_lut),
            ("LUT kernel, numpy take, 2 threads", t_np2),
            ("LUT kernel, numpy take, 1 thread", t_np1),
            ("LUT build (4096 entries, upstream lifting)", t_build),
            ("emulate highernosat, same brackets again (cached)", t_emu),
            ("emulate highernosat, new brackets (sat. + LUT)", t_emu_cold),
            ("emulate fusion, same brackets again (cached E)", t_fus),
            ("emulate fusion, new brackets (bounding pair)", t_fus_cold),
            ("motion blur: 4 ms as 32 ms (add_motion_blur)", t_blur)]
    for name, t in rows:
        print(f"{name:52s} {t:10.2f} {t_theirs / t:8.1f}x")
    ratio = t_theirs / t_lut
    print(f"kernel speed-up {ratio:.0f}x (numpy-only fallback {t_theirs / min(t_np1, t_np2):.0f}x); goal >= 100x: "
          f"{'met' if ratio >= 100 else 'NOT met'}")
    return 0 if same else 1


if __name__ == "__main__":
    sys.exit(main())
