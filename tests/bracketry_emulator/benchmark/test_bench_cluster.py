"""The benchmark's cluster path (benchmark/cluster.py): a worker's checks of shared storage and the vocabulary, the
units of work, and a scheduler that goes away mid-run (a real Dask scheduler and worker, processes of the test)."""

from __future__ import annotations

import os
import subprocess
import sys
import time
from pathlib import Path

import pytest

from bracketry_base.errors import BracketryError
from bracketry_emulator.benchmark.cluster import (
    TOKEN_NAME,
    WorkerChecks,
    check_worker,
    make_units,
    slurm_job_settings,
    slurm_walltime,
)

HERE = Path(__file__).resolve().parent


def _checks(tmp_path: Path, **kw) -> WorkerChecks:
    out = tmp_path / "out"
    out.mkdir(exist_ok=True)
    (out / TOKEN_NAME).write_text("abc")
    data = tmp_path / "data"
    data.mkdir(exist_ok=True)
    return WorkerChecks(**{"out": str(out), "token": "abc", "inputs": (str(data),), **kw})


def test_worker_checks_name_the_path_a_node_cannot_see(tmp_path: Path) -> None:
    check_worker(_checks(tmp_path))  # all there: no error
    with pytest.raises(BracketryError, match=r"sees another folder at the output folder .*/out \(the dataset"):
        check_worker(_checks(tmp_path, token="other"))  # a folder of the same name that is not the shared one
    with pytest.raises(BracketryError, match=r"cannot read the output folder .*/nowhere"):
        check_worker(_checks(tmp_path, out=str(tmp_path / "nowhere")))
    missing = tmp_path / "not_mounted" / "walk1"
    with pytest.raises(BracketryError, match=f"cannot read {missing} "):
        check_worker(_checks(tmp_path, inputs=(str(missing),)))
    voc = tmp_path / "voc.txt"
    with pytest.raises(BracketryError, match=f"cannot read the ORB-SLAM3 vocabulary {voc}"):
        check_worker(_checks(tmp_path, vocabulary=str(voc), vocabulary_id="voc.txt:0"))
    voc.write_text("10 5 0 0\n")  # header only: refused by the DBoW2 check, on the worker
    with pytest.raises(BracketryError, match=r"voc\.txt"):
        check_worker(_checks(tmp_path, vocabulary=str(voc), vocabulary_id="voc.txt:0"))


def test_job_settings_from_options_or_jobqueue_config_and_one_line_without(monkeypatch) -> None:
    import dask

    from bracketry_emulator.benchmark.cluster import SlurmOptions

    with dask.config.set({"jobqueue.slurm.cores": None, "jobqueue.slurm.memory": None,
                          "jobqueue.slurm.worker-extra-args": ["--host", "127.0.0.1"]}):
        with pytest.raises(BracketryError, match=r"pass --job-cores or set jobqueue\.slurm\.cores"):
            slurm_job_settings(SlurmOptions(jobs=2))
        kw = slurm_job_settings(SlurmOptions(jobs=2, cores=4, memory="8GB", walltime="01:30:00", partition="cpu"))
    assert kw == {"cores": 4, "memory": "8GB", "walltime": "01:30:00", "queue": "cpu",
                  "worker_extra_args": ["--host", "127.0.0.1", "--nthreads", "1"]}
    with dask.config.set({"jobqueue.slurm.cores": 2, "jobqueue.slurm.memory": "1GB"}):
        assert "cores" not in slurm_job_settings(SlurmOptions(jobs=1))  # dask-jobqueue reads its own config
    assert slurm_walltime(5400) == "01:30:00" and slurm_walltime(59.2) == "00:01:00"


