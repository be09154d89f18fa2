"""The demo pipeline: record on the simulated backpack, verify, export, benchmark every AE method, report.

Steps (each prints progress, each output kept under ``out_dir``):

1. ``rig/``: ``bracketry simulate`` — two fake GigE cameras serving the synthetic forest (Aravis, loopback, private
   network namespace), the trigger simulator, the panel firmware on the host and the daemon under test, driven by
   SENSORS/RECORD presses; the recording is verified.
2. ``dataset/``: the recording exported as a BorealHDR tree (16-bit PNG per camera and exposure, left and right
   sharing their trigger's timestamp) with the world's calibration and ground-truth poses.
3. ``suite/`` (default plan): the demo-size synthetic suite (``bracketry synth suite --size demo --seed 0``: short
   walks in the subsets forest, sun-shadow, glare, day-cycle, where the exposure decides), linked from the user
   cache when rendered before. It renders beside steps 1-2 at the lowest priority (``nice -n 19``, log
   ``suite.log``): the real-time recording leaves most of a core idle, and the rig keeps its priority.
4. ``benchmark/``: every paper AE method (DRL when ``--drl-weights`` / ``BRACKETRY_DRL_WEIGHTS`` names its weights) in
   closed loop on the emulated images of the recording (subset ``rig``) and the suite, fed to stereo SLAM as raw frames,
   three runs at a time (no emulated PNG is written), RTE/RRE, failures, statistics against AE50 over all those
   trajectories, report (Markdown, HTML, CSV, plots, and where the time went).
"""

from __future__ import annotations

import csv
import json
import math
import os
import shutil
import subprocess
import sys
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, BinaryIO

from bracketry_base.errors import BracketryError
from bracketry_base.progress import Progress
from bracketry_emulator.defaults import DEFAULT_SLAM_PACE


@dataclass(frozen=True)
class DemoPlan:
    """What the demo runs. ``seconds`` recorded at ``fps`` with ``resolution`` (width, height) cameras."""

    out_dir: Path
    seconds: float
    resolution: tuple[int, int]
    fps: float = 22.0
    workers: int = 2
    #: AE methods: "all" or a comma-separated list of ids (built-ins, plugins ``pkg.module:Class``, entry points)
    methods: str = "all"
    #: the methods in the statistics: "paper", "all" or a comma-separated list of names
    stats_methods: str = "paper"
    #: AE plugins' constructor arguments: {method: {keyword: value}}
    method_options: dict[str, dict[str, Any]] = field(default_factory=dict)
    #: the DRL actor's .pth; None leaves DRL out (its public weights are not shipped)
    drl_weights: str | None = None
    #: localisation: "orbslam3" (ORB-SLAM3 stereo) or "builtin" (the built-in VO)
    slam: str = "orbslam3"
    #: ORB-SLAM3 feed: "lockstep" (each frame once that run's mapping threads are idle, so its results do not move
    #: with the load; the default of every command, declared once in bracketry_emulator/option_table.py; see
    #: :mod:`bracketry_emulator.slam.quiescence`), seconds between frames (0 = as fast as it tracks) or "realtime"
    #: (the recording's timestamps: it does not hold on a 2-core machine with seven runs at once)
    slam_pace: str | float = DEFAULT_SLAM_PACE
    #: the synthetic suite benchmarked with the recording: a size of ``bracketry synth suite`` ("demo"), or None
    suite: str | None = None
    #: the suite's seed
    suite_seed: int = 0


#: The demo's dataset PNGs are stored (deflate without compression): 0.34 vs 5.7 ms an image to write at 640x400
#: (the export took ~9 s of the default demo with OpenCV's encoder) and faster to decode, for ~1.4x the disk
#: (~0.9 GB for 40 s).
DEMO_PNG_COMPRESSION = "stored"


