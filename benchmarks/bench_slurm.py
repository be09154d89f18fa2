"""Benchmark: ``bracketry benchmark`` on Slurm (1 and 2 jobs) against local processes (1 and 2 workers).

Workload: N short synthetic walks (``bracketry synth trajectory``, 320x200, 3 brackets, 4 s = 20 closed-loop steps)
x 2 methods (ae50, ae30), built-in VO, no cache hits (a fresh output folder per run). The Slurm side is a one-node
Slurm started here (the tests' ``slurm_node``: munged + slurmctld + slurmd in a private network namespace, needs
root), one core per job, the Dask scheduler in the benchmark process; each run is the whole command from the shell
(imports, Slurm jobs started and released, report), as a lab runs it. Prints per configuration the median wall time,
runs per minute, CPU seconds per run (SLAM + metrics, from the report's stages.json), the efficiency
of the second worker (T1 / (2 T2)) and the cost of the cluster path (Slurm 1 job / local 1 worker).

    .venv/bin/python benchmarks/bench_slurm.py [--trajectories 4] [--repeats 3]
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path[:0] = [str(ROOT / "tests"), str(ROOT / "tests" / "bracketry_emulator" / "benchmark")]

JOBQUEUE_YAML = """\
jobqueue:
  slurm:
    cores: 1
    memory: 2GB
    walltime: "01:00:00"
    death-timeout: 30
    local-directory: {root}/dask-worker
    log-directory: {root}/jobs
    scheduler-options: {{host: 127.0.0.1, dashboard: false}}
    worker-extra-args: ["--host", "127.0.0.1"]
"""


def make_walks(root: Path, n: int) -> list[Path]:
    root.mkdir(parents=True, exist_ok=True)
    out = []
    for seed in range(1, n + 1):
        d = root / f"walk{seed}"
        subprocess.run([sys.executable, "-m", "bracketry", "synth", "trajectory", "--out", str(d), "--duration-s", "4",
                        "--resolution", "320x200", "--fps", "15", "--brackets-ms", "2,8,32", "--seed", str(seed),
                        "-q"], check=True, capture_output=True)
        out.append(d)
    return out


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--trajectories", type=int, default=4)
    ap.add_argument("--repeats", type=int, default=3, help="timed runs per configuration (medians)")
    args = ap.parse_args()
    from slurm_node import start_slurm

    loads: list[float] = []
    with tempfile.TemporaryDirectory(prefix="bench_slurm_") as tmp:
        root = Path(tmp)
        walks = make_walks(root / "data", args.trajectories)
        n_runs = 2 * len(walks)
        (root / "dask").mkdir()
        (root / "jobs").mkdir()
        (root / "dask" / "jobqueue.yaml").write_text(JOBQUEUE_YAML.format(root=root))
        node = start_slurm(root / "slurm", cpus=2)
        counter = iter(range(10_000))
        try:
            env = node.env({**os.environ, "DASK_CONFIG": str(root / "dask")})

            def run(*extra: str) -> tuple[float, float]:
                out = root / f"out{next(counter)}"
                cmd = [sys.executable, "-m", "bracketry", "benchmark", *map(str, walks), "--out", str(out), "--slam",
                       "builtin", "--methods", "ae50,ae30", "--windows", "1", "-q", *extra]
                loads.append(os.getloadavg()[0])
                t0 = time.perf_counter()
                done = subprocess.run(node.command(*cmd), env=env, cwd=root, capture_output=True, text=True)
                if done.returncode != 0:
                    raise SystemExit(f"{' '.join(cmd)} failed: {done.stderr.strip()[-2000:]}")
                wall = time.perf_counter() - t0
                stages = json.loads((out / "report" / "stages.json").read_text())["stages"]
                cpu = sum(float(stages[k].get("cpu_s", 0.0)) for k in ("slam", "metrics") if k in stages)
                return wall, cpu / n_runs

            configs = {"local 1w": ("--workers", "1"), "local 2w": ("--workers", "2"),
                       "slurm 1 job": ("--cluster", "slurm", "--jobs", "1"),
                       "slurm 2 jobs": ("--cluster", "slurm", "--jobs", "2")}
            run(*configs["local 1w"])  # warm-up (imports, page cache)
            walls: dict[str, list[float]] = {k: [] for k in configs}
            cpus: dict[str, list[float]] = {k: [] for k in configs}
            for _ in range(args.repeats):  # interleaved, so a change of load falls on every configuration alike
                for name, extra in configs.items():
                    w, c = run(*extra)
                    walls[name].append(w)
                    cpus[name].append(c)
        finally:
            left = node.stop()
    print(f"workload: {n_runs} runs ({len(walks)} synthetic walks 320x200, 20 steps x 2 methods, built-in VO); "
          f"{args.repeats} timed runs per configuration, medians")
    med = {k: statistics.median(v) for k, v in walls.items()}
    for k in walls:
        print(f"{k:13s} wall {med[k]:7.2f} s ({', '.join(f'{x:.1f}' for x in walls[k])})  "
              f"{60 * n_runs / med[k]:6.1f} runs/min  CPU {statistics.median(cpus[k]):5.2f} s/run (SLAM + metrics)")
    print(f"efficiency of the 2nd worker: local {med['local 1w'] / (2 * med['local 2w']):.2f}, "
          f"slurm {med['slurm 1 job'] / (2 * med['slurm 2 jobs']):.2f} (goal >= 0.8)")
    print(f"cluster path cost: slurm 1 job / local 1 worker = {med['slurm 1 job'] / med['local 1w']:.2f}x "
          f"(+{med['slurm 1 job'] - med['local 1w']:.1f} s: job start, scheduler, per-unit transfer)")
    print(f"1-min load average during the runs: {min(loads):.1f}..{max(loads):.1f} on {os.cpu_count()} CPUs")
    if left:
        print(f"warning: processes left in the Slurm namespace (killed): {left}")


if __name__ == "__main__":
    main()
