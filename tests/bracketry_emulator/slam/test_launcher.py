"""The SLAM fork server: a forked run gives what a started one gives, failures stay one run's, nothing outlives it.

Real processes throughout (the server, its forked children, the built-in VO's runs on a small toy corridor);
ORB-SLAM3 itself is exercised through the server by the benchmark's ORB-SLAM3 tests (stream_trajectory uses it).
"""

from __future__ import annotations

import os
import resource
import time
from pathlib import Path

import pytest

from bracketry_emulator.benchmark.toyworld import ToyWorld
from bracketry_emulator.slam.frame_stream import FrameFeed
from bracketry_emulator.slam.launcher import LaunchedProcess, SlamLauncher, close_shared_launcher, shared_launcher
from bracketry_emulator.slam.orbslam3 import SlamRunError, start_child, wait_child


@pytest.fixture(scope="module")
def toy(tmp_path_factory) -> Path:
    d = tmp_path_factory.mktemp("launcher_toy")
    w = ToyWorld(width_px=160, height_px=120, fx_px=120.0)
    w.write_calibration(d)
    w.write_run(d, "ae50", 6)
    return d


@pytest.fixture(scope="module")
def launcher():
    server = SlamLauncher()
    yield server
    server.close()


def _builtin(toy: Path) -> dict:
    return {"backend": "builtin", "run_dir": str(toy / "ae50"), "frames_fifo": None, "fps": None,
            "calibration_dir": str(toy / "calibration"), "max_frames": None}


def _outputs(d: Path) -> dict[str, bytes]:
    return {p.name: p.read_bytes() for p in sorted(d.iterdir())
            if p.name == "frames.csv" or p.name.startswith("CameraTrajectory")}


def _gone(pid: int) -> bool:
    try:
        with open(f"/proc/{pid}/stat") as fh:
            return fh.read().rsplit(") ", 1)[1][:1] == "Z"
    except FileNotFoundError:
        return True


def test_a_forked_run_gives_the_bytes_of_a_started_one(toy: Path, launcher: SlamLauncher, tmp_path: Path) -> None:
    started = wait_child(start_child(_builtin(toy), tmp_path / "started"))
    child = start_child(_builtin(toy), tmp_path / "forked run é", launcher=launcher)  # any path a user has
    assert isinstance(child.proc, LaunchedProcess) and child.proc.pid != launcher.proc.pid
    forked = wait_child(child)
    assert child.proc.returncode == 0 and forked["cpu_s"] > 0 and forked["n_frames"] == started["n_frames"] == 6
    a, b = _outputs(tmp_path / "started"), _outputs(tmp_path / "forked run é")
    assert "frames.csv" in a and "CameraTrajectory0.txt" in a and a == b
    assert _gone(child.proc.pid)  # reaped by the server


def test_a_failed_run_is_one_line_and_the_server_goes_on(toy: Path, launcher: SlamLauncher, tmp_path: Path) -> None:
    bad = {**_builtin(toy), "calibration_dir": str(tmp_path / "nowhere")}
    with pytest.raises(SlamRunError, match=r"failed \(exit code 1\): error: .*nowhere") as err:
        wait_child(start_child(bad, tmp_path / "bad", launcher=launcher))
    assert "\n" not in str(err.value)
    assert (tmp_path / "bad" / "orbslam3.log").read_text().startswith("error: ")  # the run's log, not ours
    good = wait_child(start_child(_builtin(toy), tmp_path / "good", launcher=launcher))
    assert good["n_frames"] == 6 and launcher.alive()


def test_a_run_past_its_timeout_is_killed(toy: Path, launcher: SlamLauncher, tmp_path: Path) -> None:
    fifo = FrameFeed.make_fifo(tmp_path / "frames.fifo")  # nobody writes: the run waits for its first frame
    req = {**_builtin(toy), "run_dir": None, "frames_fifo": str(fifo), "fps": 4.0}
    child = start_child(req, tmp_path / "slow", timeout_s=1.0, launcher=launcher)
    t0 = time.monotonic()
    with pytest.raises(SlamRunError, match="did not finish within 1 s"):
        wait_child(child)
    assert time.monotonic() - t0 < 30 and _gone(child.proc.pid)


def test_closing_the_server_kills_its_runs_and_a_wait_fails_in_one_line(toy: Path, tmp_path: Path) -> None:
    server = SlamLauncher()
    fifo = FrameFeed.make_fifo(tmp_path / "frames.fifo")
    req = {**_builtin(toy), "run_dir": None, "frames_fifo": str(fifo), "fps": 4.0}
    child = start_child(req, tmp_path / "orphan", launcher=server)
    pid = child.proc.pid
    assert not _gone(pid)
    server.close()
    assert server.proc.returncode == 0 and _gone(pid)
    with pytest.raises(SlamRunError, match="fork server ended before the run"):
        wait_child(child)


def test_a_gone_server_falls_back_to_a_started_child(toy: Path, tmp_path: Path) -> None:
    server = SlamLauncher()
    server.close()
    child = start_child(_builtin(toy), tmp_path / "fallback", launcher=server)
    assert not isinstance(child.proc, LaunchedProcess)
    assert wait_child(child)["n_frames"] == 6


def _children_cpu_s() -> float:
    u = resource.getrusage(resource.RUSAGE_CHILDREN)
    return u.ru_utime + u.ru_stime


def test_shared_launcher_switch_and_its_runs_cpu_once_closed(toy: Path, tmp_path: Path,
                                                              monkeypatch: pytest.MonkeyPatch) -> None:
    """One server per process (off with BRACKETRY_SLAM_LAUNCHER=0); its runs' CPU time reaches this process's
    RUSAGE_CHILDREN (what the demo's CPU per step reads) when the server is closed and reaped."""
    monkeypatch.setenv("BRACKETRY_SLAM_LAUNCHER", "0")
    assert shared_launcher() is None
    monkeypatch.delenv("BRACKETRY_SLAM_LAUNCHER")
    close_shared_launcher()
    server = shared_launcher()
    assert server is not None and server.alive() and shared_launcher() is server
    assert os.getpid() != server.proc.pid
    info = wait_child(start_child(_builtin(toy), tmp_path / "run", launcher=server))
    before = _children_cpu_s()
    close_shared_launcher()
    assert not server.alive() and shared_launcher() is not server
    assert _children_cpu_s() - before >= info["cpu_s"]
    close_shared_launcher()