def test_units_one_per_trajectory_when_streamed(tmp_path: Path) -> None:
    from bracketry_emulator.ae.runner import LoopConfig
    from bracketry_emulator.benchmark import make_task
    from bracketry_emulator.metrics.manifest import TrajectorySpec

    specs = [TrajectorySpec(name=f"t{i}", path=tmp_path / f"t{i}", subset="s") for i in (1, 2)]
    tasks = [make_task(s, m, tmp_path / "out", repeat=r) for s in specs for m in ("ae50", "dim") for r in (0, 1)]
    units = make_units(specs, tasks, LoopConfig(), stream=True)
    assert [(u.spec.name if u.spec else None, len(u.tasks)) for u in units] == [("t1", 4), ("t2", 4)]
    assert [len(u.tasks) for u in make_units(specs, tasks, LoopConfig(), stream=False)] == [1] * 8


@pytest.mark.slow
def test_scheduler_gone_is_one_line_and_the_same_command_resumes(tmp_path: Path) -> None:
    """A Dask scheduler and worker (processes of this test, 127.0.0.1); the run is held at the gate, the scheduler
    is killed: one error line, exit 2; the same command on a new scheduler finishes from the cache."""
    ds = tmp_path / "walk"
    subprocess.run([sys.executable, "-m", "bracketry", "synth", "trajectory", "--out", str(ds), "--duration-s", "2",
                    "--resolution", "320x200", "--fps", "15", "--brackets-ms", "2,8,32", "-q"], check=True,
                   capture_output=True)
    gate = tmp_path / "gate"
    env = {**os.environ, "PYTHONPATH": os.pathsep.join([str(HERE), os.environ.get("PYTHONPATH", "")])}
    procs: list[subprocess.Popen] = []

    def cluster(name: str) -> str:
        sched_file = tmp_path / f"{name}.json"
        procs.append(subprocess.Popen([sys.executable, "-m", "distributed.cli.dask_scheduler", "--host", "127.0.0.1",
                                       "--port", "0", "--no-dashboard", "--scheduler-file", str(sched_file)],
                                      env=env, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL))
        procs.append(subprocess.Popen([sys.executable, "-m", "distributed.cli.dask_worker", "--scheduler-file",
                                       str(sched_file), "--host", "127.0.0.1", "--nthreads", "1", "--no-nanny",
                                       "--death-timeout", "5", "--no-dashboard"], env=env,
                                      stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL))
        _wait(lambda: sched_file.exists() and b"address" in sched_file.read_bytes())
        import json

        return json.loads(sched_file.read_text())["address"]

    def bench(address: str) -> subprocess.Popen:
        return subprocess.Popen([sys.executable, "-m", "bracketry", "benchmark", str(ds), "--out", str(tmp_path / "o"),
                                 "--slam", "builtin", "--methods", "ae50,slurm_gate_plugin:Gated", "--method-option",
                                 f"gated.gate={gate}", "--windows", "1", "-q", "--resume", "--scheduler", address],
                                env=env,
                                stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)

    try:
        first = bench(cluster("a"))
        _wait(lambda: any(tmp_path.glob("gate.started.*")))
        procs[0].kill()  # the scheduler goes away mid-run
        procs[0].wait()
        out, err = first.communicate(timeout=300)
        assert first.returncode == 2, (out, err)
        last = err.strip().splitlines()[-1]
        assert last.startswith("error: lost the Dask scheduler") and "the same command resumes" in last, err
        assert "Traceback" not in err, err
        procs[1].kill()  # its worker, held at the gate
        procs[1].wait()
        gate.touch()
        second = bench(cluster("b"))
        out, err = second.communicate(timeout=600)
        assert second.returncode == 0, (out, err)
        assert sorted(x.split(":")[0] for x in out.splitlines() if x.startswith(("done", "cached"))) == \
            ["done   walk / ae50", "done   walk / gated"]
    finally:
        gate.touch()
        for p in procs:
            if p.poll() is None:
                p.kill()
                p.wait()


def _wait(predicate, timeout_s: float = 120.0) -> None:
    deadline = time.monotonic() + timeout_s
    while not predicate():
        assert time.monotonic() < deadline, "timed out"
        time.sleep(0.05)
