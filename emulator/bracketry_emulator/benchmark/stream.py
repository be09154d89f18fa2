"""One pass per trajectory: the closed loops of every method write their SLAM runs' frames, then the SLAM runs a
few at a time, then the metrics.

For each trajectory one closed-loop pass over the tasks still to do (method x repeat; each bracket frame decoded
once for every method) hands every step's stereo images to a
:class:`~bracketry_emulator.slam.frame_stream.FrameSpool` per run (``vo/<trajectory>/<run>/frames.stream``): the
same arrays the PNG writer would encode, named by the same timestamps, so SLAM sees the same pixels as from PNG
files, without the encode/decode round trip. PNGs are written only when asked (``write_images``). Then the runs'
SLAM child processes (:func:`~bracketry_emulator.slam.orbslam3.start_child`, ORB-SLAM3 or the built-in VO: a crash
stays one failed run), forked by this process's SLAM fork server (:mod:`~bracketry_emulator.slam.launcher`: Python
and the child's imports paid once per benchmark, not once per run) or, without one, started as ``python -m``, at
most :func:`slam_at_once` at a time (:class:`SlamRuns`, on a thread: the next trajectory's closed loops run
meanwhile, once every earlier run has started: :meth:`SlamRuns.wait_for_room`, so spools wait on disk for one
trajectory at most): each reads its spool (deleted when the run ends). In lockstep (each frame once
ORB-SLAM3's threads are idle) a run keeps about three quarters of a core busy, so one run more than cores fills the
machine; seven side by side on two cores cost about a quarter more CPU for the same runs (their idle threads poll,
their caches thrash: ``docs/RESULTS.md``). Each run's exit is collected as it ends, then its metrics (timed, cached
like any task).

ORB-SLAM3's settings need the frame rate before the first frame: a stream's comes from the dataset (the bracket-
cycle rate of the sequences' first frames, over the frames SLAM will track), which rounds to the same integer as a
run folder's image times.
"""

from __future__ import annotations

import contextlib
import os
import shutil
import subprocess
import threading
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
    from bracketry_emulator.slam.orbslam3 import SlamChild

#: a run's frames between its closed loop and its SLAM child, in ``vo/<trajectory>/<run>/``
SPOOL_NAME = "frames.stream"


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


