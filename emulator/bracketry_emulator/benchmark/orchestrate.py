"""Run every (trajectory, method) task locally (process pool) or on a Dask cluster, then statistics and report."""

from __future__ import annotations

import concurrent.futures
import json
import multiprocessing
import time
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any

from bracketry_base.errors import BracketryError
from bracketry_emulator.ae.runner import LoopConfig
from bracketry_emulator.benchmark.cluster import SlurmOptions
from bracketry_emulator.benchmark.oracle_rows import oracle_best_runs
from bracketry_emulator.benchmark.slam import SlamOptions, describe
from bracketry_emulator.benchmark.tasks import BenchmarkTask, RunResult, load_cached, make_task, run_task
from bracketry_emulator.defaults import DEFAULT_ALPHA, DEFAULT_REFERENCE, DEFAULT_STATS_METHODS
from bracketry_emulator.metrics.manifest import TrajectorySpec, expand_datasets
from bracketry_emulator.metrics.rpe import DEFAULT_WINDOWS_M

OnDone = Callable[[RunResult], None]


@dataclass(frozen=True)
class BenchmarkConfig:
    """What :func:`run_benchmark` does: ``methods`` on ``datasets`` (folders, manifests or specs) into ``out_dir``.

    ``methods``: ``--methods`` text or a sequence of ids (parsed by
    :func:`~bracketry_emulator.ae.registry.parse_methods`: ``all`` / ``paper``, ``controls``, ids).
    ``scheduler``: a Dask scheduler address (``tcp://HOST:PORT``); ``cluster``: Slurm jobs through dask-jobqueue
    (:class:`~bracketry_emulator.benchmark.cluster.SlurmOptions`); neither: local processes (``workers``). Locally,
    the closed loops of all methods still to run on a trajectory run first in one pass (each bracket sequence
    decoded once for all methods, ``progress`` shows a bar); on a cluster a worker runs such a pass per trajectory
    (:mod:`~bracketry_emulator.benchmark.cluster`: shared storage checked on every worker, a lost worker's runs
    done again elsewhere, a lost scheduler one line).
    ``drl_weights``: the DRL actor (``all`` leaves DRL out without it; an option of the ``drl`` method from here
    on). ``loop``: the closed-loop settings; what :meth:`LoopConfig.to_json` holds is part of every cache key, and a
    setting it cannot hold is refused (the cameras written, the images and ``overwrite`` are the benchmark's own).
    ``export_orbslam`` / ``slam_dir``: see :func:`~bracketry_emulator.benchmark.tasks.make_task`.
    Without ``slam_dir`` and ``export_orbslam`` (locally or on a cluster) SLAM gets the emulated images as raw frame
    records (:mod:`~bracketry_emulator.benchmark.stream`: every run of a trajectory is spooled by its one closed-loop
    pass, then its SLAM runs go one more at a time than ``workers``) and PNGs are written only with ``write_images``;
    otherwise the closed loops write PNGs and SLAM reads them.
    ``slam``: SLAM options (:func:`~bracketry_emulator.benchmark.slam.slam_options`; default: the built-in VO);
    with ``repeats`` > 1 every (trajectory, method) runs that many times and the results carry the median and
    spread (statistics on the medians). On the PNG route paced ORB-SLAM3 runs mostly wait, so locally twice
    ``workers`` of them run at once. An unresolved ORB-SLAM3
    vocabulary is resolved after the other input was checked. ``stats_methods``: the methods the statistics (and
    their Bonferroni count) cover: ``paper`` (default: the benchmarked methods among the paper's eight; ``zhang``
    and plugins are reported but not tested), ``all`` (every benchmarked method) or a list.
    ``setup_check``: with ORB-SLAM3 and runs still to do, first check that it can track at all with this vocabulary
    and calibration (:mod:`~bracketry_emulator.slam.setup_check`; a failure is one line before any method runs).
    ``method_options``: {method: {keyword: value}}: AE plugins' constructor arguments (keyed by the method's name or
    its id as given; part of their runs' cache keys, printed in the report). A method is named by its ``name``
    (:func:`~bracketry_emulator.ae.registry.resolve_methods`) in folders, rows, statistics and plots.
    Sequences may be given as lists and paths as strings: they are stored as tuples and Paths.
    """

    datasets: Sequence[str | Path | TrajectorySpec]
    methods: str | Sequence[str]
    out_dir: Path
    reference: str = DEFAULT_REFERENCE
    scheduler: str | None = None
    cluster: SlurmOptions | None = None
    workers: int = 1
    #: RTE/RRE windows (m) of every trajectory; None: a trajectory's manifest ``windows_m``, else the paper's
    windows_m: Sequence[float] | None = None
    max_frames: int | None = None
    alpha: float = DEFAULT_ALPHA
    report: bool = True
    export_orbslam: bool = False
    slam_dir: Path | None = None
    drl_weights: str | None = None
    progress: bool = False
    loop: LoopConfig = field(default_factory=LoopConfig)
    slam: SlamOptions = field(default_factory=SlamOptions.builtin)
    stats_methods: str | Sequence[str] = DEFAULT_STATS_METHODS
    write_images: bool = False
    setup_check: bool = True
    method_options: Mapping[str, Mapping[str, Any]] = field(default_factory=dict)
    #: steps each method takes on a trajectory's first view before it (:func:`~bracketry_emulator.ae.loop.iter_loop`);
    #: None: what its manifest declares (``warmup_steps:``), else ``loop.warmup_steps``
    warmup_steps: int | None = None
    #: remove what an earlier benchmark wrote into ``out_dir`` first (:func:`remove_earlier_benchmark`), once the
    #: input is checked; else its cached runs are reused
    overwrite: bool = False

    def __post_init__(self) -> None:
        def put(name: str, value: Any) -> None:
            object.__setattr__(self, name, value)

        for name in ("methods", "stats_methods"):
            if not isinstance(getattr(self, name), str):
                put(name, tuple(getattr(self, name)))
        put("datasets", tuple(self.datasets))
        if self.windows_m is not None:
            put("windows_m", tuple(float(w) for w in self.windows_m))
        put("out_dir", Path(self.out_dir))
        if self.slam_dir is not None:
            put("slam_dir", Path(self.slam_dir))
        if self.drl_weights is not None:
            put("drl_weights", str(self.drl_weights))
        put("method_options", {str(k): dict(v) for k, v in self.method_options.items()})


