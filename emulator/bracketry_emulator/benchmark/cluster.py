"""The benchmark on a Dask cluster: a scheduler the user runs (``--scheduler``) or Slurm jobs (``--cluster slurm``).

Work goes out in *units*: a trajectory's runs still to do (every method and repeat; not cached, no existing run) in
one shared pass (:func:`~bracketry_emulator.benchmark.stream.stream_trajectory`: each bracket sequence decoded once
for all methods, SLAM fed in memory), as locally; a task that cannot be streamed (a dataset's own run, external SLAM
trajectories, an ORB-SLAM export) is a unit of its own. A unit checks its worker first (:func:`check_worker`: the
dataset, output and cache on storage this node sees, the ORB-SLAM3 vocabulary the same file), loads what the cache
already holds and runs the rest; each finished run is in the cache (written atomically) before the unit returns.

Faults: a worker that dies (a cancelled job, a walltime, a killed process) loses its unit; the scheduler runs it again
on another worker, which finds the runs that finished in the cache and runs only the others, so no run is computed
twice and nothing partial reaches the report (a run's SLAM output is replaced when it starts again, its result is
only what :func:`~bracketry_emulator.benchmark.tasks.complete_task` wrote). A scheduler that goes away is one line
(:class:`ClusterLost`) saying that the same command with ``--resume`` resumes from the cache.

Slurm (:func:`slurm_cluster`): dask-jobqueue's ``SLURMCluster``, one worker process per job (no nanny, so a unit
may fork its closed-loop workers), at most ``jobs`` jobs (adaptive: fewer as the work runs out), all cancelled at the
end. Cores, memory, walltime, partition and account come from the options or from dask-jobqueue's own configuration
(``jobqueue.slurm`` in ``~/.config/dask/jobqueue.yaml`` or ``$DASK_CONFIG``). See docs/CLUSTER.md.
"""

from __future__ import annotations

import contextlib
import functools
import logging
import os
import socket
from collections.abc import Callable, Iterator
from dataclasses import dataclass, replace
from pathlib import Path
from typing import TYPE_CHECKING, Any

from bracketry_base.errors import BracketryError
from bracketry_emulator.benchmark.tasks import BenchmarkTask, RunResult, load_cached, run_task
from bracketry_emulator.metrics.manifest import TrajectorySpec
from bracketry_emulator.option_table import slurm_walltime as slurm_walltime

if TYPE_CHECKING:
    from bracketry_emulator.ae.runner import LoopConfig

#: the file a unit reads on its worker to prove the output folder is the one the benchmark writes (shared storage)
TOKEN_NAME = ".cluster_token"


class ClusterLost(BracketryError):
    """The scheduler (or the connection to it) went away mid-run; the cache holds every run that finished."""


@dataclass(frozen=True)
class SlurmOptions:
    """``--cluster slurm``: at most ``jobs`` Slurm jobs, one Dask worker each. ``cores`` (per job; also the unit's
    closed-loop processes), ``memory`` (per job, e.g. ``8GB``), ``walltime`` (``HH:MM:SS``), ``partition`` and
    ``account``: None takes dask-jobqueue's configuration (``jobqueue.slurm.*``)."""

    jobs: int
    cores: int | None = None
    memory: str | None = None
    walltime: str | None = None
    partition: str | None = None
    account: str | None = None


@dataclass(frozen=True)
class Unit:
    """What one worker runs at once: ``tasks`` (all of one trajectory when ``spec`` is set: one shared pass with
    closed-loop settings ``loop``; else a single task run alone)."""

    tasks: tuple[BenchmarkTask, ...]
    spec: TrajectorySpec | None = None
    loop: LoopConfig | None = None


@dataclass(frozen=True)
class WorkerChecks:
    """What a worker must see before it runs anything: ``token`` in ``out/.cluster_token`` (the output folder, and
    the cache under it, are the benchmark's own), ``inputs`` readable (datasets, calibrations, references, weights),
    and, with ORB-SLAM3, ``vocabulary`` a usable DBoW2 file whose content id is ``vocabulary_id``."""

    out: str
    token: str
    inputs: tuple[str, ...]
    vocabulary: str | None = None
    vocabulary_id: str | None = None


def make_units(specs: list[TrajectorySpec], tasks: list[BenchmarkTask], loop: LoopConfig, stream: bool) -> list[Unit]:
    """The units of ``tasks``: with ``stream``, one per trajectory for its tasks without an existing run (order of
    ``specs``), then one per remaining task."""
    units: list[Unit] = []
    rest = list(tasks)
    if stream:
        for spec in specs:
            mine = tuple(t for t in tasks if t.trajectory == spec.name and not t.existing_run)
            if mine:  # the trajectory's own warm-up (its tasks share it)
                units.append(Unit(mine, spec, replace(loop, warmup_steps=mine[0].loop.warmup_steps)))
        grouped = {t.key for u in units for t in u.tasks}
        rest = [t for t in tasks if t.key not in grouped]
    return units + [Unit((t,)) for t in rest]


