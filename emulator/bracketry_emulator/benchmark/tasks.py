"""One benchmark task = one (trajectory, method, repeat): closed loop -> SLAM -> metrics, with a result cache.

Output layout under the benchmark folder ``out``::

    runs/<trajectory>/<method>/...        emulated run (RunWriter layout), unless the dataset already had it
    vo/<trajectory>/<method>/frames.csv   SLAM per-frame log + CameraTrajectory<n>.txt segments (ORB-SLAM3 adds
                                          settings.yaml, orbslam3.log, slam.json); repeat r > 0: <method>.r<r>/
    orbslam/<trajectory>/<method>/        with export_orbslam: the run in ORB-SLAM's stereo-example layout
    cache/<trajectory>/<method>.json      the task's result (metrics); present = done; repeat r > 0: <method>.r<r>.json

A task whose cache file exists with the same key (dataset path, method, SLAM backend/vocabulary/pace, repeat,
metric settings) is not recomputed, so an interrupted benchmark resumes where it stopped. Cache files are written
atomically (temporary file + rename). A SLAM run that fails (crash, bad vocabulary or settings) gives a result with
an ``error`` line and NaN metrics, is not cached, and the benchmark goes on.
A task is a :class:`BenchmarkTask`, its outcome a :class:`RunResult`: frozen records (picklable for process pools
and Dask), each with one JSON form (``to_json``/``from_json``): the task's keyed part is hashed into its cache key,
the result's is the cache file and what the report reads.
"""

from __future__ import annotations

import functools
import hashlib
import json
import os
import time
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import TYPE_CHECKING, Any

from bracketry_emulator.benchmark.slam import SlamOptions
from bracketry_emulator.metrics.evaluate import evaluate_run
from bracketry_emulator.metrics.manifest import TrajectorySpec
from bracketry_emulator.metrics.rpe import DEFAULT_WINDOWS_M

if TYPE_CHECKING:
    from bracketry_emulator.ae.registry import MethodSpec
    from bracketry_emulator.ae.runner import LoopConfig

#: bumped when the code's results change under the same settings (4: Kim's default mode, fusion's default bracket
#: set 'longer', targets beyond the longest bracket recorded as gain, time before failure counted in steps; 5: the
#: step period is the dataset's bracket cycle, the same for every method; 6: Kim's metric gives clipped pixels no
#: weight, the oracle scores against its last 3 frames; 7: Kim's metric gives pixels beside clipped ones no weight
#: and its search converges only on a measured peak; 8: ORB-SLAM3's own keypoint count per frame in ``frames.csv``,
#: which the failure causes read; 9: an exposure jump from half a stop), so no older result is reused. A cache file
#: holds one task's own run (the oracle's: its step search's); the oracle row is chosen from the runs after they are
#: loaded (:mod:`~bracketry_emulator.benchmark.oracle_rows`), so no cache file holds an oracle row
CACHE_VERSION = 9


def _default_loop() -> LoopConfig:
    from bracketry_emulator.ae.runner import LoopConfig

    return LoopConfig()