@dataclass
class BenchmarkResult:
    """One result per (trajectory, method) in the JSON form the report reads (:meth:`RunResult.to_json`; repeats
    combined: ``repeats``, ``repeats_ok`` and, for repeated runs, medians with ``*_runs`` / ``*_spread``), sorted by
    trajectory then method; and where the report went."""

    results: list[dict]
    out_dir: Path
    report_files: dict[str, Path]
    #: where the time went (:func:`stage_document`)
    timing: dict = field(default_factory=dict)


#: what a benchmark writes into its output folder (``--overwrite`` removes these, and only these, first)
BENCHMARK_OUTPUTS: tuple[str, ...] = ("cache", "runs", "vo", "report", "orbslam", "setup_check", "reference", "truth",
                                      ".cluster_token")


def remove_earlier_benchmark(out_dir: Path) -> None:
    """``--overwrite``: remove what an earlier benchmark wrote into ``out_dir`` (:data:`BENCHMARK_OUTPUTS`: its runs,
    cached results and report), so nothing of it is reused or mixed with the new one; other files stay."""
    import shutil

    for name in BENCHMARK_OUTPUTS:
        p = out_dir / name
        if p.is_dir() and not p.is_symlink():
            shutil.rmtree(p)
        elif p.exists() or p.is_symlink():
            p.unlink()


def spec_loop(spec: TrajectorySpec, loop: LoopConfig, warmup_steps: int | None = None) -> LoopConfig:
    """The closed-loop settings of trajectory ``spec``: ``loop`` with its warm-up (``warmup_steps`` when given, else
    the spec's manifest value when it declares one, else ``loop``'s own)."""
    steps = warmup_steps if warmup_steps is not None else spec.warmup_steps
    return loop if steps is None or steps == loop.warmup_steps else replace(loop, warmup_steps=int(steps))


def _spec_loop(tasks: list[BenchmarkTask], loop: LoopConfig) -> LoopConfig:
    """``loop`` with the warm-up of ``tasks`` (one trajectory's: they share it; see :func:`spec_loop`)."""
    return replace(loop, warmup_steps=tasks[0].loop.warmup_steps) if tasks else loop


def _todo(tasks: list[BenchmarkTask], trajectory: str) -> list[BenchmarkTask]:
    """The tasks of ``trajectory`` whose closed loop is still to run (no existing run, not cached)."""
    return [t for t in tasks if t.trajectory == trajectory and not t.existing_run and load_cached(t) is None]