def worker_checks(out: Path, tasks: list[BenchmarkTask], vocabulary: str | None,
                  vocabulary_id: str | None) -> WorkerChecks:
    """The checks of :func:`check_worker` for ``tasks``; writes a fresh token into ``out``."""
    token = os.urandom(8).hex()
    (out / TOKEN_NAME).write_text(token)
    inputs = {p for t in tasks for p in (t.dataset, t.calibration, t.groundtruth, t.existing_run, t.drl_weights,
                                          t.slam_dir) if p}
    return WorkerChecks(str(out), token, tuple(sorted(inputs)), vocabulary, vocabulary_id)


def _unreadable(path: str) -> bool:
    p = Path(path)
    return not os.access(p, os.R_OK) or (p.is_dir() and not os.access(p, os.X_OK)) or not p.exists()


@functools.cache
def _checked_vocabulary(path: str, size: int, mtime_ns: int) -> str:
    """The vocabulary's content id after its check (once per file version and worker process)."""
    from bracketry_emulator.benchmark.slam import file_id
    from bracketry_emulator.slam.vocabulary_check import check_vocabulary

    check_vocabulary(path)
    return file_id(path)


def check_worker(checks: WorkerChecks) -> None:
    """Raise one line naming this host and the path when this worker cannot see what the benchmark needs."""
    host = socket.gethostname()
    hint = "(the dataset, the output and the cache must be on storage every node mounts at the same path)"
    token = Path(checks.out) / TOKEN_NAME
    try:
        seen = token.read_text()
    except OSError:
        seen = None
    if seen != checks.token:
        what = "cannot read" if seen is None else "sees another folder at"
        raise BracketryError(f"worker on {host} {what} the output folder {checks.out} {hint}")
    if not os.access(checks.out, os.W_OK):
        raise BracketryError(f"worker on {host} cannot write the output folder {checks.out} {hint}")
    for path in checks.inputs:
        if _unreadable(path):
            raise BracketryError(f"worker on {host} cannot read {path} {hint}")
    if checks.vocabulary is not None:
        voc = Path(checks.vocabulary)
        try:
            st = voc.stat()
        except OSError:
            raise BracketryError(f"worker on {host} cannot read the ORB-SLAM3 vocabulary {voc} (copy it to the same "
                                 f"path on every node, or onto shared storage; it is never downloaded)") from None
        found = _checked_vocabulary(str(voc), st.st_size, st.st_mtime_ns)
        if checks.vocabulary_id and found != checks.vocabulary_id:
            raise BracketryError(f"worker on {host}: the ORB-SLAM3 vocabulary {voc} is {found}, not "
                                 f"{checks.vocabulary_id} as where the benchmark started (the same file on every "
                                 "node)")


def run_unit(unit: Unit, checks: WorkerChecks, cores: int) -> list[RunResult]:
    """On a worker: check it (:func:`check_worker`), then the unit's results in task order (cached ones loaded,
    the others run; ``cores``: the closed-loop processes of a shared pass)."""
    check_worker(checks)
    if unit.spec is None or unit.loop is None:
        return [run_task(t) for t in unit.tasks]
    from bracketry_emulator.runtime_policy import apply_profile

    apply_profile("task")
    from bracketry_emulator.benchmark.stream import stream_trajectory
    from bracketry_emulator.stages import StageTimes

    done: dict[str, RunResult] = {}
    todo = []
    for t in unit.tasks:
        cached = load_cached(t)
        if cached is not None:
            done[t.key] = replace(cached, cached=True)
        else:
            todo.append(t)
    if todo:
        out = Path(unit.tasks[0].out)
        for r in stream_trajectory(unit.spec, todo, out, unit.loop, workers=max(1, cores), progress=False,
                                   stages=StageTimes()):
            done[r.key] = r
    return [done[t.key] for t in unit.tasks]


def _lost(address: str, exc: BaseException, n_done: int, n_units: int) -> ClusterLost:
    return ClusterLost(f"lost the Dask scheduler {address} after {n_done} of {n_units} work units "
                       f"({type(exc).__name__}: {exc or 'no detail'}); every finished run is in the cache: the same "
                       "command resumes with --resume")


