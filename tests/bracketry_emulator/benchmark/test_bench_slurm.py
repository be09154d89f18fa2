"""``bracketry benchmark --cluster slurm`` on a real one-node Slurm (munged, slurmctld, slurmd started by the test).

Each run holds its units at a gate (:mod:`slurm_gate_plugin`) until the test has ended a job of its choosing (scancel,
or Slurm's own walltime kill), then opens it: the report must be complete, each run computed once (one ``done``
line, no cache hit), and equal to a local run of the same command. Everything waits on events (files, job states),
never on a sleep of a guessed length.
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
from collections.abc import Iterator
from pathlib import Path

import pytest
from slurm_node import SlurmNode, start_slurm

from bracketry.cli import main as cli_main

pytestmark = pytest.mark.slow

HERE = Path(__file__).resolve().parent
PLUGIN = "slurm_gate_plugin:Gated"
#: result fields that name where a run went or how long it took (the rest must be equal to the byte)
_WHERE = ("run_dir", "vo_dir", "stages", "cached", "s_per_frame")
JOBQUEUE_YAML = """\
jobqueue:
  slurm:
    cores: 1
    memory: 1GB
    walltime: "00:10:00"
    death-timeout: 30
    local-directory: {root}/dask-worker
    log-directory: {root}/jobs
    scheduler-options: {{host: 127.0.0.1, dashboard: false}}
    worker-extra-args: ["--host", "127.0.0.1"]
