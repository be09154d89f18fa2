"""Cost of the full suite's benchmark per task (#28 item 6), measured on a sample and projected to the whole suite.

Usage: nice -n 10 .venv/bin/python benchmarks/bench_full_task.py [--sample-s 6,12] [--methods fix,ae30,...]
       [--work DIR] [--json FILE]

A task is one (trajectory, method) run of ``bracketry benchmark SUITE/manifest.yaml --slam orbslam3`` on the full
suite (``bracketry synth suite --size full``: 24 walks of 60 s at 640x400, 6 brackets at 22 fps): the closed loop
emulating the method's images, ORB-SLAM3 stereo on them (paced in real time, the default) and the metrics. Sample: ONE
full-size trajectory (the suite's first entry, ``forest_canopy_a``, at the full size's resolution and detail)
shortened to two lengths (``--sample-s``, default 6 and 12 s), each rendered once (its render time is measured too)
and benchmarked as the suite is (a one-entry manifest with the suite's ``warmup_steps``, the default 5-50 m windows)
with the full suite's seven methods, the whole command timed (wall, and CPU of every process it started). The stages
come from the benchmark's own records (``OUT/report/stages.json``: per trajectory;
``OUT/cache/<trajectory>/<method>.json``: per run); CPU seconds are the figure to compare on a shared machine (wall
carries the other users' load). The two lengths give each cost as a fixed part + a part per second of walk (a line
through the two points), projected to the full suite's 24 x 60 s x 7 methods (the paper's without DRL; 1 SLAM repeat):
here (``--cores``) and on a cluster (nodes of ``--job-cores`` cores, one trajectory per job, as docs/CLUSTER.md).

The projection takes a trajectory's time as the larger of its CPU seconds over the cores it gets and its walk's
duration (paced runs last the walk whatever the CPU); here the benchmark's default, one worker per CPU, runs one
trajectory per core; CPU the stages do not record (the closed loop's feeding) is the whole command's CPU less its
tasks', per second of walk, and its fixed part (imports, vocabulary and set-up checks, report) counts once.
"""

from __future__ import annotations

import os

for _var in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ[_var] = "1"

import argparse  # noqa: E402
import datetime  # noqa: E402
import json  # noqa: E402
import math  # noqa: E402
import resource  # noqa: E402
import statistics  # noqa: E402
import subprocess  # noqa: E402
import sys  # noqa: E402
import tempfile  # noqa: E402
import time  # noqa: E402
from pathlib import Path  # noqa: E402

import yaml  # noqa: E402

from bracketry_emulator.synth.scenario import scenario_from_dict  # noqa: E402
from bracketry_emulator.synth.suite import SIZES, WARMUP_STEPS, entries, entry_scenario_doc  # noqa: E402
from bracketry_emulator.synth.world import world_from_scenario  # noqa: E402
from bracketry_emulator.synth.writer import write_trajectory  # noqa: E402

#: the full suite's benchmark: the paper's seven methods without DRL (no public weights shipped)
FULL_METHODS = ("fix", "ae30", "ae50", "ae70", "shim", "wang", "kim")
#: the full suite's render, measured per subset by benchmarks/bench_suite_render.py (README): minutes on 2 idle cores
RENDER_FULL_MIN_2_CORES = 58.0
#: the cluster path's fixed cost per job (job start + a worker's imports), docs/CLUSTER.md (bench_slurm.py): "~1-3 s
#: on this one-node Slurm" for the start plus the imports; taken as 10 s; queue waits are the site's and not counted
JOB_FIXED_S = 10.0


def _children_cpu_s() -> float:
    ru = resource.getrusage(resource.RUSAGE_CHILDREN)
    return ru.ru_utime + ru.ru_stime