def _request(task: BenchmarkTask, stream: Path, fps: float, n_steps: int) -> dict:
    """The child's request; ``preview_index``: the run's middle frame, kept as the report's qualitative image."""
    return {**_backend_request(task, stream, fps), "preview_index": n_steps // 2}


def _backend_request(task: BenchmarkTask, stream: Path, fps: float) -> dict:
    from bracketry_emulator.benchmark.slam import orbslam3_options
    from bracketry_emulator.slam.orbslam3 import orbslam3_request

    if task.slam.backend == "builtin":
        return {"backend": "builtin", "run_dir": None, "frames_fifo": str(stream), "fps": fps,
                "calibration_dir": task.calibration, "max_frames": task.max_frames}
    return orbslam3_request(None, str(task.calibration), orbslam3_options(task.slam), task.max_frames, stream, fps)


def stream_trajectory(spec: TrajectorySpec, tasks: list[BenchmarkTask], out: Path, loop: LoopConfig, *,
                      workers: int, progress: bool, stages: StageTimes,
                      on_done: Callable[[RunResult], None] | None = None) -> list[RunResult]:
    """Closed loops (settings ``loop``, its ``write_images`` included) + SLAM + metrics of ``tasks`` (all of
    trajectory ``spec``, none cached, none with an existing run); returns their results in task order, each also
    to ``on_done`` as it ends. ``workers``: the closed loop's processes (0: one per CPU); the SLAM runs go
    :func:`slam_at_once` at a time. See the module docstring."""
    with SlamRuns(slam_at_once(workers), on_done) as runs:
        runs.submit(*spool_trajectory(spec, tasks, out, loop, workers=workers, progress=progress, stages=stages))
        return runs.results(tasks)


def slam_at_once(workers: int) -> int:
    """SLAM runs alive at once for ``workers`` (the benchmark's ``--workers``; 0: one per CPU): one more. A lockstep
    run keeps about three quarters of a core busy (between frames it waits for ORB-SLAM3's threads to stay idle a
    quiet window): two runs on two cores left a quarter of them idle in the demo, seven cost a quarter more CPU
    (``docs/RESULTS.md``)."""
    return 1 + max(1, workers if workers > 0 else (os.cpu_count() or 1))


def spool_trajectory(spec: TrajectorySpec, tasks: list[BenchmarkTask], out: Path, loop: LoopConfig, *,
                     workers: int, progress: bool, stages: StageTimes
                     ) -> tuple[list[BenchmarkTask], dict[str, Path], float, int]:
    """The closed loops of ``tasks`` (one trajectory's) with every run's frames spooled to
    ``vo/<trajectory>/<run>/frames.stream``: (tasks, {method: run folder}, the streams' frame rate, steps), what
    :meth:`SlamRuns.submit` takes. A failed closed loop leaves no spool."""
    from bracketry_emulator.slam.frame_stream import FrameSpool

    if spec.calibration_dir() is None:
        raise BracketryError(f"{spec.path}: no calibration/ folder with left/right camera_info YAMLs")
    fps, n_steps = stream_fps(spec.path, tasks[0].max_frames)
    methods = list(dict.fromkeys(t.method_spec for t in tasks))
    spools: dict[str, list[FrameSpool]] = {}
    for t in tasks:
        t.vo_path.mkdir(parents=True, exist_ok=True)
        spools.setdefault(t.method, []).append(FrameSpool(t.vo_path / SPOOL_NAME))
    try:
        run_dirs = emulate_feeding(spec.path, methods, out / "runs" / spec.name, spools, loop, workers=workers,
                                   progress=progress, stages=stages)
    except BaseException:
        for t in tasks:
            (t.vo_path / SPOOL_NAME).unlink(missing_ok=True)
        raise
    return tasks, run_dirs, fps, n_steps


#: how often the SLAM runs in flight are checked for their end (s)
_POLL_S = 0.02

#: held by a :class:`SlamRuns` thread while it works (starts, collects, computes metrics, reports), never while it
#: waits; a fork of this process (the closed loop's workers) takes it first, so no forked child inherits a lock
#: that thread held (stdout's, the fork server's) at the fork
_BUSY = threading.Lock()
os.register_at_fork(before=_BUSY.acquire, after_in_parent=_BUSY.release, after_in_child=_BUSY.release)


class SlamRuns:
    """The SLAM children of spooled runs (:meth:`submit`), started in submission order with at most ``at_once``
    alive, by a thread of this process (so the next trajectory's closed loops run meanwhile); each run's metrics
    as it ends, also to ``on_done`` (called on that thread). Used as a context manager: leaving it on an error
    kills the runs still alive and deletes the spools left."""

    def __init__(self, at_once: int, on_done: Callable[[RunResult], None] | None = None) -> None:
        self.at_once = max(1, at_once)
        self.on_done = on_done
        self._waiting: list[tuple[BenchmarkTask, Path, dict]] = []
        #: runs taken from ``_waiting`` and not yet started (their request.json not yet written)
        self._starting = 0
        self._done: dict[str, RunResult] = {}
        self._cond = threading.Condition()
        self._closed = False
        self._stop = False
        self._error: BaseException | None = None
        self._thread = threading.Thread(target=self._loop, name="bracketry-slam-runs", daemon=True)
        self._thread.start()

    def __enter__(self) -> SlamRuns:
        return self

    def __exit__(self, exc_type: object, exc: object, tb: object) -> None:
        with self._cond:
            self._closed = True
            self._stop = self._stop or exc_type is not None
            self._cond.notify_all()
        self._thread.join()

    def submit(self, tasks: list[BenchmarkTask], run_dirs: dict[str, Path], fps: float, n_steps: int) -> None:
        """Queue the SLAM runs of ``tasks`` (what :func:`spool_trajectory` returns)."""
        with self._cond:
            self._raise()
            self._waiting += [(t, run_dirs[t.method], _request(t, t.vo_path / SPOOL_NAME, fps, n_steps))
                              for t in tasks]
            self._cond.notify_all()

    def wait_for_room(self) -> None:
        """Return once every submitted run has started (or the runs stopped on an error, raised here). The next
        trajectory's closed loops spool only then, so the disk holds the running runs' spools and one trajectory's
        more, not every trajectory's: the closed loops go far faster than SLAM (a full-size walk's seven runs spool
        about 2 GB)."""
        with self._cond:
            while (self._waiting or self._starting) and self._error is None and not self._stop:
                self._cond.wait()
            self._raise()

    def results(self, tasks: list[BenchmarkTask]) -> list[RunResult]:
        """Wait for every submitted run; the results of ``tasks`` in their order."""
        with self._cond:
            self._closed = True
            self._cond.notify_all()
        self._thread.join()
        self._raise()
        return [self._done[t.key] for t in tasks]

    def _raise(self) -> None:
        if self._error is not None:
            raise self._error

    def _finish(self, t: BenchmarkTask, run_dir: Path, info: dict | None, error: str | None) -> None:
        from bracketry_emulator.benchmark.tasks import complete_task

        (t.vo_path / SPOOL_NAME).unlink(missing_ok=True)
        result = complete_task(t, run_dir, info, error)
        self._done[t.key] = result
        if self.on_done:
            self.on_done(result)

    def _loop(self) -> None:
        from bracketry_emulator.slam.launcher import LauncherError, shared_launcher
        from bracketry_emulator.slam.orbslam3 import SlamRunError, child_ended, start_child, wait_child

        running: dict[str, tuple[BenchmarkTask, Path, SlamChild]] = {}
        try:
            launcher = shared_launcher()  # the children forked by one server that imported their modules once
            while True:
                with self._cond:
                    if self._stop:
                        return
                    starts: list[tuple[BenchmarkTask, Path, dict]] = []
                    while self._waiting and len(running) + len(starts) < self.at_once:
                        starts.append(self._waiting.pop(0))
                    self._starting = len(starts)
                    if not running and not starts:
                        if self._closed and not self._waiting:
                            return
                        self._cond.wait()
                        continue
                with _BUSY:
                    for t, run_dir, request in starts:
                        try:
                            running[t.key] = (t, run_dir, start_child(request, t.vo_path, launcher=launcher))
                        except SlamRunError as exc:  # e.g. a vocabulary gone missing: this run fails, the rest go on
                            self._finish(t, run_dir, None, str(exc))
                    if starts:
                        with self._cond:
                            self._starting = 0
                            self._cond.notify_all()  # wait_for_room
                    ended = [key for key, (_t, _r, child) in running.items() if child_ended(child)]
                    for key in ended:
                        t, run_dir, child = running.pop(key)
                        try:
                            info, error = wait_child(child), None
                        except SlamRunError as exc:
                            info, error = None, str(exc)
                        self._finish(t, run_dir, info, error)
                if not ended and not starts:
                    with self._cond:
                        self._cond.wait(_POLL_S)
        except BaseException as exc:  # raised in the caller's thread by submit() or results()
            self._error = exc
        finally:
            for t, _r, child in running.values():  # stopped: no run outlives the benchmark
                with contextlib.suppress(OSError, LauncherError):
                    child.proc.kill()
                with contextlib.suppress(ChildProcessError, LauncherError, subprocess.TimeoutExpired):
                    child.proc.wait(30.0)
                (t.vo_path / SPOOL_NAME).unlink(missing_ok=True)
            with self._cond:
                for t, _r, _q in self._waiting:
                    (t.vo_path / SPOOL_NAME).unlink(missing_ok=True)
                self._waiting.clear()
                self._cond.notify_all()


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
