"""Benchmark: wall time of `run_benchmark` with 2 Dask workers vs 1 (goal: speed-up >= 1.8x on 2 cores).

Workload: toy-world trajectories (ray-cast stereo corridor, pre-emulated runs of two 'methods'), each task = stereo VO
+ evo RTE/RRE + robustness; no cache hits (a fresh output folder per run). The Dask LocalCluster (127.0.0.1,
dashboard off, one thread per worker process) is started before the clock; the local process pool is timed too.

    .venv/bin/python benchmarks/bench_dask.py [--quick]
"""

from __future__ import annotations

import argparse
import os
import statistics
import tempfile
import time
from pathlib import Path


def make_datasets(root: Path, n_traj: int, n_frames: int) -> list[Path]:
    from bracketry_emulator.benchmark.toyworld import ToyWorld

    out = []
    for seed in range(n_traj):
        d = root / f"traj{seed}"
        w = ToyWorld(seed=seed)
        w.write_calibration(d)
        for method, gain in (("ae50", 1.0), ("dim", 0.7)):
            times = w.write_run(d, method, n_frames, gain=gain)
        w.write_groundtruth(d / "groundtruth.txt", times)
        out.append(d)
    return out


LOADS: list[float] = []


def timed(fn) -> float:
    LOADS.append(os.getloadavg()[0])
    t0 = time.perf_counter()
    fn()
    return time.perf_counter() - t0


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--quick", action="store_true", help="fewer trajectories, one repetition")
    args = ap.parse_args()
    n_traj, n_frames, reps = (4, 8, 1) if args.quick else (6, 12, 3)

    from distributed import LocalCluster

    from bracketry_emulator.benchmark import BenchmarkConfig, run_benchmark

    with tempfile.TemporaryDirectory(prefix="bench_dask_") as tmp:
        root = Path(tmp)
        datasets = make_datasets(root / "data", n_traj, n_frames)
        n_tasks = 2 * n_traj
        counter = iter(range(10_000))

        def run(**kw) -> None:
            run_benchmark(BenchmarkConfig(datasets, ["ae50", "dim"], root / f"out{next(counter)}", windows_m=(1.0, 2.0),
                                          report=False, **kw))

        times: dict[str, list[float]] = {}
        for n_workers in (1, 2):
            with LocalCluster(n_workers=n_workers, threads_per_worker=1, processes=True, host="127.0.0.1",
                              dashboard_address="127.0.0.1:0", scheduler_kwargs={"dashboard": False}) as cluster:
                run(scheduler=cluster.scheduler_address)  # warm-up: imports in the workers
                times[f"dask {n_workers}w"] = [timed(lambda c=cluster: run(scheduler=c.scheduler_address))
                                               for _ in range(reps)]
        for n_workers in (1, 2):
            times[f"local {n_workers}w"] = [timed(lambda n=n_workers: run(workers=n)) for _ in range(reps)]

    print(f"workload: {n_tasks} tasks ({n_traj} trajectories x 2 methods, {n_frames} stereo frames 320x240 each)")
    med = {k: statistics.median(v) for k, v in times.items()}
    for k, v in med.items():
        print(f"{k:9s} median {v:7.2f} s  ({', '.join(f'{x:.2f}' for x in times[k])})")
    print(f"speed-up dask  2 vs 1 workers: {med['dask 1w'] / med['dask 2w']:.2f}x (goal >= 1.8x)")
    print(f"speed-up local 2 vs 1 workers: {med['local 1w'] / med['local 2w']:.2f}x (2 workers include process spawn)")
    print(f"1-min load average during the runs: {min(LOADS):.1f}..{max(LOADS):.1f} on {os.cpu_count()} CPUs "
          "(a speed-up needs idle cores: above ~1 the other processes take the second core)")


if __name__ == "__main__":
    main()