def render_sample(root: Path, sample_s: float) -> tuple[Path, dict]:
    """The suite's first full-size entry shortened to ``sample_s`` under ``root`` with a one-entry manifest;
    returns (manifest path, {entry, walk_s, frames, render CPU s, render wall s})."""
    e = entries("full")[0]
    doc = entry_scenario_doc(e, "full", 0)
    doc["duration_s"] = sample_s
    sc = scenario_from_dict(doc)
    out = root / e.subset / e.name
    c0, t0 = time.process_time(), time.perf_counter()
    world = world_from_scenario(sc, detail=SIZES["full"].detail)
    summary = write_trajectory(world, out, seconds=sc.duration_s, brackets_ms=sc.brackets_ms, fps=sc.fps)
    info = {"entry": e.name, "walk_s": sc.duration_s, "frames": summary["frames"],
            "render_cpu_s": time.process_time() - c0, "render_wall_s": time.perf_counter() - t0}
    manifest = root / "manifest.yaml"
    manifest.write_text(yaml.safe_dump({
        "description": f"bench_full_task sample: {e.name} of the full suite, {sample_s:g} s",
        "warmup_steps": WARMUP_STEPS,
        "trajectories": [{"path": f"{e.subset}/{e.name}", "subset": e.subset, "name": e.name, "split": e.split,
                          "scenario": e.scenario}]}, sort_keys=False))
    return manifest, info


def run_benchmark(manifest: Path, out: Path, methods: str) -> dict:
    """``bracketry benchmark`` on the sample, the whole command timed: {wall_s, cpu_s (all its processes)}."""
    cmd = [sys.executable, "-m", "bracketry", "benchmark", str(manifest), "--out", str(out), "--methods", methods,
           "--slam", "orbslam3", "-q"]
    c0, t0 = _children_cpu_s(), time.perf_counter()
    done = subprocess.run(cmd, capture_output=True, text=True)
    wall, cpu = time.perf_counter() - t0, _children_cpu_s() - c0
    if done.returncode != 0:
        raise SystemExit(f"{' '.join(cmd)} failed: {done.stderr.strip()[-2000:]}")
    return {"wall_s": wall, "cpu_s": cpu}


def _med(xs: list[float]) -> float:
    xs = [x for x in xs if math.isfinite(x)]
    return statistics.median(xs) if xs else math.nan


def read_stages(out: Path) -> dict:
    """Per-trajectory stages (report/stages.json) and per-run stages (cache/<trajectory>/*.json) of one benchmark."""
    doc = json.loads((out / "report" / "stages.json").read_text())
    runs = []
    for f in sorted((out / "cache").glob("*/*.json")):
        r = json.loads(f.read_text())
        if "method" in r and "stages" in r:
            runs.append(r)
    return {"trajectory": doc["stages"], "command_wall_s": doc.get("wall_s"), "slam_late_s": doc.get("slam_late_s"),
            "runs": runs}


def per_task(stages: dict, n_methods: int) -> dict[str, dict[str, float]]:
    """CPU-s and wall s of one task per stage: the per-run stages (slam, metrics) as medians over the runs; the
    stages done once per trajectory for all its methods (decode, emulation) divided by the number of methods; the
    AE methods' own computation (``ae``: wall only, its CPU is not recorded) as the mean over the methods."""
    per_run: dict[str, dict[str, list[float]]] = {}
    for r in stages["runs"]:
        for name, v in r["stages"].items():
            d = per_run.setdefault(name, {"cpu": [], "wall": []})
            d["cpu"].append(float(v.get("cpu_s", math.nan)))
            d["wall"].append(float(v.get("wall_s", math.nan)))
    rows = {name: {"cpu_s": _med(d["cpu"]), "wall_s": _med(d["wall"])} for name, d in per_run.items()}
    traj = stages["trajectory"]
    for name in ("decode", "emulation"):
        if name in traj:
            rows[name] = {"cpu_s": float(traj[name].get("cpu_s", math.nan)) / n_methods,
                          "wall_s": float(traj[name]["wall_s"]) / n_methods}
    ae_wall = [float(v["wall_s"]) for k, v in traj.items() if k.startswith("ae:")]
    rows["ae"] = {"cpu_s": math.nan, "wall_s": sum(ae_wall) / max(1, len(ae_wall))}
    order = ("decode", "emulation", "ae", "slam", "metrics")
    return {k: rows[k] for k in sorted(rows, key=lambda k: order.index(k) if k in order else len(order))}