def _shared_closed_loops(specs: list[TrajectorySpec], tasks: list[BenchmarkTask], out: Path, loop: LoopConfig,
                         workers: int, progress: bool, stages: Any = None) -> None:
    """Per trajectory, the closed loops of every method whose task still needs one, in one shared-decode pass."""
    from bracketry_emulator.benchmark.emulated_runs import emulate_runs

    for spec in specs:
        mine = _todo(tasks, spec.name)
        todo = list(dict.fromkeys(t.method_spec for t in mine))
        if todo:
            emulate_runs(spec.path, todo, out / "runs" / spec.name, _spec_loop(mine, loop), workers=max(0, workers),
                         progress=progress, stages=stages)


def _streamed(specs: list[TrajectorySpec], tasks: list[BenchmarkTask], out: Path, loop: LoopConfig, workers: int,
              progress: bool, stages: Any, on_done: OnDone | None) -> list[RunResult]:
    """Per trajectory, the tasks still to run (not cached, no existing run): one closed-loop pass that spools their
    frames, whose SLAM runs then go while the next trajectory's pass runs (see
    :mod:`~bracketry_emulator.benchmark.stream`); returns their results."""
    from bracketry_emulator.benchmark.stream import SlamRuns, slam_at_once, spool_trajectory

    done: list[BenchmarkTask] = []
    with SlamRuns(slam_at_once(workers), on_done) as runs:
        for spec in specs:
            todo = _todo(tasks, spec.name)
            if todo:
                runs.wait_for_room()
                runs.submit(*spool_trajectory(spec, todo, out, _spec_loop(todo, loop), workers=workers,
                                              progress=progress and not done,  # then the SLAM runs' bar only
                                              stages=stages))
                done += todo
        return runs.results(done)


def _run_local(tasks: list[BenchmarkTask], workers: int, on_done: OnDone | None) -> list[RunResult]:
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


def _run_cluster(c: BenchmarkConfig, specs: list[TrajectorySpec], tasks: list[BenchmarkTask], loop: LoopConfig,
                 slam: SlamOptions, stream: bool, on_done: OnDone | None) -> list[RunResult]:
    """The tasks on a Dask cluster (``c.scheduler``) or on Slurm jobs (``c.cluster``), in the units of
    :func:`~bracketry_emulator.benchmark.cluster.make_units`; every worker checked first."""
    from bracketry_emulator.benchmark import cluster as cl

    cached = [r for r in (load_cached(t) for t in tasks) if r is not None]
    if len(cached) == len(tasks):  # nothing to run: no cluster to start
        return _run_local(tasks, 1, on_done)
    units = cl.make_units(specs, tasks, loop, stream)
    checks = cl.worker_checks(c.out_dir.resolve(), tasks, slam.vocabulary if slam.backend == "orbslam3" else None,
                              slam.vocabulary_id)
    if c.cluster is not None:
        with cl.slurm_cluster(c.cluster) as (client, address, cores):
            return cl.run_units(client, units, checks, cores, on_done, address)
    assert c.scheduler is not None
    with cl.connect(c.scheduler) as client:
        return cl.run_units(client, units, checks, 1, on_done, c.scheduler)