@dataclass(frozen=True)
class BenchmarkTask:
    """One (trajectory, method, repeat) of a benchmark (:func:`make_task`). Paths are strings (as in its JSON form).

    ``method_spec``: the method itself (name, source, options such as a plugin's arguments or the DRL actor's
    weights), as :func:`~bracketry_emulator.ae.registry.resolve_methods` made it: the worker creates the method from
    it. ``out``: the benchmark folder. ``groundtruth``: the TUM left-camera reference (None: none). ``calibration``:
    the trajectory's calibration folder. ``existing_run``: the dataset's own emulated run of the method (then no
    closed loop runs). ``loop``: the closed-loop settings. ``slam_dir``: external SLAM trajectories evaluated instead
    of running SLAM. ``export_orbslam``: also export the run for ORB-SLAM's stereo examples.
    """

    trajectory: str
    subset: str
    method_spec: MethodSpec
    dataset: str
    out: str
    groundtruth: str | None = None
    calibration: str | None = None
    existing_run: str | None = None
    windows_m: tuple[float, ...] = DEFAULT_WINDOWS_M
    max_frames: int | None = None
    export_orbslam: bool = False
    slam_dir: str | None = None
    loop: LoopConfig = field(default_factory=_default_loop)
    slam: SlamOptions = field(default_factory=SlamOptions.builtin)
    repeat: int = 0

    @property
    def method(self) -> str:
        """The method's name (folders, rows, statistics)."""
        return self.method_spec.name

    @property
    def drl_weights(self) -> str | None:
        """The DRL actor's weights (an option of the ``drl`` method; None for every other)."""
        w = self.method_spec.option("drl_weights") if self.method_spec.builtin else None
        return None if w is None else str(w)

    def _plugin_json(self) -> dict[str, Any]:
        """``{"plugin": {"source", "options"}}`` for a method its name alone does not load, else nothing (so a
        built-in's JSON form and key are as before)."""
        spec = self.method_spec
        return {} if spec.plain else {"plugin": spec.to_json()}

    def to_json(self) -> dict[str, Any]:
        """The task as a JSON object (the loop and SLAM options in their own JSON forms) with its ``key``."""
        doc: dict[str, Any] = {
            "trajectory": self.trajectory, "subset": self.subset, "method": self.method, "dataset": self.dataset,
            "out": self.out, "groundtruth": self.groundtruth, "calibration": self.calibration,
            "existing_run": self.existing_run, "windows_m": list(self.windows_m), "max_frames": self.max_frames,
            "export_orbslam": self.export_orbslam, "slam_dir": self.slam_dir, "drl_weights": self.drl_weights,
            "loop": self.loop.to_json(), "slam": self.slam.to_json(), "repeat": self.repeat, **self._plugin_json()}
        doc["key"] = self.key
        return doc

    @classmethod
    def from_json(cls, doc: dict[str, Any]) -> BenchmarkTask:
        """The task of :meth:`to_json`'s form (its ``key`` is recomputed)."""
        from bracketry_emulator.ae.registry import MethodSpec
        from bracketry_emulator.ae.runner import LoopConfig

        fields_ = {k: v for k, v in doc.items() if k not in ("key", "plugin", "method", "drl_weights")}
        name, plugin, weights = str(doc["method"]), doc.get("plugin"), doc.get("drl_weights")
        spec = (MethodSpec.from_json(name, plugin) if plugin else
                MethodSpec(name, name, (("drl_weights", weights),) if weights is not None else ()))
        return cls(**{**fields_, "method_spec": spec, "windows_m": tuple(doc["windows_m"]),
                      "loop": LoopConfig.from_json(doc["loop"]), "slam": SlamOptions.from_json(doc["slam"])})

    @property
    def key(self) -> str:
        """The cache key: what decides the result (dataset, method, references, metric settings, closed loop,
        SLAM backend and its result-deciding options, repeat), hashed."""
        doc = self.to_json_keyed()
        key_src = json.dumps(doc, sort_keys=True)
        return hashlib.sha256(f"v{CACHE_VERSION}:{key_src}".encode()).hexdigest()[:16]

    def to_json_keyed(self) -> dict[str, Any]:
        """The part of the JSON form the cache key covers."""
        return {"dataset": self.dataset, "method": self.method, "groundtruth": self.groundtruth,
                "calibration": self.calibration, "existing_run": self.existing_run,
                "windows_m": list(self.windows_m), "max_frames": self.max_frames, "slam_dir": self.slam_dir,
                "drl_weights": self.drl_weights, "loop": self.loop.to_json(), "repeat": self.repeat,
                "slam": self.slam.key_json(), **self._plugin_json()}

    @property
    def run_name(self) -> str:
        """``<method>``, or ``<method>.r<repeat>`` for repeat r > 0."""
        return self.method if self.repeat == 0 else f"{self.method}.r{self.repeat}"

    @property
    def cache_path(self) -> Path:
        """``out/cache/<trajectory>/<run name>.json``."""
        return Path(self.out) / "cache" / self.trajectory / f"{self.run_name}.json"

    @property
    def vo_path(self) -> Path:
        """Where the task's SLAM output goes: ``out/vo/<trajectory>/<run name>``."""
        return Path(self.out) / "vo" / self.trajectory / self.run_name


@dataclass(frozen=True)
class RunResult:
    """The outcome of one task: where its run and SLAM output are, the SLAM backend and its speed, the metrics of
    :func:`~bracketry_emulator.metrics.evaluate.evaluate_run` (or :func:`failed_metrics` with an ``error`` line),
    this run's SLAM and metrics seconds (``stages``, :class:`~bracketry_emulator.stages.StageTimes` ``as_dict``),
    whether it came from the cache. ``slam_input``: how SLAM got the images (``png`` / ``stream``);
    ``slam_late_s``: how far a paced run fell behind its clock."""

    trajectory: str
    subset: str
    method: str
    repeat: int
    key: str
    run_dir: str
    vo_dir: str
    metrics: dict[str, Any]
    slam: str
    s_per_frame: float
    stages: dict[str, Any] = field(default_factory=dict)
    slam_input: str | None = None
    slam_late_s: float | None = None
    error: str | None = None
    cached: bool = False

    def to_json(self, cached: bool = True) -> dict[str, Any]:
        """The result as one flat JSON object (base fields, metrics, SLAM facts; ``cached`` last unless ``cached``
        is False: the cache file's form)."""
        base = {"trajectory": self.trajectory, "subset": self.subset, "method": self.method, "repeat": self.repeat,
                "key": self.key, "run_dir": self.run_dir, "vo_dir": self.vo_dir, **self.metrics, "slam": self.slam,
                "s_per_frame": self.s_per_frame}
        if self.error is not None:
            return {**base, "error": self.error, **({"cached": self.cached} if cached else {}),
                    "stages": self.stages}
        doc = {**base, "stages": self.stages}
        if self.slam_input is not None:
            doc["slam_input"] = self.slam_input
        if self.slam_late_s is not None:
            doc["slam_late_s"] = self.slam_late_s
        if cached:
            doc["cached"] = self.cached
        return doc

    @classmethod
    def from_json(cls, doc: dict[str, Any]) -> RunResult:
        """The result of :meth:`to_json`'s form (every key not a field is a metric, order kept)."""
        names = set(cls.__dataclass_fields__) - {"metrics"}
        return cls(**{k: v for k, v in doc.items() if k in names},
                   metrics={k: v for k, v in doc.items() if k not in names})