#: 12 s: longer than the suite's 10-s walks, and with the demo-size suite beside it the demo stays within its 4
#: minutes on 2 cores (a 640x400 recording's seven lockstep ORB-SLAM3 runs cost about 4.5 times a suite walk's at
#: 20 s: 30 % of the demo's SLAM; docs/RESULTS.md)
DEFAULT_SECONDS = 12.0
#: 10 s: the simulated walk (~0.58 m/s) covers ~5.8 m, safely more than the shortest RTE window (5 m, pairs from
#: 4.5 m); 8 s (~4.7 m) left RTE/RRE to chance.
QUICK_SECONDS = 10.0
#: the suite the default plan benchmarks with the recording (with one trajectory the statistics cannot separate any
#: two methods; the suite's trajectories, paired across methods, can)
DEMO_SUITE = "demo"
#: the name and subset of the rig's own recording among the benchmark's trajectories
RIG_TRAJECTORY, RIG_SUBSET = "simulated_forest", "rig"
DEFAULT_RESOLUTION = (640, 400)
QUICK_RESOLUTION = (320, 200)


def plan(out_dir: Path, seconds: float | None, quick: bool, drl_weights: str | None = None,
         slam: str | None = None, slam_pace: str | float | None = None, methods: str = "all",
         stats_methods: str = "paper", method_options: dict[str, dict[str, Any]] | None = None,
         suite: bool | None = None) -> DemoPlan:
    """The default plan (a SLAM run long enough to mean something, and the demo-size suite beside the recording), or
    the quick one for CI (< 2 minutes: the recording alone). ``suite``: True/False overrides the plan's choice.

    SLAM: ORB-SLAM3 by default; the quick plan uses the built-in VO unless ``slam`` says otherwise (its 320x200
    images leave ORB-SLAM3 a 7-level pyramid, and the first ORB-SLAM3 run on a machine builds the vocabulary,
    about half a minute of a 2-minute budget).
    ``methods``, ``stats_methods``, ``method_options``: as ``bracketry benchmark``'s options.
    """
    chosen: dict[str, Any] = {"methods": methods, "stats_methods": stats_methods,
                              "method_options": dict(method_options or {})}
    if quick:
        return DemoPlan(out_dir, seconds or QUICK_SECONDS, QUICK_RESOLUTION, drl_weights=drl_weights,
                        slam=slam or "builtin", slam_pace=DEFAULT_SLAM_PACE if slam_pace is None else slam_pace,
                        suite=DEMO_SUITE if suite else None, **chosen)
    return DemoPlan(out_dir, seconds or DEFAULT_SECONDS, DEFAULT_RESOLUTION, drl_weights=drl_weights,
                    slam=slam or "orbslam3", slam_pace=DEFAULT_SLAM_PACE if slam_pace is None else slam_pace,
                    suite=None if suite is False else DEMO_SUITE, **chosen)


def _steps(p: DemoPlan) -> int:
    """The demo's steps: record, export, (render the suite,) benchmark."""
    return 3 if p.suite is None else 4


def check_methods(p: DemoPlan) -> list[str]:
    """The names of the plan's methods, checked as the benchmark checks them (unknown ids, plugins that do not
    load or reject an option, unsafe or shared names, --stats-methods): one line before anything is recorded."""
    from bracketry_emulator.ae.registry import resolve_methods
    from bracketry_emulator.benchmark.orchestrate import select_stats_methods

    names = [m.name for m in resolve_methods(p.methods, p.method_options, drl_weights=p.drl_weights)]
    if "ae50" not in names:
        raise BracketryError("the demo's statistics compare with ae50: keep it in --methods")
    select_stats_methods(p.stats_methods, names, "ae50", plugins=[])
    return names


def record(p: DemoPlan, echo: Callable[[str], None]) -> dict[str, Any]:
    """Step 1: the simulated rig records ``p.seconds``; returns its summary (``simulation.json``)."""
    rig_dir = p.out_dir / "rig"
    if rig_dir.exists():
        shutil.rmtree(rig_dir)
    w, h = p.resolution
    # Real-time-ish priority for the simulated devices when we may (root): a starved fake camera misses triggers.
    prio = ["nice", "-n", "-10"] if os.geteuid() == 0 and shutil.which("nice") else []
    cmd = [*prio, sys.executable, "-m", "bracketry", "simulate", "--duration-s", f"{p.seconds:g}", "--out",
           str(rig_dir), "--overwrite", "--resolution", f"{w}x{h}", "--fps", f"{p.fps:g}", "--render-ahead"]
    echo(f"[1/{_steps(p)}] recording {p.seconds:g} s on the simulated backpack ({w}x{h}, {p.fps:g} fps): "
         f"bracketry {' '.join(cmd[len(prio) + 3:])}")
    log_path = p.out_dir / "simulate.log"
    with open(log_path, "wb") as log:
        proc = subprocess.Popen(cmd, stdin=subprocess.DEVNULL, stdout=subprocess.PIPE, stderr=subprocess.STDOUT)
        _tee(proc, log)
        rc = proc.wait()
    summary_path = rig_dir / "simulation.json"
    if not summary_path.is_file():
        tail = log_path.read_text()[-800:]
        raise BracketryError(f"the simulated rig failed (exit {rc}); see {log_path}: ...{tail.strip()[-300:]}")
    summary = json.loads(summary_path.read_text())
    summary["exit_code"] = rc
    return summary


