"""Run every (trajectory, method) task locally (process pool) or on a Dask cluster, then statistics and report."""

from __future__ import annotations

import concurrent.futures
import json
import multiprocessing
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from bracketry.errors import BracketryError
from bracketry_emulator.benchmark.emulated_runs import all_methods, loop_config
from bracketry_emulator.benchmark.tasks import make_task, run_task
from bracketry_emulator.metrics.manifest import TrajectorySpec, expand_datasets
from bracketry_emulator.metrics.rpe import DEFAULT_WINDOWS_M


@dataclass
class BenchmarkResult:
    """All task results (sorted by trajectory then method) and where the report went."""

    results: list[dict]
    out_dir: Path
    report_files: dict[str, Path]
    #: where the time went (:func:`stage_document`)
    timing: dict = field(default_factory=dict)


def parse_methods(methods: str | list[str], has_drl_weights: bool = True) -> list[str]:
    """``all`` / ``paper`` (the paper's eight) or a comma-separated list (or a list) -> method ids, order kept,
    duplicates removed.

    Without DRL weights (``has_drl_weights=False``) ``all`` leaves ``drl`` out and an explicit ``drl`` is an error.
    """
    items = methods.split(",") if isinstance(methods, str) else list(methods)
    out: list[str] = []
    for item in (m.strip() for m in items):
        if item == "drl" and not has_drl_weights:
            raise BracketryError("the drl method needs its weights: pass --drl-weights PATH (or set "
                                 "BRACKETRY_DRL_WEIGHTS)")
        expanded = ([m for m in all_methods() if m != "drl" or has_drl_weights] if item in ("all", "paper")
                    else [item])
        for m in expanded:
            if m and m not in out:
                out.append(m)
    if not out:
        raise BracketryError("no AE method given (--methods all or a comma-separated list)")
    return out


def _shared_closed_loops(specs: list[TrajectorySpec], tasks: list[dict], out: Path, drl_weights: str | None,
                         workers: int, progress: bool, loop: dict | None, stages: Any = None) -> None:
    """Per trajectory, the closed loops of every method whose task still needs one, in one shared-decode pass."""
    from bracketry_emulator.benchmark.emulated_runs import emulate_runs
    from bracketry_emulator.benchmark.tasks import load_cached

    for spec in specs:
        todo = list(dict.fromkeys(t["method"] for t in tasks if t["trajectory"] == spec.name
                                  and not t["existing_run"] and load_cached(t) is None))
        if todo:
            emulate_runs(spec.path, todo, out / "runs" / spec.name, drl_weights=drl_weights,
                         workers=max(0, workers), progress=progress, options=loop, stages=stages)


def _run_local(tasks: list[dict], workers: int, on_done: Callable[[dict], None] | None) -> list[dict]:
    from bracketry_emulator.benchmark.tasks import load_cached

    todo = [t for t in tasks if load_cached(t) is None]
    workers = min(workers, len(todo))  # all cached (or one task left): no process pool to start
    if workers <= 1:
        results = []
        for t in tasks:
            r = run_task(t)
            if on_done:
                on_done(r)
            results.append(r)
        return results
    ctx = multiprocessing.get_context("spawn")
    with concurrent.futures.ProcessPoolExecutor(max_workers=workers, mp_context=ctx) as pool:
        futures = [pool.submit(run_task, t) for t in tasks]
        for f in concurrent.futures.as_completed(futures):
            if on_done:
                on_done(f.result())
        return [f.result() for f in futures]


def _run_dask(tasks: list[dict], scheduler: str, on_done: Callable[[dict], None] | None) -> list[dict]:
    try:
        from distributed import Client, as_completed
    except ImportError as exc:
        raise BracketryError("--scheduler needs dask.distributed (install the emulator extra)") from exc
    try:
        client = Client(scheduler, timeout=30)
    except OSError as exc:
        raise BracketryError(f"cannot reach the Dask scheduler {scheduler}: {exc}") from exc
    try:
        futures = client.map(run_task, tasks, pure=False)
        if on_done:
            for f in as_completed(futures):
                on_done(f.result())
        return list(client.gather(futures))
    finally:
        client.close()