def task_cpu_s(rows: dict[str, dict[str, float]]) -> float:
    """A task's CPU seconds: its stages' CPU, the AE stage's wall where its CPU is not recorded."""
    return sum(v["cpu_s"] if math.isfinite(v["cpu_s"]) else v["wall_s"] for v in rows.values())


def fit_line(x: tuple[float, float], y: tuple[float, float]) -> tuple[float, float]:
    """(fixed, per unit of x) of the line through two points; the fixed part clipped at 0 (noise)."""
    b = (y[1] - y[0]) / (x[1] - x[0])
    a = y[1] - b * x[1]
    return (a, b) if a >= 0 else (0.0, y[1] / x[1])


def project_s(traj_cpu_s: float, walk_s: float, n_traj: int, cores: int, nodes: int, fixed_s: float) -> float:
    """Seconds for ``n_traj`` trajectories of ``traj_cpu_s`` CPU seconds each on ``nodes`` x ``cores``, one
    trajectory per node at a time, each taking max(its CPU / cores, its walk) (paced runs), + ``fixed_s`` a round."""
    return math.ceil(n_traj / nodes) * (max(traj_cpu_s / cores, walk_s) + fixed_s)


def _cells(pairs: list[tuple[float, float]]) -> str:
    return " | ".join(f"{c:.1f} / {w:.1f}" if math.isfinite(w) else f"{c:.1f}" for c, w in pairs)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--sample-s", default="6,12", help="seconds of the two sample walks (default 6,12)")
    ap.add_argument("--methods", default=",".join(FULL_METHODS), help="methods benchmarked on the samples")
    ap.add_argument("--cores", type=int, default=2, help="cores here (default 2)")
    ap.add_argument("--job-cores", type=int, default=8, help="cores per cluster job (default 8)")
    ap.add_argument("--work", type=Path, default=None, help="keep the samples and benchmarks here (default: temp)")
    ap.add_argument("--json", type=Path, default=None, help="also write the figures here")
    args = ap.parse_args()
    lengths = tuple(float(x) for x in args.sample_s.split(","))
    if len(lengths) != 2 or lengths[0] >= lengths[1]:
        raise SystemExit("--sample-s: two lengths, the shorter first")
    n_methods = len(args.methods.split(","))
    spec = SIZES["full"]
    res = f"{spec.resolution[0]}x{spec.resolution[1]}"
    print(f"{datetime.datetime.now(datetime.UTC):%Y-%m-%d %H:%M} UTC, load average at start: "
          f"{os.getloadavg()[0]:.1f} on {os.cpu_count()} CPUs", flush=True)
    samples = []
    with tempfile.TemporaryDirectory(prefix="bench_full_task_") as tmp:
        root = args.work or Path(tmp)
        for walk in lengths:
            manifest, info = render_sample(root / f"suite_{walk:g}s", walk)
            print(f"sample: {info['entry']} {res}, {walk:g} s walk ({info['frames']} frames per side), rendered in "
                  f"{info['render_cpu_s']:.1f} CPU-s ({info['render_wall_s']:.1f} s wall)", flush=True)
            command = run_benchmark(manifest, root / f"bench_{walk:g}s", args.methods)
            stages = read_stages(root / f"bench_{walk:g}s")
            ok = sum(1 for r in stages["runs"] if r.get("success"))
            print(f"  bracketry benchmark ({len(stages['runs'])} runs, {ok} successful): command wall "
                  f"{command['wall_s']:.1f} s, CPU {command['cpu_s']:.1f} s (all its processes); ORB-SLAM3 behind "
                  f"real time at most {stages['slam_late_s']} s", flush=True)
            rows = per_task(stages, n_methods)
            samples.append({**info, "command": command, "per_task": rows, "task_cpu_s": task_cpu_s(rows)})

    print(f"\nper task (one trajectory x one method; medians over the {n_methods} methods' runs; decode and "
          f"emulation: the trajectory's / {n_methods}; ae: wall, CPU not recorded), {res}:")
    head = " | ".join(f"{w:g} s walk: CPU-s / wall s" for w in lengths)
    print(f"| stage | {head} | CPU-s per s of walk (slope) | fixed CPU-s |")
    print("|---|---|---|---|---|")
    fits = {}
    for name in samples[1]["per_task"]:
        cells = []
        ys = []
        for smp in samples:
            v = smp["per_task"].get(name, {"cpu_s": math.nan, "wall_s": math.nan})
            cpu = v["cpu_s"] if math.isfinite(v["cpu_s"]) else v["wall_s"]
            ys.append(cpu)
            cells.append(f"{v['cpu_s']:.2f} / {v['wall_s']:.2f}")
        a, b = fit_line(lengths, (ys[0], ys[1]))
        fits[name] = (a, b)
        print(f"| {name} | {' | '.join(cells)} | {b:.3f} | {a:.2f} |")
    a_t, b_t = fit_line(lengths, (samples[0]["task_cpu_s"], samples[1]["task_cpu_s"]))
    print(f"| task (sum) | {_cells([(s['task_cpu_s'], math.nan) for s in samples])} | {b_t:.3f} | {a_t:.2f} |")
    a_c, b_c = fit_line(lengths, (samples[0]["command"]["cpu_s"], samples[1]["command"]["cpu_s"]))
    cells = _cells([(s["command"]["cpu_s"], s["command"]["wall_s"]) for s in samples])
    print(f"| whole command (1 trajectory x {n_methods} methods) | {cells} | {b_c:.3f} | {a_c:.1f} |")
    a_r, b_r = fit_line(lengths, (samples[0]["render_cpu_s"], samples[1]["render_cpu_s"]))
    cells = _cells([(s["render_cpu_s"], s["render_wall_s"]) for s in samples])
    print(f"| render (per trajectory, for comparison) | {cells} | {b_r:.3f} | {a_r:.1f} |")

    n_traj, walk_full, n_full = len(entries("full")), spec.duration_s, len(FULL_METHODS)
    task_full = a_t + b_t * walk_full
    loop_rest_per_s = max(0.0, b_c - n_methods * b_t)  # the trajectory's unrecorded share (closed loop, feeding)
    command_fixed = max(0.0, a_c - n_methods * a_t)  # imports, vocabulary and set-up checks, report
    traj_cpu = n_full * task_full + loop_rest_per_s * walk_full
    total_cpu = n_traj * traj_cpu + command_fixed
    print(f"\nfull suite ({n_traj} walks x {walk_full:g} s x {n_full} methods = {n_traj * n_full} tasks, 1 SLAM "
          f"repeat): {task_full:.1f} CPU-s per task, {traj_cpu:.0f} CPU-s per trajectory (+ {loop_rest_per_s:.3f} "
          f"CPU-s per s of walk not in the stages), {command_fixed:.0f} CPU-s once: {total_cpu / 3600:.2f} CPU-h")
    projections = {}
    for label, nodes, cores, fixed in ((f"here, {args.cores} cores", args.cores, 1, 0.0),
                                       (f"cluster, 10 jobs x {args.job_cores} cores", 10, args.job_cores, JOB_FIXED_S),
                                       (f"cluster, {n_traj} jobs x {args.job_cores} cores", n_traj, args.job_cores,
                                        JOB_FIXED_S)):
        t = project_s(traj_cpu, walk_full, n_traj, cores, nodes, fixed) + command_fixed / cores
        projections[label] = t
        print(f"  {label:28s} {t / 60:6.1f} min")
    render_min = (n_traj * (a_r + b_r * walk_full)) / args.cores / 60
    print(f"render of the full suite from these samples: {render_min:.0f} min on {args.cores} idle cores "
          f"(bench_suite_render.py: {RENDER_FULL_MIN_2_CORES:.0f} min); load average at end: {os.getloadavg()[0]:.1f}")
    if args.json is not None:
        args.json.write_text(json.dumps({"samples": samples, "fits": fits, "task_cpu_s_full": task_full,
                                         "trajectory_cpu_s_full": traj_cpu, "command_fixed_cpu_s": command_fixed,
                                         "total_cpu_s": total_cpu, "projections_s": projections,
                                         "render_full_min": render_min}, indent=2) + "\n")


if __name__ == "__main__":
    main()