def _tee(proc: subprocess.Popen[bytes], log: BinaryIO) -> None:
    """Copy the child's output to ``log`` and, live, to our stderr (its render bar, devices, panel screens)."""
    assert proc.stdout is not None
    err = getattr(sys.stderr, "buffer", None)
    fd = proc.stdout.fileno()
    while chunk := os.read(fd, 65536):
        log.write(chunk)
        if err is not None:
            err.write(chunk)
            err.flush()
        else:
            sys.stderr.write(chunk.decode(errors="replace"))


def export_dataset(p: DemoPlan, sim: dict[str, Any], echo: Callable[[str], None]) -> Path:
    """Step 2: export each recorded segment into one BorealHDR tree with calibration and ground truth."""
    from bracketry_rig.export.borealhdr import export_borealhdr

    ds = p.out_dir / "dataset" / "simulated_forest"
    if ds.exists():
        shutil.rmtree(ds)
    ds.mkdir(parents=True)
    echo(f"[2/{_steps(p)}] exporting the recording to a BorealHDR tree: {ds}")
    for seg in sim["recordings"]:
        export_borealhdr(seg, ds, workers=p.workers, progress=False, png_compression=DEMO_PNG_COMPRESSION)
    rig_dir = p.out_dir / "rig"
    shutil.copytree(rig_dir / "calibration", ds / "calibration")
    for name in ("groundtruth.txt", "groundtruth_unknown.txt"):  # the second lists frames without a known pose
        if (rig_dir / name).is_file():
            shutil.copy2(rig_dir / name, ds / name)
    return ds


#: the suite's render beside the recording runs at this niceness (the lowest priority: the rig's devices and
#: renderer, at 0 or -10, keep the cores they need)
BACKGROUND_NICE = 19


def start_suite(p: DemoPlan) -> subprocess.Popen[bytes] | None:
    """Start rendering the plan's suite in the background (``bracketry synth suite ... --overwrite -q`` under
    ``nice -n 19``, output in ``out_dir/suite.log``), to run beside the recording and the export; None without a
    suite in the plan. :func:`suite` waits for it and checks what it made."""
    if p.suite is None:
        return None
    p.out_dir.mkdir(parents=True, exist_ok=True)
    prio = ["nice", "-n", str(BACKGROUND_NICE)] if shutil.which("nice") else []
    cmd = [*prio, sys.executable, "-m", "bracketry", "synth", "suite", "--out", str(p.out_dir / "suite"), "--size",
           p.suite, "--seed", str(p.suite_seed), "--overwrite", "--workers", str(p.workers), "-q"]
    with open(p.out_dir / "suite.log", "wb") as log:
        return subprocess.Popen(cmd, stdin=subprocess.DEVNULL, stdout=log, stderr=subprocess.STDOUT)


def stop_suite(proc: subprocess.Popen[bytes] | None) -> None:
    """End a background suite render that is still running (the demo failed before step 3)."""
    if proc is not None and proc.poll() is None:
        proc.terminate()
        try:
            proc.wait(timeout=30)
        except subprocess.TimeoutExpired:
            proc.kill()
            proc.wait()


