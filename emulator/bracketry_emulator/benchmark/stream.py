"""One pass per trajectory: the closed loops of every method feed their SLAM runs in memory, then the metrics.

For each trajectory the SLAM runs of every task still to do (method x repeat) start first, one child process each
(:func:`~bracketry_emulator.slam.orbslam3.start_child`, ORB-SLAM3 or the built-in VO: a crash stays one failed
run), forked by this process's SLAM fork server (:mod:`~bracketry_emulator.slam.launcher`: Python and the child's
imports paid once per benchmark, not once per run) or, without one, started as ``python -m``. Each gets a
named pipe (``vo/<trajectory>/<run>/frames.fifo``); then one closed-loop pass over the trajectory
(each bracket frame decoded once for every method) hands every step's stereo images to the method's runs through
:class:`~bracketry_emulator.slam.frame_stream.FrameFeed`: the same arrays the PNG writer would encode, named by the
same timestamps, so SLAM sees the same pixels as from PNG files, without the encode/decode round trip. PNGs are
written only when asked (``write_images``). The runs consume while the loop produces; when all are fed, each run's
exit is collected, then its metrics (timed, cached like any task).

ORB-SLAM3's settings need the frame rate before the first frame: a stream's comes from the dataset (the bracket-
cycle rate of the sequences' first frames, over the frames SLAM will track), which rounds to the same integer as a
run folder's image times.
"""

from __future__ import annotations

import contextlib
import shutil
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import TYPE_CHECKING

from bracketry_base.errors import BracketryError
from bracketry_emulator.metrics.manifest import TrajectorySpec
from bracketry_emulator.stages import StageTimes

if TYPE_CHECKING:
    from bracketry_emulator.ae.registry import MethodSpec
    from bracketry_emulator.ae.runner import LoopConfig
    from bracketry_emulator.benchmark.tasks import BenchmarkTask, RunResult

FIFO_NAME = "frames.fifo"


def stream_fps(dataset_path: str | Path, max_frames: int | None) -> tuple[float, int]:
    """The frame rate a streamed run gets in ORB-SLAM3's settings: bracket sequences per second of the dataset
    (first frame of each sequence, first side), over the first ``max_frames`` sequences when given; and the number
    of steps the closed loop will take (every sequence)."""
    from bracketry_emulator.dataset import open_dataset

    ds = open_dataset(dataset_path)
    seqs = ds.sequences()
    n_steps = len(seqs)
    if max_frames:
        seqs = seqs[:max_frames]
    side = ds.sides[0]
    times = [min(s.timestamps_ns[side].values()) for s in seqs]
    span_s = (times[-1] - times[0]) * 1e-9 if times else 0.0
    return ((len(times) - 1) / span_s if len(times) > 1 and span_s > 0 else 1.0), n_steps


