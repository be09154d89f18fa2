"""The simulated rig's renderer, per side and bracket cycle: each bracket at its own instant with its motion blur
(reprojection) vs one instant per cycle; numpy paths vs compiled loops; the renderer processes as the rig starts them.

Usage: .venv/bin/python benchmarks/bench_sim_render.py [--resolution 640x400] [--cycles 40] [--preset forest-winter]
       [--process-cycles 165] [--repeats 3] [--blur-cycles 8] [--error-cycles 3] [--speed-kmh 2]

0. Motion blur (``--blur-cycles``, ``--error-cycles``; 0 skips): CPU per frame and per cycle of one side, alternating
cycle by cycle on the same walk: "before" (one render per cycle at its first trigger, no blur: what the rig did),
"rig now" (one render per cycle at the middle of its span, reprojected to each bracket's exposure interval:
``bracketry.sim.frames.cycle_rates``), "offline before" (one render per frame, no blur: ``synth trajectory``'s old
default), "offline now" (one render per frame at its mid-exposure, reprojected within its exposure: ``synth
trajectory``), "offline k renders" (up to k renders per frame, each moved to its share of the instants:
``World(blur_renders=k)``), "old 4-slice blur" (the former ``--motion-blur``: the mean of ceil(E / 8 ms) <= 4 full
renders) and "dense" (full renders at the reprojection's instants). Error: RMSE in DN of the noise-free frame (its
own exposure) against the mean of full renders at 4x the reprojection's instants (at least 8, <= 0.25 px of motion
apart), per bracket, medians over the cycles; "sharp at mid" is one full render at mid-exposure (blur off); "dense/2"
(half the reference's instants) is the floor. A point-sampled render aliases (fine texture, far foliage): most of a
one-render frame's error is that aliasing, which only more renders average out.

1. In this process (one BLAS thread for both), what one renderer process of ``bracketry simulate`` does per side and
bracket cycle (one scene render, reprojected to the cycle's brackets and exposed with the rig's pre-drawn noise,
``bracketry.sim.frames.cycle_rates`` and ``expose_frame``), timed on consecutive cycles of the walk at the rig's
default 22 fps and 6 brackets, once with the numpy paths (``extensions_disabled()``, as with
``BRACKETRY_NO_CKERNEL=1``) and once with the compiled ``bracketry_emulator.synth._kernels``, alternating cycle by
cycle so both see the same load. Checks both give the same codes, and prints medians (ms per side per cycle,
radiance ms, ms per exposure) and the ratio. The cameras need 22 / 6 cycles per second per side: a cycle's CPU
time x 3.67 is the share of a core each renderer needs.

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
import math
import resource
import shutil
import statistics
import subprocess
import tempfile
import time

import numpy as np

from bracketry.sim.frames import cycle_rates, expose_frame, noise_bank, reference_time_s, trigger_time_s
from bracketry_base.options import parse_resolution
from bracketry_emulator.extensions import extensions_disabled
from bracketry_emulator.runtime_policy import apply_profile
from bracketry_emulator.synth import World
from bracketry_emulator.synth.kernels import synth_kernels
from bracketry_emulator.synth.trajectory import LoopTrajectory

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


def _rmse_dn(world: World, a: np.ndarray, b: np.ndarray, exposure_us: float) -> float:
    ca = world.camera.noise_free_codes(a, exposure_us).astype(np.float64)
    cb = world.camera.noise_free_codes(b, exposure_us).astype(np.float64)
    return float(np.sqrt(np.mean((ca - cb) ** 2)))


def _blur_report(args: argparse.Namespace) -> None:
    """Section 0 (see the module docstring)."""
    res = parse_resolution(args.resolution)
    traj = LoopTrajectory(speed_kmh=args.speed_kmh)
    world = World(args.preset, seed=0, resolution=res, trajectory=traj, cache_size=1024)
    sharp = World(args.preset, seed=0, resolution=res, trajectory=traj, motion_blur=False)
    dense_w = World(args.preset, seed=0, resolution=res, trajectory=traj, blur_method="render", cache_size=1024)
    multi = {k: World(args.preset, seed=0, resolution=res, trajectory=traj, blur_renders=k, cache_size=1024)
             for k in (2, 4)}
    n = len(BRACKETS_US)
    side = "left"
    bank = noise_bank(world, 0)
    cpu: dict[str, list[float]] = {k: [] for k in ("before", "rig now", "offline before", "offline now",
                                                   "offline 2 renders",
                                                   "offline 4 renders", "old 4-slice blur", "dense")}
    instants: list[list[int]] = []

    def expose_all(rates: list[np.ndarray], c: int) -> list[np.ndarray]:
        return [expose_frame(world, bank, side, r, trigger_time_s(c * n + j, FPS), float(e))
                for j, (r, e) in enumerate(zip(rates, BRACKETS_US))]

    def intervals(c: int) -> list[tuple[float, float]]:
        return [(trigger_time_s(c * n + j, FPS), float(e)) for j, e in enumerate(BRACKETS_US)]

    def old_blur(c: int) -> list[np.ndarray]:  # the former --motion-blur: ceil(E / 8 ms) <= 4 full renders
        return [sharp._gained(side, sharp.integrate(side, [t + (k + 0.5) / m * e * 1e-6 for k in range(m)]))
                for t, e in intervals(c) for m in [max(1, min(4, math.ceil(e / 8000.0)))]]

    variants = {"before": lambda c: [sharp.rate_e_per_us(side, trigger_time_s(c * n, FPS))] * n,
                "rig now": lambda c: cycle_rates(world, side, c, BRACKETS_US, FPS),
                "offline before": lambda c: [sharp.rate_e_per_us(side, t) for t, _e in intervals(c)],
                "offline now": lambda c: cycle_rates(world, side, c, BRACKETS_US, FPS, "frame"),
                "offline 2 renders": lambda c: cycle_rates(multi[2], side, c, BRACKETS_US, FPS, "frame"),
                "offline 4 renders": lambda c: cycle_rates(multi[4], side, c, BRACKETS_US, FPS, "frame"),
                "old 4-slice blur": old_blur,
                "dense": lambda c: cycle_rates(dense_w, side, c, BRACKETS_US, FPS, "frame")}
    first = 7  # past the walk's first seconds
    for i in range(-1, args.blur_cycles):  # cycle -1: warm-up
        c = first + 11 * max(i, 0)
        for name, rates_of in variants.items():
            for w_ in (world, sharp, dense_w, *multi.values()):
                w_._cache.clear()
            c0 = time.process_time()
            expose_all(rates_of(c), c)
            if i >= 0:
                cpu[name].append(time.process_time() - c0)
        if i >= 0:
            instants.append([len(world.blur_times_s(t, e)) for t, e in intervals(c)])
    w, h = res
    print(f"motion blur ({args.preset} {w}x{h}, {args.speed_kmh:g} km/h, {n} brackets at {FPS:g} fps, one side, "
          f"{args.blur_cycles} cycles along the walk; CPU ms, medians)")
    inst = np.median(np.array(instants), axis=0) if instants else np.zeros(n)
    print("instants per frame (reprojection, <= 1 px apart), per bracket: "
          + ", ".join(f"{e / 1000:g} ms: {k:g}" for e, k in zip(BRACKETS_US, inst)))
    med = {k: 1000 * statistics.median(v) for k, v in cpu.items() if v}
    print(f"{'':>18} {'ms per cycle':>13} {'ms per frame':>13} {'x before':>9} {'core share at 22 fps':>21}")
    for k, m in med.items():
        print(f"{k:>18} {m:>13.1f} {m / n:>13.1f} {m / med['before']:>9.2f} {m / 1000 * FPS / n:>20.0%}")
    if args.error_cycles <= 0:
        return
    errs: dict[str, list[list[float]]] = {k: [] for k in ("before", "rig now", "offline before", "offline now",
                                                          "offline 2 renders",
                                                          "offline 4 renders", "old 4-slice blur", "sharp at mid",
                                                          "dense/2")}
    for i in range(args.error_cycles):
        c = first + 17 * i
        ivs = intervals(c)
        got = {k: variants[k](c) for k in ("before", "rig now", "offline before", "offline now", "offline 2 renders",
                                           "offline 4 renders", "old 4-slice blur")}
        got["sharp at mid"] = [sharp.rate_e_per_us(side, t, e) for t, e in ivs]
        got["dense/2"] = []
        refs = []
        for t, e in ivs:
            m = max(8, 4 * len(world.blur_times_s(t, e)))
            refs.append(world._gained(side, world.integrate(side, [t + (k + 0.5) / m * e * 1e-6 for k in range(m)])))
            got["dense/2"].append(world._gained(side, world.integrate(
                side, [t + (k + 0.5) / (m // 2) * e * 1e-6 for k in range(m // 2)])))
            world._cache.clear()
        for k in errs:
            errs[k].append([_rmse_dn(world, got[k][j], refs[j], e) for j, (_t, e) in enumerate(ivs)])
    print(f"error against dense full renders (RMSE DN of the noise-free frame at its own exposure; medians over "
          f"{args.error_cycles} cycles)")
    print(f"{'':>18} " + " ".join(f"{e / 1000:>7g} ms" for e in BRACKETS_US) + f" {'mean':>8}")
    for k, rows in errs.items():
        m = np.median(np.array(rows), axis=0)
        print(f"{k:>18} " + " ".join(f"{x:>10.1f}" for x in m) + f" {float(m.mean()):>8.1f}")


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
    ap.add_argument("--blur-cycles", type=int, default=8, help="cycles of the motion-blur cost comparison (0: skip)")
    ap.add_argument("--error-cycles", type=int, default=3, help="cycles of the error against dense renders (0: skip)")
    ap.add_argument("--speed-kmh", type=float, default=2.0, help="walking speed of the motion-blur sections")
    ap.add_argument("--skip-paths", action="store_true", help="skip the numpy / C comparison")
    ap.add_argument("--child", action="store_true", help=argparse.SUPPRESS)
    args = ap.parse_args()
    if args.child:
        _processes(parse_resolution(args.resolution), args.preset, args.process_cycles)
        return
    apply_profile("timing")
    if synth_kernels() is None:
        raise SystemExit("error: bracketry_emulator.synth._kernels is not built (run ./setup.sh)")
    if args.blur_cycles > 0:
        _blur_report(args)
        print()
    if args.skip_paths:
        if args.repeats > 0:
            _compare_processes(args)
        return
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