def suite(p: DemoPlan, echo: Callable[[str], None], background: subprocess.Popen[bytes] | None = None
          ) -> Path | None:
    """Step 3 of the default plan: the demo-size synthetic suite under ``out_dir/suite`` (linked from the user cache
    when rendered before); returns its manifest (None without a suite in the plan). ``background``: its render
    started by :func:`start_suite`, waited for here; whatever it did not make is made here, with a progress bar."""
    if p.suite is None:
        return None
    from bracketry_emulator.synth.suite import make_suite

    out = p.out_dir / "suite"
    echo(f"[3/4] synthetic suite ({p.suite}, seed {p.suite_seed}): trajectories where the exposure decides")
    if background is not None:
        if background.poll() is None:
            echo(f"      waiting for its render, started beside the recording ({p.out_dir / 'suite.log'})")
        rc = background.wait()
        if rc != 0:
            echo(f"      the render beside the recording failed (exit {rc}, see {p.out_dir / 'suite.log'}): again here")
    bar: Any = None

    def progress(done: int, total: int) -> None:
        nonlocal bar
        if bar is None:
            bar = Progress("render suite", total=total, unit="trajectory")
        bar.update(1)

    try:
        _id, how = make_suite(out, p.suite, p.suite_seed, overwrite=True, workers=p.workers, progress=progress)
    finally:
        if bar is not None:
            bar.close()
    if background is not None and background.returncode == 0 and how == "reused":
        how = "made beside the recording"
    echo(f"      suite {how} ({out})")
    return out / "manifest.yaml"


def benchmark(p: DemoPlan, dataset: Path, echo: Callable[[str], None], suite_manifest: Path | None = None) -> Any:
    """The last step: all AE methods in closed loop (one shared-decode pass per trajectory, with a progress bar), VO,
    metrics, statistics and the report, on the recording (and the suite's trajectories when given)."""
    from bracketry_emulator.benchmark.orchestrate import BenchmarkConfig, run_benchmark
    from bracketry_emulator.benchmark.slam import slam_options
    from bracketry_emulator.metrics.manifest import TrajectorySpec, load_manifest

    methods = check_methods(p)  # their names
    slam = slam_options(p.slam, pace=p.slam_pace, echo=echo)  # the default vocabulary is built here the first time
    out = p.out_dir / "benchmark"
    if out.exists():  # a new recording: earlier runs and cached results belong to the old one
        shutil.rmtree(out)
    datasets = [TrajectorySpec(RIG_TRAJECTORY, dataset.resolve(), RIG_SUBSET if suite_manifest is not None else "all")]
    if suite_manifest is not None:
        datasets += load_manifest(suite_manifest)
    where = f" on the recording and {len(datasets) - 1} suite trajectories" if suite_manifest is not None else ""
    n = _steps(p)
    slam_name = "ORB-SLAM3" if p.slam == "orbslam3" else "the built-in VO"
    echo(f"[{n}/{n}] benchmarking {len(methods)} AE methods ({', '.join(methods)}){where}: closed loops (each "
         f"bracket decoded once for all) spooling raw frames for {slam_name} (one process per method, "
         f"{p.workers + 1} at a time, no PNG round trip), then metrics per method")
    bar: Any = None

    def done(r: Any) -> None:  # a RunResult
        nonlocal bar
        if bar is None:  # after the closed loops' own bar
            bar = Progress("SLAM + metrics", total=len(methods) * len(datasets), unit="run")
        bar.set_postfix(r.method)
        bar.update(1)

    try:
        return run_benchmark(BenchmarkConfig(datasets, p.methods, out, reference="ae50", workers=p.workers,
                                             drl_weights=p.drl_weights, progress=True, slam=slam,
                                             stats_methods=p.stats_methods, method_options=p.method_options),
                             on_done=done)
    finally:
        if bar is not None:
            bar.close()
        from bracketry_emulator.slam.launcher import close_shared_launcher

        close_shared_launcher()  # its SLAM runs' CPU time reaches cpu_s() when it is reaped


def best_per_metric(summary_csv: Path) -> dict[str, tuple[str, str]]:
    """From the report's summary.csv: metric -> (best method, its value)."""
    with open(summary_csv, newline="") as f:
        rows = list(csv.reader(f))
    header, body = rows[0], rows[1:]
    wanted = {"RTE (%)": min, "RRE (deg/m)": min, "coverage median (%)": max, "matches median": max,
              "time before failure median (s)": max}
    out: dict[str, tuple[str, str]] = {}
    for col, pick in wanted.items():
        if col not in header:
            continue
        i = header.index(col)
        vals = []
        for row in body:
            try:
                v = float(row[i])
            except ValueError:
                continue
            if math.isfinite(v):
                vals.append((v, row[0], row[i]))
        if vals:
            best = pick(vals, key=lambda t: t[0])
            out[col] = (best[1], best[2])
    return out