def make_task(spec: TrajectorySpec, method: str | MethodSpec, out_dir: Path,
              windows_m: tuple[float, ...] = DEFAULT_WINDOWS_M, max_frames: int | None = None,
              export_orbslam: bool = False, slam_dir: Path | None = None,
              loop: LoopConfig | None = None, slam: SlamOptions | None = None,
              repeat: int = 0, groundtruth: Path | None = None) -> BenchmarkTask:
    """The task of ``method`` (a resolved :class:`~bracketry_emulator.ae.registry.MethodSpec`: its source and
    options, the DRL actor's weights included; or a built-in's id) on trajectory ``spec``.

    ``slam``: SLAM options (:func:`~bracketry_emulator.benchmark.slam.slam_options`; None = the built-in VO).
    ``repeat``: which repeat of the (trajectory, method) run this is (0-based; part of the key and the paths).
    ``groundtruth``: a TUM left-camera reference replacing the spec's (e.g. made from its ``reference.yaml``).

    ``loop``: closed-loop settings (None: the defaults; part of the key in :meth:`LoopConfig.to_json`'s form).

    ``export_orbslam``: also write the run in ORB-SLAM's stereo-example layout to
    ``out/orbslam/<trajectory>/<method>/``. ``slam_dir``: evaluate external SLAM trajectories
    ``slam_dir/<trajectory>/<method>/CameraTrajectory*.txt`` instead of running the built-in VO.
    """
    from bracketry_emulator.ae.registry import MethodSpec

    resolved = MethodSpec(method, method) if isinstance(method, str) else method
    gt = groundtruth or spec.groundtruth_path()
    calibration, existing = spec.calibration_dir(), spec.existing_run(resolved.name)
    return BenchmarkTask(
        trajectory=spec.name, subset=spec.subset, method_spec=resolved, dataset=str(spec.path), out=str(out_dir),
        groundtruth=str(gt) if gt else None, calibration=str(calibration) if calibration else None,
        existing_run=str(existing) if existing else None, windows_m=tuple(float(w) for w in windows_m),
        max_frames=max_frames, export_orbslam=bool(export_orbslam), slam_dir=str(slam_dir) if slam_dir else None,
        loop=loop if loop is not None else _default_loop(), slam=slam or SlamOptions.builtin(), repeat=int(repeat))


def load_cached(task: BenchmarkTask) -> RunResult | None:
    """The cached result of ``task`` if present and made with the same key."""
    p = task.cache_path
    if not p.is_file():
        return None
    try:
        doc = json.loads(p.read_text())
    except (OSError, ValueError):
        return None
    return RunResult.from_json(doc) if doc.get("key") == task.key else None


def _write_atomic(path: Path, text: str) -> None:
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_name(f".{path.name}.{os.getpid()}.tmp")
    tmp.write_text(text)
    os.replace(tmp, path)