def run_benchmark(config: BenchmarkConfig, *, on_done: OnDone | None = None,
                  slam_echo: Callable[[str], None] | None = None) -> BenchmarkResult:
    """Benchmark ``config.methods`` on ``config.datasets`` into ``config.out_dir`` (see :class:`BenchmarkConfig`).

    ``on_done``: called with each run's result as it completes (cached ones too). ``slam_echo``: says when the
    default ORB-SLAM3 vocabulary is being built and what the set-up check found. Where the time went is in the
    report's stage table and ``report/stages.json`` (:mod:`~bracketry_emulator.stages`).
    """
    c = config
    paths = [d for d in c.datasets if not isinstance(d, TrajectorySpec)]
    specs = [d for d in c.datasets if isinstance(d, TrajectorySpec)] + (expand_datasets(paths) if paths else [])
    if c.loop.images == "truth":
        check_truth_datasets(specs)
    weights = c.drl_weights
    if weights is not None and not Path(weights).is_file():
        raise BracketryError(f"--drl-weights file not found: {weights}")
    from bracketry_emulator.ae.registry import BUILTIN_METHODS, MethodSpec, is_builtin, parse_methods, resolve_methods

    # an unknown id, a broken plugin, a bad option, an unsafe or shared name: one line, before any work; a
    # dataset's own run of a method is named by its folder. Resolved once: the specs travel to the workers.
    method_ids = parse_methods(c.methods, has_drl_weights=weights is not None)
    existing = {m for m in method_ids if m.lower() not in BUILTIN_METHODS and any(s.existing_run(m) for s in specs)}
    resolved = resolve_methods([MethodSpec(m, m) if m in existing else m for m in method_ids], c.method_options,
                               seed=c.loop.seed, parity=c.loop.emulator.parity, drl_weights=weights)
    method_ids = [m.name for m in resolved]
    plugins = [m for m in resolved if m.name not in existing and not is_builtin(m.source)]
    if c.reference not in method_ids:
        raise BracketryError(f"reference method {c.reference!r} is not among the benchmarked methods {method_ids}")
    stats_methods = c.stats_methods if isinstance(c.stats_methods, str) else list(c.stats_methods)
    plugin_names = [m.name for m in plugins]
    select_stats_methods(stats_methods, method_ids, c.reference, plugin_names)  # bad names: one line, before work
    out = c.out_dir
    if c.overwrite:
        remove_earlier_benchmark(out)
    out.mkdir(parents=True, exist_ok=True)
    slam_path = c.slam_dir.resolve() if c.slam_dir else None
    if slam_path is not None and not slam_path.is_dir():
        raise BracketryError(f"--slam-trajectories folder not found: {slam_path}")
    loop = replace(c.loop, camera="both", write_images=c.write_images, overwrite=False)
    loop.validate()  # bad settings: one clear line before anything runs
    if not loop.round_trips():
        raise BracketryError("the benchmark's closed loops take only the settings of its options (selection, crf, "
                             "parity, init exposure, seed, AE camera, exposure bounds)")
    from bracketry_emulator.benchmark.slam import resolve_options

    slam = resolve_options(c.slam, echo=slam_echo)
    references = {s.name: _reference(s, out) for s in specs}
    if c.warmup_steps is not None:
        replace(loop, warmup_steps=c.warmup_steps).validate()  # a bad warm-up: one line before anything runs
    loops = {s.name: spec_loop(s, loop, c.warmup_steps) for s in specs}
    windows = {s.name: tuple(c.windows_m or s.windows_m or DEFAULT_WINDOWS_M) for s in specs}
    tasks = [make_task(s, m, out, windows[s.name], c.max_frames, c.export_orbslam, slam_path, loops[s.name], slam, r,
                       references[s.name])
             for s in specs for m in resolved for r in range(slam.repeats)]
    if c.setup_check and slam_path is None and slam.backend == "orbslam3":
        _check_setup(specs, tasks, method_ids, references, slam, out, slam_echo)
    from bracketry_emulator.stages import StageTimes

    t_start = time.perf_counter()
    stages = StageTimes()
    slam_workers = c.workers * 2 if slam.paced and c.workers > 1 else c.workers
    if c.scheduler is not None and c.cluster is not None:
        raise BracketryError("--scheduler and --cluster exclude each other (a cluster you run, or Slurm jobs)")
    local = c.scheduler is None and c.cluster is None
    if local and slam_path is None and not c.export_orbslam:
        streamed = _streamed(specs, tasks, out, loop, c.workers, c.progress, stages, on_done)
        done_keys = {r.key for r in streamed}
        runs = [*streamed, *_run_local([t for t in tasks if t.key not in done_keys], slam_workers, on_done)]
    elif local:
        if slam_path is None:
            _shared_closed_loops(specs, tasks, out, loop, c.workers, c.progress, stages)
        runs = _run_local(tasks, slam_workers, on_done)
    else:
        stream = slam_path is None and not c.export_orbslam
        runs = _run_cluster(c, specs, tasks, loop, slam, stream, on_done)
    for r in runs:  # this invocation's SLAM and metrics seconds (cached results did no work now)
        if not r.cached and r.stages:
            stages.merge(r.stages)
    results = group_repeats(oracle_best_runs([r.to_json() for r in runs]))  # the oracle: the best run of its rows
    results.sort(key=lambda r: (r["trajectory"], method_ids.index(r["method"])))
    files: dict[str, Path] = {}
    timing = stage_document(stages, results, time.perf_counter() - t_start, len(runs),
                            sum(1 for r in runs if r.cached))
    if c.report:
        from bracketry_emulator.report import write_report

        with stages.time("report"):
            files = write_report(results, out, reference=c.reference, methods=method_ids, alpha=c.alpha,
                                 localisation=describe(slam),
                                 stats_methods=select_stats_methods(stats_methods, method_ids, c.reference,
                                                                    plugin_names),
                                 plugins=[m.describe() for m in plugins],
                                 stages=timing)
        timing = {**timing, "stages": stages.as_dict(), "wall_s": round(time.perf_counter() - t_start, 3)}
        files["stages.json"] = out / "report" / "stages.json"
        files["stages.json"].write_text(json.dumps(timing, indent=1) + "\n")
    return BenchmarkResult(results, out, files, timing)


