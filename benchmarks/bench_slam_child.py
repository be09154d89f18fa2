"""Benchmark: where one demo-size SLAM run's CPU goes, and a run started as ``python -m`` vs forked by the fork server.

``make demo`` runs ORB-SLAM3 105 times (15 trajectories x 7 methods), each on ~11 stereo frames at 320x200, each in
a child process of its own. This script times, on the same kind of run (a toy corridor of ``--frames`` stereo frames
at 320x200, unpaced, the default vocabulary, one OpenCV/BLAS thread as in the benchmark):

* the parts of one run: Python's start + the child's imports (a process that only imports them), the vocabulary
  load (``pyorbslam3.Slam(...)``: ORB-SLAM3 parses the DBoW2 text file), the whole run;
* a run started as ``python -m bracketry_emulator.slam.orbslam3_child`` (before) vs forked by
  :mod:`bracketry_emulator.slam.launcher` (after), interleaved, CPU seconds of the child (all its threads) and wall;
* that both give the same result bit for bit where the backend is deterministic (the built-in VO's frames.csv and
  trajectories; ORB-SLAM3's own threads make two of its runs differ either way).

Medians and ratios side by side; the demo's saving projected from them (x 105 runs).

    .venv/bin/python benchmarks/bench_slam_child.py [--reps 7] [--frames 11]
"""

from __future__ import annotations

import argparse
import os
import resource
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

DEMO_RUNS = 105

IMPORTS = "from bracketry_emulator.slam.orbslam3_child import preload; preload()"
VOC_LOAD = """
import sys, time, pyorbslam3
c0 = time.process_time()
s = pyorbslam3.Slam(sys.argv[1], sys.argv[2], pyorbslam3.Sensor.STEREO)
print(time.process_time() - c0, file=sys.stderr, flush=True)
import os; os._exit(0)
"""


def child_env() -> dict[str, str]:
    return dict(os.environ, OMP_NUM_THREADS="1", OPENBLAS_NUM_THREADS="1")


def children_cpu_s() -> float:
    u = resource.getrusage(resource.RUSAGE_CHILDREN)
    return u.ru_utime + u.ru_stime


def cpu_of(cmd: list[str]) -> tuple[float, float, str]:
    """(CPU s of the process, wall s, its stderr)."""
    c0, t0 = children_cpu_s(), time.perf_counter()
    p = subprocess.run(cmd, env=child_env(), capture_output=True, text=True, check=True)
    return children_cpu_s() - c0, time.perf_counter() - t0, p.stderr


def make_run(root: Path, frames: int) -> tuple[Path, Path]:
    from bracketry_emulator.benchmark.toyworld import ToyWorld

    w = ToyWorld(width_px=320, height_px=200, fx_px=190.0)
    cal = w.write_calibration(root)
    w.write_run(root, "ae50", frames)
    return root / "ae50", cal


def output_bytes(out: Path) -> bytes:
    """frames.csv and the trajectories of one run's folder, concatenated in name order (empty: none written)."""
    names = sorted(p.name for p in out.iterdir() if p.name == "frames.csv" or p.name.startswith("CameraTrajectory"))
    return b"".join(n.encode() + (out / n).read_bytes() for n in names)