def run_benchmark(datasets: Sequence[str | Path | TrajectorySpec], methods: str | list[str], out_dir: str | Path,
                  reference: str = "ae50", scheduler: str | None = None, workers: int = 1,
                  windows_m: tuple[float, ...] = DEFAULT_WINDOWS_M, max_frames: int | None = None,
                  alpha: float = 0.05, report: bool = True, export_orbslam: bool = False,
                  slam_dir: str | Path | None = None, drl_weights: str | Path | None = None,
                  progress: bool = False, loop: dict | None = None,
                  on_done: Callable[[dict], None] | None = None, slam: dict | None = None,
                  slam_echo: Callable[[str], None] | None = None,
                  stats_methods: str | list[str] = "paper", write_images: bool = False,
                  setup_check: bool = True) -> BenchmarkResult:
    """Benchmark ``methods`` on ``datasets`` (folders, manifests or specs) into ``out_dir``.

    ``scheduler``: a Dask scheduler address (``tcp://HOST:PORT``) or None for local processes (``workers``). Locally,
    the closed loops of all methods still to run on a trajectory run first in one pass (each bracket sequence
    decoded once for all methods, ``progress`` shows a bar); with a scheduler each task runs its own closed loop
    on the cluster. ``drl_weights``: the DRL actor (``all`` leaves DRL out without it). ``loop``: closed-loop
    settings (selection, crf, init_exposure_us, seed, ae_camera; see
    :data:`~bracketry_emulator.benchmark.emulated_runs.LOOP_DEFAULTS`), part of every cache key.
    ``export_orbslam`` / ``slam_dir``: see :func:`~bracketry_emulator.benchmark.tasks.make_task`.
    Locally (no scheduler, no ``slam_dir``, no ``export_orbslam``) SLAM gets the emulated images in memory
    (:mod:`~bracketry_emulator.benchmark.stream`: every run of a trajectory is fed by its one closed-loop pass) and
    PNGs are written only with ``write_images``; otherwise the closed loops write PNGs and SLAM reads them.
    Where the time went is in the report's stage table and ``report/stages.json``
    (:mod:`~bracketry_emulator.stages`).
    ``slam``: SLAM options (:func:`~bracketry_emulator.benchmark.slam.slam_options`; None = the built-in VO); with
    ``repeats`` > 1 every (trajectory, method) runs that many times and the results carry the median and spread
    (statistics on the medians). Fed in memory, every run of a trajectory runs at once; on the PNG route paced
    ORB-SLAM3 runs mostly wait, so locally twice ``workers`` of them run at once.
    An unresolved ORB-SLAM3 vocabulary is resolved after the other input was checked (``slam_echo`` says when the
    default vocabulary is being built). ``stats_methods``: the methods the statistics (and their Bonferroni count)
    cover: ``paper`` (default: the benchmarked methods among the paper's eight; ``zhang`` and plugins are reported
    but not tested), ``all`` (every benchmarked method) or a list.
    ``setup_check``: with ORB-SLAM3 and runs still to do, first check that it can track at all with this vocabulary
    and calibration (:mod:`~bracketry_emulator.slam.setup_check`; a failure is one line before any method runs).
    """
    paths = [d for d in datasets if not isinstance(d, TrajectorySpec)]
    specs = [d for d in datasets if isinstance(d, TrajectorySpec)] + (expand_datasets(paths) if paths else [])
    weights = str(drl_weights) if drl_weights else None
    if weights is not None and not Path(weights).is_file():
        raise BracketryError(f"--drl-weights file not found: {weights}")
    method_ids = parse_methods(methods, has_drl_weights=weights is not None)
    from bracketry_emulator.ae.registry import get_method

    builtin = set(all_methods())
    for m in method_ids:  # an unknown id or a broken plugin: one line naming it, before any work
        if m not in builtin and not any(spec.existing_run(m) for spec in specs):
            get_method(m)
    if reference not in method_ids:
        raise BracketryError(f"reference method {reference!r} is not among the benchmarked methods {method_ids}")
    select_stats_methods(stats_methods, method_ids, reference)  # bad names: one line before anything runs
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    slam_path = Path(slam_dir).resolve() if slam_dir else None
    if slam_path is not None and not slam_path.is_dir():
        raise BracketryError(f"--slam-trajectories folder not found: {slam_path}")
    loop_config(loop, None)  # bad settings: one clear line before anything runs
    from bracketry_emulator.benchmark.slam import resolve_options

    slam_opts: dict = resolve_options(dict(slam), echo=slam_echo) if slam else {"backend": "builtin", "repeats": 1}
    repeats = int(slam_opts.get("repeats", 1))
    references = {s.name: _reference(s, out) for s in specs}
    tasks = [make_task(s, m, out, windows_m, max_frames, export_orbslam, slam_path, weights, loop, slam_opts, r,
                       references[s.name]) for s in specs for m in method_ids for r in range(repeats)]
    if setup_check and slam_path is None and slam_opts.get("backend") == "orbslam3":
        _check_setup(specs, tasks, method_ids, references, slam_opts, out, slam_echo)
    from bracketry_emulator.stages import StageTimes

    t_start = time.perf_counter()
    stages = StageTimes()
    paced = slam_opts.get("backend") == "orbslam3" and slam_opts.get("pace") != 0.0
    slam_workers = workers * 2 if paced and workers > 1 else workers
    if scheduler is None and slam_path is None and not export_orbslam:
        streamed = _streamed(specs, tasks, out, weights, workers, progress, loop, write_images, stages, on_done)
        runs = [*streamed, *_run_local([t for t in tasks if t["key"] not in {r["key"] for r in streamed}],
                                       slam_workers, on_done)]
    elif scheduler is None:
        if slam_path is None:
            _shared_closed_loops(specs, tasks, out, weights, workers, progress, loop, stages)
        runs = _run_local(tasks, slam_workers, on_done)
    else:
        runs = _run_dask(tasks, scheduler, on_done)
    for r in runs:  # this invocation's SLAM and metrics seconds (cached results did no work now)
        if not r.get("cached") and r.get("stages"):
            stages.merge(r["stages"])
    results = group_repeats(runs)
    results.sort(key=lambda r: (r["trajectory"], method_ids.index(r["method"])))
    files: dict[str, Path] = {}
    timing = stage_document(stages, results, time.perf_counter() - t_start, len(runs),
                            sum(1 for r in runs if r.get("cached")))
    if report:
        from bracketry_emulator.report import write_report

        with stages.time("report"):
            files = write_report(results, out, reference=reference, methods=method_ids, alpha=alpha, slam=slam_opts,
                                 stats_methods=select_stats_methods(stats_methods, method_ids, reference),
                                 stages=timing)
        timing = {**timing, "stages": stages.as_dict(), "wall_s": round(time.perf_counter() - t_start, 3)}
        files["stages.json"] = out / "report" / "stages.json"
        files["stages.json"].write_text(json.dumps(timing, indent=1) + "\n")
    return BenchmarkResult(results, out, files, timing)