def cpu_s() -> float:
    """CPU seconds (user + system) of this process and of every child process it (or they) waited for: the
    simulated rig, the closed loops' workers, the SLAM runs."""
    import resource

    own, children = resource.getrusage(resource.RUSAGE_SELF), resource.getrusage(resource.RUSAGE_CHILDREN)
    return own.ru_utime + own.ru_stime + children.ru_utime + children.ru_stime


def run(p: DemoPlan, echo: Callable[[str], None]) -> dict[str, Any]:
    """The whole demo; returns the summary written to ``out_dir/demo_summary.json``."""
    t0, cpu0 = time.monotonic(), cpu_s()
    p.out_dir.mkdir(parents=True, exist_ok=True)
    background = start_suite(p)  # beside the recording and the export, at the lowest priority
    try:
        return _run(p, echo, t0, cpu0, background)
    finally:
        stop_suite(background)


def _run(p: DemoPlan, echo: Callable[[str], None], t0: float, cpu0: float,
         background: subprocess.Popen[bytes] | None) -> dict[str, Any]:
    sim = record(p, echo)
    verify = sim.get("verify", [])
    frames = {s: sum(v["sides"].get(s, {}).get("frames", 0) for v in verify) for s in ("left", "right")}
    drops = {s: sum(v["sides"].get(s, {}).get("drops", 0) for v in verify) for s in ("left", "right")}
    echo(f"      recorded {sim['session']['recorded_s']} s: frames {frames}, drops {drops}, "
         f"{'verified clean' if sim['ok'] else 'verify found problems'}")
    gt = sim.get("groundtruth")
    unknown = int(gt.get("unknown", 0)) if isinstance(gt, dict) else 0
    if unknown:
        echo(f"      {unknown} recorded frames have no known pose (no rendered-frame identity, or a stereo pair of two "
             "rendered frames): left out of RTE/RRE, which are refused when that is more than 5 % of a run's frames")
    held = int(sim.get("frames_held_for_renderer") or 0)
    if held:
        echo(f"      WARNING: the frame renderer fell behind the cameras on this loaded machine: {held} recorded "
             "frames repeat an earlier rendered cycle (the world held); poses stay right, but the walk and so the "
             "figures below are NOT those of an idle run")
    t_rec, cpu_rec = time.monotonic() - t0, cpu_s() - cpu0
    dataset = export_dataset(p, sim, echo)
    t_export, cpu_export = time.monotonic() - t0 - t_rec, cpu_s() - cpu0 - cpu_rec
    suite_manifest = suite(p, echo, background)
    t_suite, cpu_suite = (time.monotonic() - t0 - t_rec - t_export, cpu_s() - cpu0 - cpu_rec - cpu_export)
    result = benchmark(p, dataset, echo, suite_manifest)
    t_bench = time.monotonic() - t0 - t_rec - t_export - t_suite
    cpu_bench = cpu_s() - cpu0 - cpu_rec - cpu_export - cpu_suite
    best = best_per_metric(result.report_files["summary.csv"]) if "summary.csv" in result.report_files else {}
    summary = {"out_dir": str(p.out_dir), "seconds": p.seconds, "resolution": list(p.resolution),
               "frames": frames, "drops": drops, "recording_verified": bool(sim["ok"]),
               "frames_without_pose": unknown, "frames_held_for_renderer": held,
               "recordings": sim["recordings"], "dataset": str(dataset),
               "methods": sorted({r["method"] for r in result.results}),
               "best": {k: {"method": v[0], "value": v[1]} for k, v in best.items()},
               "report": {k: str(v) for k, v in result.report_files.items()},
               "suite": str(suite_manifest) if suite_manifest is not None else None,
               "trajectories": len({r["trajectory"] for r in result.results}),
               "timing_s": {"record": round(t_rec, 1), "export": round(t_export, 1), "suite": round(t_suite, 1),
                            "benchmark": round(t_bench, 1), "total": round(time.monotonic() - t0, 1)},
               "cpu_s": {"record": round(cpu_rec, 1), "export": round(cpu_export, 1), "suite": round(cpu_suite, 1),
                         "benchmark": round(cpu_bench, 1), "total": round(cpu_s() - cpu0, 1)},
               "load_average": [round(x, 2) for x in os.getloadavg()]}
    (p.out_dir / "demo_summary.json").write_text(json.dumps(summary, indent=2))
    return summary
