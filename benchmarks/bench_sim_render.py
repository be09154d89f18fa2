"""The simulated rig's renderer, per side and bracket cycle: before (numpy paths, a BLAS thread pool) vs now (the
compiled loops, one BLAS thread), side by side.

Usage: .venv/bin/python benchmarks/bench_sim_render.py [--resolution 640x400] [--cycles 40] [--preset forest-winter]
       [--process-cycles 165] [--repeats 3]

1. In this process (one BLAS thread for both), what one renderer process of ``bracketry simulate`` does per side and
bracket cycle (one scene render, then the cycle's exposures with the rig's pre-drawn noise,
``bracketry.sim.frames.world_frame``), timed on consecutive cycles of the walk at the rig's default 22 fps and 6
brackets, once with the numpy paths (``extensions_disabled()``, as with ``BRACKETRY_NO_CKERNEL=1``) and once with
the compiled ``bracketry_emulator.synth._kernels``, alternating cycle by cycle so both see the same load. Checks both
give the same codes, and prints medians (ms per side per cycle, radiance ms, ms per exposure) and the ratio. The
cameras need 22 / 6 cycles per second per side: a cycle's CPU time x 3.67 is the share of a core each renderer needs.

2. The renderer processes as ``bracketry simulate`` starts them (``FrameSchedule.start``: both sides at once,
``--process-cycles`` cycles each, start-up included), before (``BRACKETRY_NO_CKERNEL=1`` and
``OPENBLAS_NUM_THREADS=2``, numpy's default pool here) and now, alternating: their CPU seconds per side and cycle and
their wall time (medians of ``--repeats``). The pool's threads spin waiting for each other when the other core is
busy, so the gap is widest on a loaded machine: quote the load average.
"""

from __future__ import annotations

import os
import sys

if "--child" not in sys.argv:  # the process comparison's children keep the environment they are given
    for _var in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
        os.environ[_var] = "1"

import argparse
import contextlib
import resource
import shutil
import statistics
import subprocess
import tempfile
import time

import numpy as np

from bracketry.sim.frames import cycle_rates, expose_frame, noise_bank, reference_time_s, trigger_time_s
from bracketry_emulator.extensions import extensions_disabled
from bracketry_emulator.runtime_policy import apply_profile
from bracketry_emulator.synth import World
from bracketry_emulator.synth.kernels import synth_kernels
from bracketry_emulator.synth.world import parse_resolution

BRACKETS_US = (1000, 2000, 4000, 8000, 16000, 32000)
FPS = 22.0


def _cycle(world: World, bank: np.ndarray, side: str, c: int) -> tuple[float, float, float, list[np.ndarray]]:
    """(cycle CPU s, radiance CPU s, reprojection + exposures CPU s, frames) of bracket cycle ``c`` of ``side``."""
    n = len(BRACKETS_US)
    world._cache.clear()  # a new cycle renders its scene (as in the rig: each cycle is a new world time)
    c0 = time.process_time()
    world.radiance(side, reference_time_s(c, BRACKETS_US, FPS))
    c1 = time.process_time()
    rates = cycle_rates(world, side, c, BRACKETS_US, FPS)
    frames = [expose_frame(world, bank, side, r, trigger_time_s(c * n + j, FPS), float(e))
              for j, (r, e) in enumerate(zip(rates, BRACKETS_US))]
    c2 = time.process_time()
    return c2 - c0, c1 - c0, c2 - c1, frames


def _processes(res: tuple[int, int], preset: str, cycles: int) -> None:
    """Child mode: start the rig's renderer processes for ``cycles`` cycles per side, wait, print CPU and wall s."""
    from bracketry.sim.frames import FrameSchedule, WorldSpec

    folder = tempfile.mkdtemp(prefix="bench-sim-render-")
    try:
        sched = FrameSchedule(folder, WorldSpec(preset), BRACKETS_US, FPS, cycles * len(BRACKETS_US), resolution=res)
        t0 = time.perf_counter()
        sched.start()
        sched.wait(timeout_s=1800)
        wall_s = time.perf_counter() - t0
        for proc in sched._procs:
            proc.join(60)
        ru = resource.getrusage(resource.RUSAGE_CHILDREN)
        print(f"{ru.ru_utime + ru.ru_stime} {wall_s}")
    finally:
        shutil.rmtree(folder, ignore_errors=True)