def _check_setup(specs: list[TrajectorySpec], tasks: list[BenchmarkTask], method_ids: list[str],
                 references: dict[str, Path | None], slam: SlamOptions, out: Path,
                 echo: Callable[[str], None] | None) -> None:
    """The ORB-SLAM3 set-up check (:func:`~bracketry_emulator.slam.setup_check.check_setup`) when some run is still
    to do; its runs go to ``out/setup_check/``."""
    from bracketry_emulator.slam.setup_check import Trajectory, check_setup

    if all(load_cached(t) is not None for t in tasks):
        return
    trajectories = [Trajectory(s.name, s.path, s.calibration_dir(),
                               next((r for r in (s.existing_run(m) for m in method_ids) if r is not None), None),
                               references.get(s.name) or s.groundtruth_path()) for s in specs]
    res = check_setup(trajectories, str(slam.vocabulary), out / "setup_check")
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


def _reference(spec: TrajectorySpec, out: Path) -> Path | None:
    """A trajectory's ``reference.yaml`` (TUM/KITTI/EuRoC, any sensor frame) as a left-camera TUM file under
    ``out/reference/``; None when it has none (then its ``groundtruth.txt``, if any, is the reference)."""
    from bracketry_emulator.metrics.reference import write_camera_reference

    if spec.is_zip():
        from bracketry_emulator.dataset.ziptree import left_image_times_ns

        return write_camera_reference(spec.side_files(), out / "reference" / f"{spec.name}.txt",
                                      left_image_times_ns(spec.path))
    return write_camera_reference(spec.path, out / "reference" / f"{spec.name}.txt")


def select_stats_methods(which: str | list[str], methods: list[str], reference: str,
                         plugins: Sequence[str] | None = None) -> list[str]:
    """The benchmarked methods the statistics cover (see :func:`run_benchmark`), the reference always included.
    ``plugins``: the names of the plugins among ``methods`` (``paper`` leaves them out; None: the entry points'
    names)."""
    from importlib.metadata import entry_points

    from bracketry_emulator.ae.registry import BUILTIN_METHODS, ENTRY_POINT_GROUP, PAPER_METHODS

    if which == "all":
        chosen = list(methods)
    elif which == "paper":  # leave out the non-paper built-ins (zhang) and plugins; runs named otherwise stay
        named = plugins if plugins is not None else [ep.name for ep in entry_points(group=ENTRY_POINT_GROUP)]
        extra = {*BUILTIN_METHODS, *named} - set(PAPER_METHODS)
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


def check_truth_datasets(datasets: Sequence[str | Path | TrajectorySpec]) -> None:
    """Refuse (BracketryError, one line) truth images for any trajectory that is not a synthetic one, and for one of
    a rendered suite whose synth code (its manifest's ``suite.code``) is not this bracketry's: the truth would render
    another world than the one its brackets show (a suite rendered before a change of the synthetic world)."""
    from bracketry_emulator.ae.truth import truth_recording
    from bracketry_emulator.synth.suite import code_digest

    paths = [d for d in datasets if not isinstance(d, TrajectorySpec)]
    specs = [d for d in datasets if isinstance(d, TrajectorySpec)] + (expand_datasets(paths) if paths else [])
    ours = code_digest()
    for s in specs:
        if s.suite_code is not None and s.suite_code != ours:
            raise BracketryError(
                f"{s.name}: its suite was rendered by synth code {s.suite_code}, this bracketry renders {ours}: its "
                f"truth images would show another world than its brackets; render the suite again (bracketry synth "
                f"suite --out NEW_DIR)")
    for s in specs:
        truth_recording(s.path)