def _check_setup(specs: list[TrajectorySpec], tasks: list[dict], method_ids: list[str],
                 references: dict[str, Path | None], slam_opts: dict, out: Path,
                 echo: Callable[[str], None] | None) -> None:
    """The ORB-SLAM3 set-up check (:func:`~bracketry_emulator.slam.setup_check.check_setup`) when some run is still
    to do; its runs go to ``out/setup_check/``."""
    from bracketry_emulator.benchmark.tasks import load_cached
    from bracketry_emulator.slam.setup_check import Trajectory, check_setup

    if all(load_cached(t) is not None for t in tasks):
        return
    trajectories = [Trajectory(s.name, s.path, s.calibration_dir(),
                               next((r for r in (s.existing_run(m) for m in method_ids) if r is not None), None),
                               references.get(s.name) or s.groundtruth_path()) for s in specs]
    res = check_setup(trajectories, slam_opts["vocabulary"], out / "setup_check")
    if echo and res is not None:
        echo(f"set-up check: ORB-SLAM3 tracked {res.longest_tracked} of {res.n_frames} frames of the {res.what} of "
             f"{res.trajectory} ({res.cpu_s:.1f} CPU s in ORB-SLAM3, {res.wall_s:.1f} s)")


def stage_document(stages: Any, results: list[dict], wall_s: float, n_runs: int, n_cached: int) -> dict:
    """The benchmark's timing: machine, trajectory seconds (per trajectory, the longest run's duration), wall clock,
    runs (and how many came from the cache, which add nothing to the stages) and the stage seconds."""
    import math

    from bracketry_emulator.stages import describe_machine

    per_traj: dict[str, float] = {}
    for r in results:
        d = float(r.get("duration_s", math.nan))
        if math.isfinite(d):
            per_traj[r["trajectory"]] = max(per_traj.get(r["trajectory"], 0.0), d)
    late = [float(r["slam_late_s"]) for r in results if math.isfinite(float(r.get("slam_late_s", math.nan)))]
    return {"machine": describe_machine(), "trajectory_s": round(sum(per_traj.values()), 3),
            "slam_late_s": round(max(late), 3) if late else None,
            "trajectories": per_traj, "wall_s": round(wall_s, 3), "runs": n_runs, "runs_cached": n_cached,
            "stages": stages.as_dict()}


