"""Render time of the synthetic world (one core): radiance ray casting, the camera model, PNG encoding.

Usage: .venv/bin/python benchmarks/bench_synth.py [--quick]

Goal: one 960x600 frame (ray casting + camera model) <= 50 ms on one core. Prints medians over several poses of
the walk (each frame at a new pose, so nothing is cached), both resolutions measured side by side in one run.
"""

from __future__ import annotations

import os

for _var in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ[_var] = "1"

import argparse  # noqa: E402
import statistics  # noqa: E402
import time  # noqa: E402

import cv2  # noqa: E402

from bracketry_emulator.runtime_policy import apply_profile  # noqa: E402
from bracketry_emulator.synth import World  # noqa: E402

GOAL_MS = 50.0


def _bench(world: World, n: int) -> dict[str, float]:
    side = "left"
    geo, cam, total, png, cpu = [], [], [], [], []
    for k in range(n + 1):
        t_s = 7.3 + 3.1 * k  # a new pose each time: no cache hit
        c0 = time.process_time()
        t0 = time.perf_counter()
        world.radiance(side, t_s)
        t1 = time.perf_counter()
        img = world.render(side, t_s, 4000.0)
        t2 = time.perf_counter()
        c1 = time.process_time()
        ok, _buf = cv2.imencode(".png", img, [cv2.IMWRITE_PNG_COMPRESSION, 1])
        t3 = time.perf_counter()
        assert ok
        if k == 0:
            continue  # warm-up (lazy per-side precomputation)
        geo.append(t1 - t0)
        cam.append(t2 - t1)
        total.append(t2 - t0)
        cpu.append(c1 - c0)
        png.append(t3 - t2)
    med = {name: 1000 * statistics.median(v) for name, v in
           (("raycast_ms", geo), ("camera_ms", cam), ("frame_ms", total), ("frame_cpu_ms", cpu), ("png_ms", png))}
    return med


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true", help="fewer repetitions")
    ap.add_argument("--preset", default="forest-winter")
    args = ap.parse_args()
    apply_profile("timing")
    n = 5 if args.quick else 15
    rows = {}
    for res in ((960, 600), (1920, 1200)):
        t0 = time.perf_counter()
        world = World(args.preset, seed=0, resolution=res)
        world.radiance("left", 0.0)
        setup_s = time.perf_counter() - t0
        rows[res] = _bench(world, n if res[0] < 1920 else max(3, n // 3))
        rows[res]["setup_s"] = setup_s
    print(f"bench_synth ({args.preset}, one core, median over new poses; frame = ray casting + camera model)")
    print(f"{'resolution':>11} {'raycast ms':>11} {'camera ms':>10} {'frame ms':>9} {'cpu ms':>7} {'png ms':>7} "
          f"{'setup s':>8}")
    for (w, h), r in rows.items():
        print(f"{w:>5}x{h:<5} {r['raycast_ms']:>11.1f} {r['camera_ms']:>10.1f} {r['frame_ms']:>9.1f} "
              f"{r['frame_cpu_ms']:>7.1f} {r['png_ms']:>7.1f} {r['setup_s']:>8.2f}")
    small, big = rows[(960, 600)], rows[(1920, 1200)]
    print(f"ratio 1920x1200 / 960x600 frame time: {big['frame_ms'] / small['frame_ms']:.2f} (pixels x4)")
    verdict = "meets" if small["frame_ms"] <= GOAL_MS else "misses"
    print(f"960x600 frame {small['frame_ms']:.1f} ms vs goal {GOAL_MS:.0f} ms: ratio {small['frame_ms'] / GOAL_MS:.2f} "
          f"({verdict} the goal)")
    print(f"load average during the run: {os.getloadavg()[0]:.2f} (2 cores shared)")


if __name__ == "__main__":
    main()