def _compare_processes(args: argparse.Namespace) -> None:
    env_now = {k: v for k, v in os.environ.items()  # as the rig starts them (it sets the renderers' own BLAS threads)
               if k not in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS", "BRACKETRY_NO_CKERNEL")}
    envs = {"before": dict(env_now, BRACKETRY_NO_CKERNEL="1", OPENBLAS_NUM_THREADS=str(os.cpu_count() or 2)),
            "now": env_now}
    got: dict[str, dict[str, list[float]]] = {k: {"cpu": [], "wall": []} for k in envs}
    load0 = os.getloadavg()[0]
    for _ in range(args.repeats):
        for name, env in envs.items():
            out = subprocess.run([sys.executable, __file__, "--child", "--resolution", args.resolution, "--preset",
                                  args.preset, "--process-cycles", str(args.process_cycles)], env=env, check=True,
                                 capture_output=True, text=True).stdout.split()
            got[name]["cpu"].append(float(out[0]) / 2 / args.process_cycles)  # per side and cycle
            got[name]["wall"].append(float(out[1]))
    med = {k: {m: statistics.median(v) for m, v in d.items()} for k, d in got.items()}
    print(f"renderer processes as the rig starts them: both sides, {args.process_cycles} cycles each, start-up "
          f"included, medians of {args.repeats}")
    print(f"{'':>7} {'CPU ms per side per cycle':>26} {'wall s':>7}")
    for k, m in med.items():
        print(f"{k:>7} {1000 * m['cpu']:>26.1f} {m['wall']:>7.1f}")
    print(f"ratio before / now: CPU {med['before']['cpu'] / med['now']['cpu']:.2f}x, wall "
          f"{med['before']['wall'] / med['now']['wall']:.2f}x")
    print(f"load average: {load0:.2f} at the start, {os.getloadavg()[0]:.2f} at the end (2 cores shared)")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--resolution", default="640x400")
    ap.add_argument("--cycles", type=int, default=40, help="bracket cycles per side and path")
    ap.add_argument("--preset", default="forest-winter")
    ap.add_argument("--process-cycles", type=int, default=165,
                    help="cycles per side of the process comparison (165: the default demo's 45 s of world)")
    ap.add_argument("--repeats", type=int, default=3, help="runs of each process set-up (0: skip the comparison)")
    ap.add_argument("--child", action="store_true", help=argparse.SUPPRESS)
    args = ap.parse_args()
    if args.child:
        _processes(parse_resolution(args.resolution), args.preset, args.process_cycles)
        return
    apply_profile("timing")
    if synth_kernels() is None:
        raise SystemExit("error: bracketry_emulator.synth._kernels is not built (run ./setup.sh)")
    res = parse_resolution(args.resolution)
    world = World(args.preset, seed=0, resolution=res)
    stats: dict[str, dict[str, list[float]]] = {p: {"cycle": [], "radiance": [], "expose": []} for p in ("numpy", "C")}
    different = 0
    load0 = os.getloadavg()[0]
    for side in ("left", "right"):
        bank = noise_bank(world, ("left", "right").index(side))
        for c in range(-1, args.cycles):
            got = {}
            for path in ("numpy", "C"):
                with extensions_disabled() if path == "numpy" else contextlib.nullcontext():
                    cyc, rad, exp, frames = _cycle(world, bank, side, max(c, 0))
                got[path] = frames
                if c >= 0:  # cycle -1: warm-up (per-side precomputation)
                    stats[path]["cycle"].append(cyc)
                    stats[path]["radiance"].append(rad)
                    stats[path]["expose"].append(exp / len(BRACKETS_US))
            different += any(not np.array_equal(a, b) for a, b in zip(got["numpy"], got["C"]))
    med = {p: {k: 1000 * statistics.median(v) for k, v in s.items()} for p, s in stats.items()}
    w, h = res
    print(f"bench_sim_render ({args.preset} {w}x{h}, {len(BRACKETS_US)} brackets at {FPS:g} fps, both sides, "
          f"{args.cycles} cycles each; CPU ms, medians)")
    print(f"{'path':>6} {'cycle ms':>9} {'radiance ms':>12} {'exposure ms':>12} {'core share at 22 fps':>21}")
    for p, m in med.items():
        share = m["cycle"] / 1000 * FPS / len(BRACKETS_US)
        print(f"{p:>6} {m['cycle']:>9.1f} {m['radiance']:>12.1f} {m['expose']:>12.2f} {share:>20.0%}")
    ratio = {k: med["numpy"][k] / med["C"][k] for k in ("cycle", "radiance", "expose")}
    print(f"ratio numpy / C per side per cycle: {ratio['cycle']:.2f}x (radiance {ratio['radiance']:.2f}x, "
          f"exposure {ratio['expose']:.2f}x)")
    print(f"frames differing between the paths: {different} of {2 * args.cycles} cycles")
    print(f"load average: {load0:.2f} at the start, {os.getloadavg()[0]:.2f} at the end (2 cores shared)")
    if different:
        raise SystemExit(1)
    if args.repeats > 0:
        print()
        _compare_processes(args)


if __name__ == "__main__":
    main()