def _request(task: BenchmarkTask, fifo: Path, fps: float, n_steps: int) -> dict:
    """The child's request; ``preview_index``: the run's middle frame, kept as the report's qualitative image."""
    return {**_backend_request(task, fifo, fps), "preview_index": n_steps // 2}


def _backend_request(task: BenchmarkTask, fifo: Path, fps: float) -> dict:
    from bracketry_emulator.benchmark.slam import orbslam3_options
    from bracketry_emulator.slam.orbslam3 import orbslam3_request

    if task.slam.backend == "builtin":
        return {"backend": "builtin", "run_dir": None, "frames_fifo": str(fifo), "fps": fps,
                "calibration_dir": task.calibration, "max_frames": task.max_frames}
    return orbslam3_request(None, str(task.calibration), orbslam3_options(task.slam), task.max_frames, fifo, fps)


def stream_trajectory(spec: TrajectorySpec, tasks: list[BenchmarkTask], out: Path, loop: LoopConfig, *,
                      workers: int, progress: bool, stages: StageTimes,
                      on_done: Callable[[RunResult], None] | None = None) -> list[RunResult]:
    """Closed loops (settings ``loop``, its ``write_images`` included) + SLAM (in memory) + metrics of ``tasks`` (all
    of trajectory ``spec``, none cached, none with an existing run); returns their results. See the module
    docstring."""
    from bracketry_emulator.benchmark.tasks import complete_task
    from bracketry_emulator.slam.frame_stream import FrameFeed
    from bracketry_emulator.slam.launcher import LauncherError, shared_launcher
    from bracketry_emulator.slam.orbslam3 import SlamChild, SlamRunError, start_child, wait_child

    if spec.calibration_dir() is None:
        raise BracketryError(f"{spec.path}: no calibration/ folder with left/right camera_info YAMLs")
    fps, n_steps = stream_fps(spec.path, tasks[0].max_frames)
    children: dict[str, SlamChild] = {}
    errors: dict[str, str] = {}
    feeds: dict[str, list[FrameFeed]] = {}
    methods = list(dict.fromkeys(t.method_spec for t in tasks))
    ok = False
    launcher = shared_launcher()  # the children forked by one server that imported their modules once
    try:
        for t in tasks:
            vo_dir = t.vo_path
            vo_dir.mkdir(parents=True, exist_ok=True)
            fifo = FrameFeed.make_fifo(vo_dir / FIFO_NAME)
            try:
                children[t.key] = start_child(_request(t, fifo, fps, n_steps), vo_dir, launcher=launcher)
            except SlamRunError as exc:  # e.g. a vocabulary gone missing: this run fails, the others go on
                errors[t.key] = str(exc)
                continue
            feeds.setdefault(t.method, []).append(FrameFeed(fifo, reader_pid=children[t.key].proc.pid))
        run_dirs = emulate_feeding(spec.path, methods, out / "runs" / spec.name, feeds, loop, workers=workers,
                                   progress=progress, stages=stages)
        ok = True
    finally:
        if not ok:  # the closed loop failed: its SLAM runs wait for frames that will never come
            for child in children.values():
                with contextlib.suppress(OSError):
                    child.proc.kill()
                with contextlib.suppress(ChildProcessError, LauncherError):
                    child.proc.wait()
    results = []
    for t in tasks:
        run_dir = run_dirs[t.method]
        info, error = None, errors.get(t.key)
        started = children.get(t.key)
        if started is not None:
            try:
                info = wait_child(started)
            except SlamRunError as exc:
                error = str(exc)
        (t.vo_path / FIFO_NAME).unlink(missing_ok=True)
        result = complete_task(t, run_dir, info, error)
        if on_done:
            on_done(result)
        results.append(result)
    return results


def emulate_feeding(dataset_path: Path, methods: Sequence[str | MethodSpec], runs_dir: Path,
                    feeds: dict[str, list],
                    cfg: LoopConfig, *, workers: int, progress: bool, stages: StageTimes) -> dict[str, Path]:
    """One closed-loop pass of ``methods`` over the dataset with settings ``cfg`` whose steps go to ``feeds``
    ({method name: [FrameFeed]}); the runs' files (ae.csv, steps, summaries; images only with ``cfg.write_images``)
    replace any earlier ones in ``runs_dir/<method>``. Returns {method: its folder}."""
    from bracketry_emulator.ae import run_methods
    from bracketry_emulator.benchmark.emulated_runs import check_options, mark_made_by, method_name

    check_options(runs_dir, cfg)
    tmp_root = runs_dir / ".partial"
    shutil.rmtree(tmp_root, ignore_errors=True)
    tmp_root.mkdir(parents=True)
    summary = run_methods(dataset_path, methods, tmp_root, workers=max(0, workers), progress=progress, config=cfg,
                          feeds=feeds)
    stages.merge(summary.stages)
    finals = {}
    for m in methods:
        method = method_name(m)
        final = runs_dir / method
        if final.exists():
            shutil.rmtree(final)
        (tmp_root / method).rename(final)
        mark_made_by(final, m)
        finals[method] = final
    for extra in tmp_root.iterdir():  # summary.json, exposures.csv, exposure_times.png of the pass
        if extra.is_file():
            extra.replace(runs_dir / f"closedloop_{extra.name}")
    shutil.rmtree(tmp_root, ignore_errors=True)
    return finals
