"""Benchmark: what the lockstep feed of ORB-SLAM3 (``--slam-pace lockstep``, the default) costs against the real-time
feed (``--slam-pace realtime``) on the same run.

Workload: one demo-size SLAM run (a toy corridor of ``--frames`` stereo frames at 320x200, the default vocabulary,
one OpenCV/BLAS thread as in the benchmark), each run a child process of its own started the same way. The feeds
alternate on the same run, ``--reps`` pairs (the first feed of a pair alternates too). Per feed: medians of the
child's wall seconds and CPU seconds (all its threads), their ratio lockstep / realtime side by side, and the
lockstep waits (seconds a run spent waiting for ORB-SLAM3's threads to be idle). Also how many runs of each feed
gave the same ``frames.csv`` and trajectories, byte for byte, as that feed's first run.

    .venv/bin/python benchmarks/bench_slam_pace.py [--reps 5] [--frames 11]
"""

from __future__ import annotations

import argparse
import os
import statistics
import tempfile
from pathlib import Path

from bench_slam_child import make_run, output_bytes

FEEDS = ("lockstep", "realtime")


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--reps", type=int, default=5, help="runs of each feed (interleaved pairs)")
    ap.add_argument("--frames", type=int, default=11, help="stereo frames per run (the demo suite's: ~11)")
    args = ap.parse_args()

    from bracketry_emulator.runtime_policy import apply_profile

    apply_profile("timing")
    from bracketry_emulator.slam.orbslam3 import OrbSlam3Options, run_orbslam3
    from bracketry_emulator.slam.vocabulary_files import resolve_vocabulary

    voc = str(resolve_vocabulary(None, echo=print))
    options = {"lockstep": OrbSlam3Options(voc, lockstep=True, pace_s=0.0),
               "realtime": OrbSlam3Options(voc, pace_s=None)}
    rows: dict[str, list[tuple[float, float]]] = {f: [] for f in FEEDS}
    waits: list[float] = []
    outputs: dict[str, list[bytes]] = {f: [] for f in FEEDS}
    loads = [os.getloadavg()[0]]
    with tempfile.TemporaryDirectory(prefix="bench_slam_pace_") as tmp:
        root = Path(tmp)
        run_dir, cal = make_run(root / "traj", args.frames)
        for rep in range(args.reps):
            for feed in FEEDS if rep % 2 == 0 else FEEDS[::-1]:
                out = root / f"{feed}{rep}"
                info = run_orbslam3(run_dir, cal, out, options[feed])
                rows[feed].append((float(info["wall_s"]), float(info["cpu_s"])))
                if feed == "lockstep":
                    waits.append(float(info["lockstep_wait_s"]))
                outputs[feed].append(output_bytes(out))
            loads.append(os.getloadavg()[0])

    med = {f: (statistics.median(w for w, _ in v), statistics.median(c for _, c in v)) for f, v in rows.items()}
    print(f"workload: one ORB-SLAM3 stereo run of {args.frames} frames at 320x200 (toy corridor, vocabulary "
          f"{Path(voc).name}), {args.reps} runs of each feed, interleaved")
    print(f"{'feed':10s} {'wall s (median)':>16s} {'CPU s (median)':>15s}   runs' wall s / CPU s")
    for f in FEEDS:
        print(f"{f:10s} {med[f][0]:16.2f} {med[f][1]:15.2f}   "
              f"{', '.join(f'{w:.2f}/{c:.2f}' for w, c in rows[f])}")
    print(f"lockstep / realtime: wall {med['lockstep'][0] / med['realtime'][0]:.2f}, "
          f"CPU {med['lockstep'][1] / med['realtime'][1]:.2f}")
    print(f"lockstep waits per run (median): {statistics.median(waits):.2f} s")
    for f in FEEDS:
        same = sum(o == outputs[f][0] for o in outputs[f])
        print(f"{f}: frames.csv and trajectories identical to its first run in {same}/{len(outputs[f])} runs")
    print(f"1-min load average during the runs: {min(loads):.1f}..{max(loads):.1f} on {os.cpu_count()} CPUs")


if __name__ == "__main__":
    main()