def _streamed(specs: list[TrajectorySpec], tasks: list[dict], out: Path, drl_weights: str | None, workers: int,
              progress: bool, loop: dict | None, write_images: bool, stages: Any,
              on_done: Callable[[dict], None] | None) -> list[dict]:
    """Per trajectory, the tasks still to run (not cached, no existing run) in one in-memory pass (see
    :mod:`~bracketry_emulator.benchmark.stream`); returns their results."""
    from bracketry_emulator.benchmark.stream import stream_trajectory
    from bracketry_emulator.benchmark.tasks import load_cached

    out_results: list[dict] = []
    for spec in specs:
        todo = [t for t in tasks if t["trajectory"] == spec.name and not t["existing_run"]
                and load_cached(t) is None]
        if todo:
            out_results += stream_trajectory(spec, todo, out, drl_weights=drl_weights, workers=workers,
                                             progress=progress, loop=loop, write_images=write_images,
                                             stages=stages, on_done=on_done)
    return out_results


def _reference(spec: TrajectorySpec, out: Path) -> Path | None:
    """A trajectory's ``reference.yaml`` (TUM/KITTI/EuRoC, any sensor frame) as a left-camera TUM file under
    ``out/reference/``; None when it has none (then its ``groundtruth.txt``, if any, is the reference)."""
    from bracketry_emulator.metrics.reference import write_camera_reference

    return write_camera_reference(spec.path, out / "reference" / f"{spec.name}.txt")


def select_stats_methods(which: str | list[str], methods: list[str], reference: str) -> list[str]:
    """The benchmarked methods the statistics cover (see :func:`run_benchmark`), the reference always included."""
    from importlib.metadata import entry_points

    from bracketry_emulator.ae.registry import BUILTIN_METHODS, ENTRY_POINT_GROUP, PAPER_METHODS

    if which == "all":
        chosen = list(methods)
    elif which == "paper":  # leave out the non-paper built-ins (zhang) and plugins; runs named otherwise stay
        extra = {*BUILTIN_METHODS, *(ep.name for ep in entry_points(group=ENTRY_POINT_GROUP))} - set(PAPER_METHODS)
        chosen = [m for m in methods if m not in extra or m == reference]
    else:
        items = which.split(",") if isinstance(which, str) else list(which)
        chosen = [m for m in methods if m in {i.strip() for i in items} or m == reference]
        unknown = sorted({i.strip() for i in items} - set(methods))
        if unknown:
            raise BracketryError(f"--stats-methods names methods that are not benchmarked: {', '.join(unknown)}")
    return chosen


def group_repeats(runs: list[dict]) -> list[dict]:
    """One result per (trajectory, method): the run itself, or the median and spread of its repeats."""
    from bracketry_emulator.benchmark.slam import combine_repeats

    groups: dict[tuple[str, str], list[dict]] = {}
    for r in runs:
        groups.setdefault((r["trajectory"], r["method"]), []).append(r)
    out = []
    for rs in groups.values():
        rs.sort(key=lambda r: r.get("repeat", 0))
        out.append(combine_repeats(rs) if len(rs) > 1 else {**rs[0], "repeats": 1,
                                                             "repeats_ok": 0 if rs[0].get("error") else 1})
    return out