def same_files(a: Path, b: Path) -> bool:
    """Both runs wrote frames.csv / trajectories, byte for byte the same."""
    return bool(output_bytes(a)) and output_bytes(a) == output_bytes(b)


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--reps", type=int, default=7, help="runs of each kind (interleaved)")
    ap.add_argument("--frames", type=int, default=11, help="stereo frames per run (the demo suite's: ~11)")
    args = ap.parse_args()

    from bracketry_emulator.runtime_policy import apply_profile

    apply_profile("timing")
    from bracketry_emulator.slam.launcher import SlamLauncher
    from bracketry_emulator.slam.orbslam3 import OrbSlam3Options, orbslam3_request, start_child, wait_child
    from bracketry_emulator.slam.vocabulary_files import resolve_vocabulary

    voc = str(resolve_vocabulary(None, echo=print))
    loads = [os.getloadavg()[0]]
    with tempfile.TemporaryDirectory(prefix="bench_slam_child_") as tmp:
        root = Path(tmp)
        run_dir, cal = make_run(root / "traj", args.frames)
        opts = OrbSlam3Options(voc, pace_s=0.0)
        c0, t0 = children_cpu_s(), time.perf_counter()
        launcher = SlamLauncher()
        server = (children_cpu_s() - c0, time.perf_counter() - t0)  # not reaped yet: wall only is exact
        rows: dict[str, list[tuple[float, float]]] = {k: [] for k in ("imports", "vocabulary", "started", "forked")}
        vload: list[float] = []
        identical = []
        k = 0
        try:
            for rep in range(args.reps):
                cpu, wall, _ = cpu_of([sys.executable, "-c", IMPORTS])
                rows["imports"].append((cpu, wall))
                for kind in ("started", "forked") if rep % 2 == 0 else ("forked", "started"):
                    out = root / f"out{k}"
                    k += 1
                    req = orbslam3_request(run_dir, cal, opts)
                    info = wait_child(start_child(req, out, launcher=launcher if kind == "forked" else None))
                    rows[kind].append((float(info["cpu_s"]), float(info["wall_s"])))
                    vload.append(float(info["vocabulary_load_s"]))
                settings = next(iter(root.glob("out*/settings.yaml")), None)  # what the runs gave ORB-SLAM3
                if settings is not None:
                    cpu, wall, err = cpu_of([sys.executable, "-c", VOC_LOAD, voc, str(settings)])
                    rows["vocabulary"].append((float(err.strip().splitlines()[-1]), wall))
                loads.append(os.getloadavg()[0])
            for rep in range(2):  # the built-in VO: deterministic, so both ways must give the same bytes
                outs = []
                for kind in ("started", "forked"):
                    out = root / f"vo_{kind}{rep}"
                    req = {"backend": "builtin", "run_dir": str(run_dir), "frames_fifo": None, "fps": None,
                           "calibration_dir": str(cal), "max_frames": None}
                    wait_child(start_child(req, out, launcher=launcher if kind == "forked" else None))
                    outs.append(out)
                identical.append(same_files(*outs))
        finally:
            launcher.close()

    med = {k: (statistics.median(c for c, _ in v), statistics.median(w for _, w in v)) for k, v in rows.items() if v}
    print(f"workload: one ORB-SLAM3 stereo run of {args.frames} frames at 320x200 (toy corridor, unpaced, vocabulary "
          f"{Path(voc).name}), {args.reps} of each kind, interleaved")
    print(f"{'part':44s} {'CPU s (median)':>14s} {'wall s':>8s}   runs' CPU s")
    names = {"imports": "Python start + the child's imports", "vocabulary": "vocabulary load (pyorbslam3.Slam)",
             "started": "whole run, started as python -m (before)", "forked": "whole run, forked by the server (after)"}
    for key, label in names.items():
        if key in med:
            print(f"{label:44s} {med[key][0]:14.3f} {med[key][1]:8.3f}   "
                  f"{', '.join(f'{c:.2f}' for c, _ in rows[key])}")
    before, after = med["started"][0], med["forked"][0]
    print(f"per-run CPU after/before: {after / before:.2f} (saves {before - after:.2f} CPU-s a run; the server "
          f"itself: {server[1]:.2f} s wall once per benchmark)")
    print(f"{DEMO_RUNS} runs of this size (the demo's 105, 7 of them longer): {DEMO_RUNS * before:.0f} -> "
          f"{DEMO_RUNS * after:.0f} CPU-s (~{DEMO_RUNS * (before - after) / 2:.0f} s less wall on 2 cores)")
    print(f"vocabulary load inside the runs (wall, median): {statistics.median(vload):.2f} s")
    print(f"built-in VO, started vs forked: frames.csv and trajectories identical in {sum(identical)}/"
          f"{len(identical)} pairs")
    print(f"1-min load average during the runs: {min(loads):.1f}..{max(loads):.1f} on {os.cpu_count()} CPUs")


if __name__ == "__main__":
    main()