def run_units(client: Any, units: list[Unit], checks: WorkerChecks, cores: int,
              on_done: Callable[[RunResult], None] | None, address: str) -> list[RunResult]:
    """Submit ``units`` through ``client`` and gather their results (each unit's as it completes, to ``on_done``).
    A lost scheduler raises :class:`ClusterLost`; a unit's own error (a worker that cannot see the data) is raised as
    it is."""
    from concurrent.futures import CancelledError

    from distributed import as_completed

    futures = [client.submit(run_unit, u, checks, cores, pure=False, key=f"unit-{i}-{os.urandom(4).hex()}")
               for i, u in enumerate(units)]
    results: dict[str, list[RunResult]] = {}
    try:
        for f in as_completed(futures):
            rs = f.result()
            results[f.key] = rs
            if on_done:
                for r in rs:
                    on_done(r)
    except (OSError, CancelledError, TimeoutError) as exc:
        from distributed.comm.core import CommClosedError

        if isinstance(exc, OSError) and not isinstance(exc, CommClosedError) and client.status == "running":
            raise  # a unit's own error on its worker (e.g. a full disk), not the connection
        raise _lost(address, exc, len(results), len(units)) from exc
    return [r for f in futures for r in results[f.key]]


@contextlib.contextmanager
def _quiet_client() -> Iterator[None]:
    """Dask's client logs a traceback when it loses its scheduler (while it runs and while it closes): the
    :class:`ClusterLost` line says it, so its errors are kept out of the terminal for the client's lifetime."""
    logger = logging.getLogger("distributed.client")
    level = logger.level
    logger.setLevel(logging.CRITICAL)
    try:
        yield
    finally:
        logger.setLevel(level)


@contextlib.contextmanager
def connect(address: str) -> Iterator[Any]:
    """A Dask client of the scheduler at ``address`` (one line when it cannot be reached)."""
    try:
        from distributed import Client
    except ImportError as exc:
        raise BracketryError("--scheduler needs dask.distributed (install the emulator extra)") from exc
    try:
        client = Client(address, timeout=30)
    except OSError as exc:
        raise BracketryError(f"cannot reach the Dask scheduler {address}: {exc}") from exc
    with _quiet_client():
        try:
            yield client
        finally:
            with contextlib.suppress(Exception):
                client.close()


def slurm_job_settings(opts: SlurmOptions) -> dict[str, Any]:
    """The SLURMCluster keyword arguments of ``opts`` (the options given, else dask-jobqueue's configuration); one
    line naming the missing setting when cores or memory are nowhere."""
    import dask

    def conf(name: str) -> Any:
        return dask.config.get(f"jobqueue.slurm.{name}", default=None)

    given = {"cores": opts.cores, "memory": opts.memory, "walltime": opts.walltime, "queue": opts.partition,
             "account": opts.account}
    kw: dict[str, Any] = {k: v for k, v in given.items() if v is not None}
    for key, option, name in (("cores", "--job-cores", "cores"), ("memory", "--job-memory", "memory")):
        if key not in kw and conf(name) is None:
            raise BracketryError(f"--cluster slurm needs the {name} of a job: pass {option} or set "
                                 f"jobqueue.slurm.{name} in dask-jobqueue's configuration (docs/CLUSTER.md)")
    extra = list(conf("worker-extra-args") or [])
    kw["worker_extra_args"] = [*extra, "--nthreads", "1"]  # one unit at a time per job; its cores go to the unit
    return kw


def import_slurm_cluster() -> Any:
    """``dask_jobqueue.SLURMCluster``, imported without writing into the user's home: dask-jobqueue's import copies
    its ``jobqueue.yaml`` into dask's config folder (``~/.config/dask`` unless ``DASK_CONFIG``); that folder is a
    temporary one during the import (its defaults are loaded from the package all the same)."""
    import tempfile

    import dask.config

    with tempfile.TemporaryDirectory(prefix="bracketry-dask-") as tmp:
        path = dask.config.PATH
        dask.config.PATH = tmp
        try:
            from dask_jobqueue import SLURMCluster
        finally:
            dask.config.PATH = path
    return SLURMCluster


@contextlib.contextmanager
def slurm_cluster(opts: SlurmOptions) -> Iterator[tuple[Any, str, int]]:
    """(client, scheduler address, cores per job) of a SLURMCluster with at most ``opts.jobs`` jobs (adaptive);
    every job is cancelled when the block ends (normally or not)."""
    try:
        import dask
        from distributed import Client

        SLURMCluster = import_slurm_cluster()
    except ImportError as exc:
        raise BracketryError("--cluster slurm needs dask-jobqueue (install the emulator extra)") from exc
    kw = slurm_job_settings(opts)
    try:
        cluster = SLURMCluster(processes=1, nanny=False, **kw)
    except (ValueError, OSError, RuntimeError) as exc:
        raise BracketryError(f"cannot start the Slurm cluster: {exc}") from exc
    try:
        cores = int(kw.get("cores") or dask.config.get("jobqueue.slurm.cores"))
        cluster.adapt(minimum_jobs=0, maximum_jobs=opts.jobs)
        client = Client(cluster)
        with _quiet_client():
            try:
                yield client, cluster.scheduler_address, cores
            finally:
                with contextlib.suppress(Exception):
                    client.close()
    finally:
        with contextlib.suppress(Exception):
            cluster.close()
