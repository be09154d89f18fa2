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
Tasks are plain dicts in and out (picklable for process pools and Dask).
"""

from __future__ import annotations

import hashlib
import json
import os
import time
from pathlib import Path

from bracketry_emulator.benchmark.emulated_runs import loop_options
from bracketry_emulator.benchmark.slam import key_options
from bracketry_emulator.metrics.evaluate import evaluate_run
from bracketry_emulator.metrics.manifest import TrajectorySpec
from bracketry_emulator.metrics.rpe import DEFAULT_WINDOWS_M

CACHE_VERSION = 3


def make_task(spec: TrajectorySpec, method: str, out_dir: Path, windows_m: tuple[float, ...] = DEFAULT_WINDOWS_M,
              max_frames: int | None = None, export_orbslam: bool = False, slam_dir: Path | None = None,
              drl_weights: str | None = None, loop: dict | None = None, slam: dict | None = None,
              repeat: int = 0, groundtruth: Path | None = None) -> dict:
    """A picklable task description.

    ``slam``: SLAM options (:func:`~bracketry_emulator.benchmark.slam.slam_options`; None = the built-in VO).
    ``repeat``: which repeat of the (trajectory, method) run this is (0-based; part of the key and the paths).
    ``groundtruth``: a TUM left-camera reference replacing the spec's (e.g. made from its ``reference.yaml``).

    ``drl_weights``: the DRL actor's .pth (used by the ``drl`` method's closed loop; part of its cache key).
    ``loop``: closed-loop settings (:data:`~bracketry_emulator.benchmark.emulated_runs.LOOP_DEFAULTS`; part of the key).

    ``export_orbslam``: also write the run in ORB-SLAM's stereo-example layout to
    ``out/orbslam/<trajectory>/<method>/``. ``slam_dir``: evaluate external SLAM trajectories
    ``slam_dir/<trajectory>/<method>/CameraTrajectory*.txt`` instead of running the built-in VO.
    """
    slam_opts: dict = dict(slam) if slam else {"backend": "builtin"}
    task: dict = {
        "trajectory": spec.name, "subset": spec.subset, "method": method,
        "dataset": str(spec.path), "out": str(out_dir),
        "groundtruth": (str(groundtruth) if groundtruth else
                        str(spec.groundtruth_path()) if spec.groundtruth_path() else None),
        "calibration": str(spec.calibration_dir()) if spec.calibration_dir() else None,
        "existing_run": str(spec.existing_run(method)) if spec.existing_run(method) else None,
        "windows_m": [float(w) for w in windows_m], "max_frames": max_frames,
        "export_orbslam": bool(export_orbslam), "slam_dir": str(slam_dir) if slam_dir else None,
        "drl_weights": str(Path(drl_weights).resolve()) if drl_weights and method == "drl" else None,
        "loop": loop_options(**(loop or {})),
        "slam": slam_opts, "repeat": int(repeat),
    }
    key_src = json.dumps({**{k: task[k] for k in ("dataset", "method", "groundtruth", "calibration", "existing_run",
                                                  "windows_m", "max_frames", "slam_dir", "drl_weights", "loop",
                                                  "repeat")},
                          "slam": key_options(slam_opts)}, sort_keys=True)
    task["key"] = hashlib.sha256(f"v{CACHE_VERSION}:{key_src}".encode()).hexdigest()[:16]
    return task


def _run_name(task: dict) -> str:
    r = int(task.get("repeat", 0))
    return task["method"] if r == 0 else f"{task['method']}.r{r}"


def cache_path(task: dict) -> Path:
    return Path(task["out"]) / "cache" / task["trajectory"] / f"{_run_name(task)}.json"


def load_cached(task: dict) -> dict | None:
    """The cached result of ``task`` if present and made with the same key."""
    p = cache_path(task)
    if not p.is_file():
        return None
    try:
        result = json.loads(p.read_text())
    except (OSError, ValueError):
        return None
    return result if result.get("key") == task["key"] else None


def _write_atomic(path: Path, text: str) -> None:
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_name(f".{path.name}.{os.getpid()}.tmp")
    tmp.write_text(text)
    os.replace(tmp, path)


def _tune_malloc() -> None:
    """Undo a small fixed glibc trim threshold (Dask's nanny sets ``MALLOC_TRIM_THRESHOLD_=65536`` for workers).

    With that variable glibc also freezes its mmap threshold at 128 KiB, so every image-sized numpy temporary is a
    fresh mmap + page faults + munmap: measured 2x the CPU time of a VO task. Raising both thresholds with
    ``mallopt`` restores in-process speed; memory is still returned to the OS above 256 MiB of free heap.
    """
    import ctypes
    import ctypes.util
    import sys

    if not sys.platform.startswith("linux"):
        return
    try:
        libc = ctypes.CDLL(ctypes.util.find_library("c") or "libc.so.6")
        libc.mallopt(-3, 64 * 1024 * 1024)  # M_MMAP_THRESHOLD
        libc.mallopt(-1, 256 * 1024 * 1024)  # M_TRIM_THRESHOLD
    except (OSError, AttributeError):
        pass


def run_task(task: dict) -> dict:
    """Run (or load from the cache) one task and return its result dict.

    Result keys: trajectory, subset, method, repeat, key, run_dir, vo_dir, slam (backend), s_per_frame,
    cached (bool), ``error`` (one line, only when the SLAM run failed) and the metrics of
    :func:`~bracketry_emulator.metrics.evaluate.evaluate_run`.
    """
    cached = load_cached(task)
    if cached is not None:
        cached["cached"] = True
        return cached
    import cv2

    cv2.setNumThreads(1)  # one core per task: deterministic, and workers do not fight over cores
    _tune_malloc()
    from bracketry.errors import BracketryError
    from bracketry_emulator.benchmark.emulated_runs import emulate_run
    from bracketry_emulator.benchmark.slam import run_slam

    out = Path(task["out"])
    if task["calibration"] is None:
        raise BracketryError(f"{task['dataset']}: no calibration/ folder with left/right camera_info YAMLs")
    if task["existing_run"]:
        run_dir = Path(task["existing_run"])
    else:
        run_dir = emulate_run(Path(task["dataset"]), task["method"], out / "runs" / task["trajectory"],
                              drl_weights=task.get("drl_weights"), options=task.get("loop"))
    if task.get("export_orbslam"):
        from bracketry_emulator.vo.orbslam import export_orbslam

        export_orbslam(run_dir, task["calibration"], out / "orbslam" / task["trajectory"] / task["method"])
    vo_dir = vo_path(task)
    if task.get("slam_dir"):
        from bracketry_emulator.vo.orbslam import import_orbslam

        slam = Path(task["slam_dir"]) / task["trajectory"] / task["method"]
        import_orbslam(slam, run_dir / "times_images_left.txt", vo_dir)
        return complete_task(task, run_dir, {"backend": "external", "s_per_frame": float("nan")})
    t0, c0 = time.perf_counter(), time.thread_time()
    try:
        info = run_slam(task.get("slam"), run_dir, task["calibration"], vo_dir, task["max_frames"])
    except BracketryError as exc:  # this run only: a clear line in the report, the benchmark goes on
        return complete_task(task, run_dir, None, str(exc),
                             slam_s=(time.perf_counter() - t0, time.thread_time() - c0))
    return complete_task(task, run_dir, info, slam_s=(time.perf_counter() - t0, time.thread_time() - c0))


def vo_path(task: dict) -> Path:
    """Where a task's SLAM output goes: ``out/vo/<trajectory>/<method>[.r<repeat>]``."""
    return Path(task["out"]) / "vo" / task["trajectory"] / _run_name(task)


def complete_task(task: dict, run_dir: Path, info: dict | None, error: str | None = None,
                  slam_s: tuple[float, float] | None = None) -> dict:
    """The result of a task whose SLAM run is over: its metrics (timed), written to the cache; or, with ``error``
    (the SLAM run failed), NaN metrics and the error line, not cached.

    ``info``: the SLAM run's facts (backend, s_per_frame; a child process's ``wall_s``/``cpu_s``). ``slam_s``:
    (wall, CPU) seconds of an in-process run. The result's ``stages`` holds the SLAM and metrics seconds of this
    run (:mod:`~bracketry_emulator.stages`)."""
    from bracketry_emulator.stages import StageTimes

    vo_dir = vo_path(task)
    stages = StageTimes()
    if info is not None and "wall_s" in info:
        stages.add("slam", info["wall_s"], info.get("cpu_s", float("nan")))
    elif slam_s is not None:
        stages.add("slam", *slam_s)
    base = {"trajectory": task["trajectory"], "subset": task["subset"], "method": task["method"],
            "repeat": int(task.get("repeat", 0)), "key": task["key"], "run_dir": str(run_dir),
            "vo_dir": str(vo_dir)}
    if error is not None or info is None:
        return {**base, **failed_metrics(), "slam": task.get("slam", {}).get("backend", "builtin"),
                "s_per_frame": float("nan"), "error": error or "the SLAM run failed", "cached": False,
                "stages": stages.as_dict()}
    with stages.time("metrics"):
        metrics = evaluate_run(vo_dir, task["groundtruth"], tuple(task["windows_m"]))
    s_per_frame = info.get("s_per_frame", info.get("track_s_median", float("nan")))  # ORB-SLAM3: median track
    result = {**base, **metrics, "slam": info["backend"], "s_per_frame": s_per_frame, "stages": stages.as_dict()}
    if info.get("source"):
        result["slam_input"] = info["source"]
    if info.get("pace_s", 0.0) != 0.0 and "max_late_s" in info:  # a paced run: how far it fell behind its clock
        result["slam_late_s"] = info["max_late_s"]
    _write_atomic(cache_path(task), json.dumps(result))
    result["cached"] = False
    return result


def failed_metrics() -> dict:
    """The metrics of a run whose SLAM failed: unknown (NaN), not a tracking failure of the AE method."""
    nan = float("nan")
    return {"n_frames": 0, "success": False, "time_before_failure_s": nan, "duration_s": nan,
            "tracked_fraction": nan, "tracked_distance_fraction": nan, "n_failures": 0, "n_segments": 0,
            "coverage_mean": nan, "matches_mean": nan, "keypoints_mean": nan, "coverage": [], "matches": [],
            "rte_pct": nan, "rre_deg_per_m": nan, "windows": [], "reference": "run failed"}
