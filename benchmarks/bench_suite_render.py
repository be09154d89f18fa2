"""Render time of the synthetic suite (#28 item 7): the demo-size suite rendered whole, the full suite estimated from
a sample of its frames, and the cost per frame against today's renderer at the same resolution.

Usage: .venv/bin/python benchmarks/bench_suite_render.py [--quick] [--workers 2] [--json FILE]

Per frame (median over frames of one walk, each at its own instant and bracket, the writer's order), three ways at
each suite resolution: ``plain`` = today's renderer (the preset's fixed light, no motion blur: one ray cast at one
instant, what every frame cost before scenarios and blur), ``scenario`` = + the scenario's light at the frame's
instant (canopy, clouds, glare), ``scenario+blur`` = + the motion blur of the exposure interval (the World's
default, what the suite renders). CPU time (time.process_time) is printed beside wall time: on a shared, loaded
machine CPU time is the one to compare. Demo: ``render_suite`` into a temporary folder with ``--workers`` processes
(wall, and CPU of all processes). Full: the scene builds and the frames of the 24 trajectories, each measured on a
sample (one trajectory of each subset: its build, and ``--sample-s`` seconds of its frames written as the suite
writes them), times the frame counts. Goal: the demo suite in <= 60 s wall on this 2-core machine.
"""

from __future__ import annotations

import os

for _var in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ[_var] = "1"

import argparse  # noqa: E402
import json  # noqa: E402
import resource  # noqa: E402
import statistics  # noqa: E402
import tempfile  # noqa: E402
import time  # noqa: E402
from pathlib import Path  # noqa: E402

from bracketry_emulator.runtime_policy import apply_profile  # noqa: E402
from bracketry_emulator.synth import World  # noqa: E402
from bracketry_emulator.synth.scenario import scenario_from_dict  # noqa: E402
from bracketry_emulator.synth.suite import SIZES, entries, entry_scenario_doc, render_suite  # noqa: E402
from bracketry_emulator.synth.world import world_from_scenario  # noqa: E402
from bracketry_emulator.synth.writer import write_trajectory  # noqa: E402

GOAL_DEMO_S = 60.0


def _children_cpu_s() -> float:
    ru = resource.getrusage(resource.RUSAGE_CHILDREN)
    return ru.ru_utime + ru.ru_stime


def _per_frame(world: World, n: int, brackets_ms: tuple[float, ...], fps: float) -> tuple[float, float]:
    """Median (CPU ms, wall ms) of one frame (one side), frames k = 1..n of the walk at their own instants."""
    cpu, wall = [], []
    world.render("left", 0.0, brackets_ms[0] * 1000.0)  # warm-up: per-side precomputation
    for k in range(1, n + 1):
        t_s = 3.0 + k / fps
        exp_us = brackets_ms[k % len(brackets_ms)] * 1000.0
        c0, t0 = time.process_time(), time.perf_counter()
        world.render("left", t_s, exp_us)
        cpu.append(time.process_time() - c0)
        wall.append(time.perf_counter() - t0)
    return 1000 * statistics.median(cpu), 1000 * statistics.median(wall)


def bench_frames(size: str, n: int) -> list[dict]:
    """Per-frame cost at the resolution of ``size``: plain, scenario, scenario+blur, for one entry of each subset."""
    spec = SIZES[size]
    rows = []
    seen = set()
    for e in entries(size):
        if e.subset in seen:
            continue
        seen.add(e.subset)
        sc = scenario_from_dict(entry_scenario_doc(e, size, 0))
        plain = World(sc.preset, 0, spec.resolution, detail=spec.detail, motion_blur=False)
        lit = world_from_scenario(sc, detail=spec.detail, motion_blur=False)
        blurred = world_from_scenario(sc, detail=spec.detail)
        row = {"size": size, "entry": e.name, "resolution": f"{spec.resolution[0]}x{spec.resolution[1]}"}
        for name, w in (("plain", plain), ("scenario", lit), ("scenario+blur", blurred)):
            cpu, wall = _per_frame(w, n, sc.brackets_ms, sc.fps)
            row[f"{name}_cpu_ms"], row[f"{name}_wall_ms"] = cpu, wall
        row["ratio_blur_vs_plain_cpu"] = row["scenario+blur_cpu_ms"] / row["plain_cpu_ms"]
        row["ratio_scenario_vs_plain_cpu"] = row["scenario_cpu_ms"] / row["plain_cpu_ms"]
        rows.append(row)
        print(f"  {size:4s} {row['resolution']:8s} {e.name:20s} per frame CPU ms: plain {row['plain_cpu_ms']:6.1f}  "
              f"scenario {row['scenario_cpu_ms']:6.1f} (x{row['ratio_scenario_vs_plain_cpu']:.2f})  "
              f"scenario+blur {row['scenario+blur_cpu_ms']:6.1f} (x{row['ratio_blur_vs_plain_cpu']:.2f})", flush=True)
    return rows