"""


@pytest.fixture(scope="module")
def slurm(tmp_path_factory) -> Iterator[SlurmNode]:
    node = start_slurm(tmp_path_factory.mktemp("slurm"), cpus=4)
    try:
        yield node
    finally:
        left = node.stop()
    assert not left, f"processes left running after the tests: {left}"


@pytest.fixture(scope="module")
def datasets(tmp_path_factory) -> list[Path]:
    """Two short synthetic walks (320x200, 3 brackets, 20 steps)."""
    root = tmp_path_factory.mktemp("slurm_data")
    out = []
    for seed in (1, 2):
        d = root / f"walk{seed}"
        assert cli_main(["synth", "trajectory", "--out", str(d), "--duration-s", "4", "--resolution", "320x200",
                         "--fps", "15", "--brackets-ms", "2,8,32", "--seed", str(seed), "-q"]) == 0
        out.append(d)
    return out


#: ORB-SLAM3 in lockstep (what a run tracks does not depend on the job's CPU share; fed unpaced, a run on a loaded
#: node lost a walk its local twin kept), the project's default vocabulary (built once into the user cache, never
#: downloaded)
ORBSLAM3 = ("--slam", "orbslam3", "--slam-pace", "lockstep", "--no-setup-check")
BUILTIN = ("--slam", "builtin")


def _args(datasets: list[Path], out: Path, gate: Path, slam: tuple[str, ...], *extra: str) -> list[str]:
    return ["benchmark", *map(str, datasets), "--out", str(out), *slam, "--methods", f"ae50,{PLUGIN}",
            "--method-option", f"gated.gate={gate}", "--windows", "1", "-q", "--resume", *extra]


def _env(root: Path, slurm: SlurmNode) -> dict[str, str]:
    dask_dir = root / "dask"
    dask_dir.mkdir(exist_ok=True)
    (dask_dir / "jobqueue.yaml").write_text(JOBQUEUE_YAML.format(root=root))
    (root / "jobs").mkdir(exist_ok=True)
    path = os.pathsep.join([str(HERE), os.environ.get("PYTHONPATH", "")])
    return slurm.env({**os.environ, "DASK_CONFIG": str(dask_dir), "PYTHONPATH": path})


def _results(out: Path) -> list[dict]:
    return [{k: v for k, v in r.items() if k not in _WHERE}
            for r in json.loads((out / "report" / "results.json").read_text())]


def _local(datasets: list[Path], root: Path, slam: tuple[str, ...]) -> tuple[Path, Path]:
    """The local run (gate open from the start); (its output, the gate path every run names)."""
    gate = root / "gate"
    gate.touch()
    env = {**os.environ, "PYTHONPATH": os.pathsep.join([str(HERE), os.environ.get("PYTHONPATH", "")])}
    subprocess.run([sys.executable, "-m", "bracketry", *_args(datasets, root / "out", gate, slam)], env=env,
                   check=True, capture_output=True, timeout=900)
    gate.unlink()
    return root / "out", gate


@pytest.fixture(scope="module")
def local(datasets, tmp_path_factory) -> tuple[Path, Path]:
    return _local(datasets, tmp_path_factory.mktemp("slurm_local"), BUILTIN)


def _started(gate: Path) -> list[Path]:
    return sorted(gate.parent.glob(f"{gate.name}.started.*"))


def _running(slurm: SlurmNode) -> list[str]:
    return sorted(j for j, s in slurm.jobs().items() if s == "RUNNING")


def _slurm_run(slurm: SlurmNode, datasets: list[Path], local: tuple[Path, Path], tmp_path: Path, end_job,
               slam: tuple[str, ...] = BUILTIN) -> str:
    """The benchmark on Slurm with 2 jobs; when both hold a run at the gate, ``end_job(job id)`` ends one and
    returns the state to wait for; then the gate opens. Checks the outcome; returns the benchmark's output."""
    local_out, gate = local
    out = tmp_path / "out"
    log = tmp_path / "bench.log"
    for old in _started(gate):
        old.unlink()
    with open(log, "wb") as fh:
        proc = subprocess.Popen(slurm.command(sys.executable, "-m", "bracketry",
                                              *_args(datasets, out, gate, slam, "--cluster", "slurm", "--jobs", "2")),
                                env=_env(tmp_path, slurm), cwd=tmp_path, stdout=fh, stderr=subprocess.STDOUT)
    try:
        slurm.wait_for(lambda: len(_started(gate)) >= 2 or proc.poll() is not None, "both jobs to hold a run", 300)
        assert proc.poll() is None, log.read_text()
        victim = _running(slurm)[0]
        state = end_job(victim)
        slurm.wait_for(lambda: slurm.jobs().get(victim) == state, f"job {victim} to be {state}", 300)
        gate.touch()
        assert proc.wait(timeout=600) == 0, log.read_text()
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()
        gate.unlink(missing_ok=True)
    text = log.read_text()
    assert len(_started(gate)) == 3  # the two first units and the ended job's unit again, nowhere else
    done = sorted(line.split(":")[0] for line in text.splitlines() if line.startswith(("done", "cached", "failed")))
    assert done == [f"done   walk{s} / {m}" for s in (1, 2) for m in ("ae50", "gated")], text  # each once
    if slam == BUILTIN:
        assert _results(out) == _results(local_out)  # complete, and equal to the byte to a local run
    else:  # ORB-SLAM3's threads make each run differ a little: complete, every run tracked as locally
        mine, theirs = _results(out), _results(local_out)
        assert [(r["trajectory"], r["method"], r.get("error"), r["n_frames"], r["success"]) for r in mine] == \
            [(r["trajectory"], r["method"], r.get("error"), r["n_frames"], r["success"]) for r in theirs]
    slurm.wait_for(lambda: not slurm.namespace_pids(), "every job to be released and its processes gone",
                   details=lambda: slurm.describe(slurm.namespace_pids()))
    return text


def test_bench_slurm_cancelled_job_rerun_complete_and_equal_to_local(slurm, datasets, local, tmp_path) -> None:
    def cancel(job: str) -> str:
        slurm.run("scancel", job)
        return "CANCELLED"

    _slurm_run(slurm, datasets, local, tmp_path, cancel)


def test_bench_slurm_job_killed_by_its_walltime_is_rerun(slurm, datasets, local, tmp_path) -> None:
    def walltime(job: str) -> str:  # Slurm's time limits are whole minutes: this job ends about a minute from its start
        slurm.run("scontrol", "update", f"JobId={job}", "TimeLimit=1")
        return "TIMEOUT"

    _slurm_run(slurm, datasets, local, tmp_path, walltime)


@pytest.mark.orbslam3
def test_bench_slurm_orbslam3_cancelled_job_rerun_complete(slurm, datasets, tmp_path_factory, tmp_path) -> None:
    local = _local(datasets, tmp_path_factory.mktemp("slurm_local_orbslam3"), ORBSLAM3)

    def cancel(job: str) -> str:
        slurm.run("scancel", job)
        return "CANCELLED"

    _slurm_run(slurm, datasets, local, tmp_path, cancel, ORBSLAM3)