def run_task(task: BenchmarkTask) -> RunResult:
    """Run (or load from the cache) one task and return its result (``error``: one line, only when the SLAM run
    failed)."""
    cached = load_cached(task)
    if cached is not None:
        return replace(cached, cached=True)
    from bracketry_emulator.runtime_policy import apply_profile

    apply_profile("task")  # one core per task (workers side by side), a heap that reuses image-sized temporaries
    from bracketry_base.errors import BracketryError
    from bracketry_emulator.benchmark.emulated_runs import emulate_run
    from bracketry_emulator.benchmark.slam import run_slam

    out = Path(task.out)
    if task.calibration is None:
        raise BracketryError(f"{task.dataset}: no calibration/ folder with left/right camera_info YAMLs")
    if task.existing_run:
        run_dir = Path(task.existing_run)
    else:
        run_dir = emulate_run(Path(task.dataset), task.method_spec, out / "runs" / task.trajectory, task.loop)
    if task.export_orbslam:
        from bracketry_emulator.vo.orbslam import export_orbslam

        export_orbslam(run_dir, task.calibration, out / "orbslam" / task.trajectory / task.method)
    vo_dir = task.vo_path
    if task.slam_dir:
        from bracketry_emulator.vo.orbslam import import_orbslam

        slam = Path(task.slam_dir) / task.trajectory / task.method
        import_orbslam(slam, run_dir / "times_images_left.txt", vo_dir)
        return complete_task(task, run_dir, {"backend": "external", "s_per_frame": float("nan")})
    t0, c0 = time.perf_counter(), time.thread_time()
    try:
        info = run_slam(task.slam, run_dir, task.calibration, vo_dir, task.max_frames)
    except BracketryError as exc:  # this run only: a clear line in the report, the benchmark goes on
        return complete_task(task, run_dir, None, str(exc),
                             slam_s=(time.perf_counter() - t0, time.thread_time() - c0))
    return complete_task(task, run_dir, info, slam_s=(time.perf_counter() - t0, time.thread_time() - c0))


def complete_task(task: BenchmarkTask, run_dir: Path, info: dict | None, error: str | None = None,
                  slam_s: tuple[float, float] | None = None) -> RunResult:
    """The result of a task whose SLAM run is over: its metrics (timed), written to the cache; or, with ``error``
    (the SLAM run failed), NaN metrics and the error line, not cached.

    ``info``: the SLAM run's facts (backend, s_per_frame; a child process's ``wall_s``/``cpu_s``). ``slam_s``:
    (wall, CPU) seconds of an in-process run. The result's ``stages`` holds the SLAM and metrics seconds of this
    run (:mod:`~bracketry_emulator.stages`)."""
    from bracketry_emulator.stages import StageTimes

    vo_dir = task.vo_path
    stages = StageTimes()
    if info is not None and "wall_s" in info:
        stages.add("slam", info["wall_s"], info.get("cpu_s", float("nan")))
    elif slam_s is not None:
        stages.add("slam", *slam_s)
    base: dict[str, Any] = {"trajectory": task.trajectory, "subset": task.subset, "method": task.method,
                            "repeat": task.repeat, "key": task.key, "run_dir": str(run_dir), "vo_dir": str(vo_dir)}
    if error is not None or info is None:
        return RunResult(**base, metrics=failed_metrics(), slam=task.slam.backend, s_per_frame=float("nan"),
                         error=error or "the SLAM run failed", stages=stages.as_dict())
    with stages.time("metrics"):
        metrics = evaluate_run(vo_dir, task.groundtruth, task.windows_m, cycle_period_s(task.dataset))
        from bracketry_emulator.benchmark.failure_analysis import run_failure_cause

        metrics["failure_cause"] = (None if metrics["success"] else
                                    run_failure_cause(vo_dir, run_dir, task.groundtruth, task.calibration))
    paced = info.get("pace_s", 0.0) != 0.0 and "max_late_s" in info  # how far a paced run fell behind its clock
    result = RunResult(**base, metrics=metrics, slam=info["backend"],
                       s_per_frame=info.get("s_per_frame", info.get("track_s_median", float("nan"))),  # ORB-SLAM3
                       stages=stages.as_dict(), slam_input=info.get("source") or None,
                       slam_late_s=info["max_late_s"] if paced else None)
    _write_atomic(task.cache_path, json.dumps(result.to_json(cached=False)))
    return result


@functools.cache
def cycle_period_s(dataset: str) -> float | None:
    """The bracket-cycle period of ``dataset`` (s, rounded to 0.1 ms): the median spacing of its sequences' first
    frames, the closed loop's step period for every method alike; None with fewer than two sequences or when the
    folder cannot be read as a dataset (runs evaluated from existing files: then the runs' own stamps decide)."""
    from bracketry_base.errors import BracketryError
    from bracketry_emulator.dataset import open_dataset
    from bracketry_emulator.metrics.failures import step_period_s

    try:
        starts = [seq.start_ns for seq in open_dataset(Path(dataset)).sequences()]
    except (BracketryError, OSError, ValueError):
        return None
    return step_period_s(starts) if len(starts) >= 2 else None


def failed_metrics() -> dict:
    """The metrics of a run whose SLAM failed: unknown (NaN), not a tracking failure of the AE method."""
    nan = float("nan")
    return {"n_frames": 0, "success": False, "time_before_failure_s": nan, "duration_s": nan,
            "tracked_fraction": nan, "tracked_distance_fraction": nan, "n_failures": 0, "n_segments": 0,
            "coverage_mean": nan, "matches_mean": nan, "keypoints_mean": nan, "coverage": [], "matches": [],
            "rte_pct": nan, "rre_deg_per_m": nan, "windows": [], "reference": "run failed"}