def bench_demo(workers: int) -> dict:
    """Render the demo suite whole into a temporary folder."""
    with tempfile.TemporaryDirectory() as tmp:
        c_self, c_kids, t0 = time.process_time(), _children_cpu_s(), time.perf_counter()
        render_suite(Path(tmp) / "suite", "demo", 0, workers=workers)
        wall = time.perf_counter() - t0
        cpu = time.process_time() - c_self + _children_cpu_s() - c_kids
    n = len(entries("demo"))
    return {"trajectories": n, "workers": workers, "wall_s": wall, "cpu_s": cpu, "goal_wall_s": GOAL_DEMO_S}


def estimate_full(sample_s: float) -> dict:
    """The full suite's render time from one trajectory of each subset: build + ``sample_s`` of frames each."""
    spec = SIZES["full"]
    per_subset: dict[str, tuple[float, float]] = {}
    with tempfile.TemporaryDirectory() as tmp:
        for e in entries("full"):
            if e.subset in per_subset:
                continue
            sc = scenario_from_dict(entry_scenario_doc(e, "full", 0))
            c0, t0 = time.process_time(), time.perf_counter()
            world = world_from_scenario(sc, detail=spec.detail)
            build_cpu = time.process_time() - c0
            c1 = time.process_time()
            summary = write_trajectory(world, Path(tmp) / e.name, seconds=sample_s, brackets_ms=sc.brackets_ms,
                                       fps=sc.fps)
            frame_cpu = (time.process_time() - c1) / (summary["frames"] * len(summary["sides"]))
            per_subset[e.subset] = (build_cpu, frame_cpu)
            print(f"  full sample {e.name:20s} build {build_cpu:5.2f} s CPU, {1000 * frame_cpu:6.1f} ms CPU per "
                  f"written frame (one side, incl. PNG), wall {time.perf_counter() - t0:.1f} s", flush=True)
    total_cpu = 0.0
    n_frames = 0
    for e in entries("full"):
        build, frame = per_subset[e.subset]
        frames = max(1, round(spec.duration_s * 22.0 / 6)) * 6 * 2
        n_frames += frames
        total_cpu += build + frames * frame
    return {"trajectories": len(entries("full")), "frames": n_frames, "cpu_s": total_cpu,
            "wall_s_2_workers": total_cpu / 2, "per_subset": {k: {"build_cpu_s": v[0], "frame_cpu_ms": 1000 * v[1]}
                                                             for k, v in per_subset.items()}}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true", help="fewer frames per measure")
    ap.add_argument("--workers", type=int, default=2, help="processes for the demo suite (default 2)")
    ap.add_argument("--sample-s", type=float, default=1.1, help="seconds of each full-size sample trajectory")
    ap.add_argument("--json", type=Path, default=None, help="also write the figures here")
    args = ap.parse_args()
    apply_profile("timing")
    n = 8 if args.quick else 24
    print(f"load average at start: {os.getloadavg()[0]:.1f} on {os.cpu_count()} CPUs")
    print("per frame (median of", n, "frames):")
    frames = bench_frames("demo", n) + bench_frames("full", max(4, n // 3))
    print("demo suite, rendered whole:")
    demo = bench_demo(args.workers)
    print(f"  {demo['trajectories']} trajectories, {args.workers} workers: wall {demo['wall_s']:.1f} s (goal <= "
          f"{GOAL_DEMO_S:.0f} s), CPU {demo['cpu_s']:.1f} s")
    print("full suite, estimated from samples:")
    full = estimate_full(args.sample_s)
    print(f"  {full['trajectories']} trajectories, {full['frames']} frames: CPU {full['cpu_s'] / 60:.1f} min "
          f"(~{full['wall_s_2_workers'] / 60:.1f} min wall on 2 idle cores)")
    print(f"load average at end: {os.getloadavg()[0]:.1f}")
    if args.json is not None:
        args.json.write_text(json.dumps({"frames": frames, "demo": demo, "full": full}, indent=2) + "\n")


if __name__ == "__main__":
    main()
