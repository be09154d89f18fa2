"""ORB-SLAM3 (stereo, through ``pyorbslam3``) over an emulated run, one run per child process.

:func:`run_orbslam3` starts ``python -m bracketry_emulator.slam.orbslam3_child`` and waits: ORB-SLAM3 segfaults on
some settings and calls ``exit()`` on a bad vocabulary header, so it never runs inside the benchmark's own process.
The child's stdout and stderr file descriptors (where the C++ library prints) go straight into
``<out>/orbslam3.log``. A failed run raises :class:`SlamRunError` naming the exit status and the log's last line.

Output (``out_dir``), the same as the built-in VO's (:mod:`bracketry_emulator.vo.runner`) so the metrics read both:
``frames.csv``, ``CameraTrajectory<n>.txt`` (one per tracked segment), plus ``settings.yaml`` (what ORB-SLAM3 read),
``orbslam3.log`` and ``slam.json`` (backend, vocabulary, pace, loop closing, seconds per frame).

Per-frame states come from the tracking state ORB-SLAM3 returns for every frame, never from its trajectory files
(``SaveTrajectoryTUM`` concatenates all maps, each in its own frame, and repeats the last pose for lost frames):

* ``OK`` -> OK, the first OK frame after any other state -> INIT (a new segment);
* ``RECENTLY_LOST`` -> LOST (its pose is an identity placeholder), ``LOST`` likewise;
* ``NO_IMAGES_YET`` / ``NOT_INITIALIZED`` (a new map starts: ORB-SLAM3 restarts at identity) -> LOST.

So segments split at every loss or new map. ``n_map_matches`` = map points tracked in the frame; ``n_keypoints`` and
``coverage`` come from our ORB extractor at the paper's settings (same as the built-in VO); ``n_slam_keypoints`` is
ORB-SLAM3's own keypoint count in the frame (its stereo start needs more than 500); ``n_stereo`` and
``n_ref_matches`` are unknown (NaN).
"""

from __future__ import annotations

import contextlib
import json
import os
import signal
import subprocess
import sys
import time
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import TYPE_CHECKING

from bracketry_base.errors import BracketryError

if TYPE_CHECKING:
    from bracketry_emulator.slam.launcher import LaunchedProcess, SlamLauncher

STATE_MAP = {"OK": "OK", "OK_KLT": "OK", "RECENTLY_LOST": "LOST", "LOST": "LOST", "NO_IMAGES_YET": "LOST",
             "NOT_INITIALIZED": "LOST", "SYSTEM_NOT_READY": "LOST"}


class SlamRunError(BracketryError):
    """One SLAM run failed (crash, exit, bad settings or vocabulary); the message is one line."""


@dataclass(frozen=True)
class OrbSlam3Options:
    """How ORB-SLAM3 runs.

    vocabulary: DBoW2 text file. pace_s: wall-clock seconds between fed frames (0 = as fast as possible, None = the
    recording's own timestamps, i.e. real time). lockstep: each frame fed once ORB-SLAM3's local mapping and loop
    closing threads are idle (:mod:`.quiescence`; ``pace_s`` is then not used). loop_closing: the loop-closing
    thread (also relocalisation).
    timeout_s: the child is killed after this long.
    """

    vocabulary: str
    pace_s: float | None = None
    lockstep: bool = False
    loop_closing: bool = True
    th_depth: float = 35.0
    timeout_s: float = 3600.0


def map_states(raw_states: list[str]) -> tuple[list[str], list[int]]:
    """ORB-SLAM3 tracking-state names per frame -> (our states OK/INIT/LOST, segment ids; -1 when lost).

    A segment starts at every OK frame that follows a non-OK frame (or the first frame).
    """
    states, segments = [], []
    seg, prev_ok = -1, False
    for raw in raw_states:
        ok = STATE_MAP.get(raw, "LOST") == "OK"
        if ok and not prev_ok:
            seg += 1
            states.append("INIT")
        else:
            states.append("OK" if ok else "LOST")
        segments.append(seg if ok else -1)
        prev_ok = ok
    return states, segments


def _signal_name(rc: int) -> str:
    try:
        return signal.Signals(-rc).name
    except ValueError:
        return f"signal {-rc}"


def _last_line(log: Path) -> str:
    try:
        lines = [ln.strip() for ln in log.read_text(errors="replace").splitlines() if ln.strip()]
    except OSError:
        return ""
    return lines[-1][:200] if lines else ""


@dataclass
class SlamChild:
    """A running SLAM child process (:func:`start_child`); :func:`wait_child` collects it. ``proc``: the child
    started here, or one forked by a fork server (:class:`~bracketry_emulator.slam.launcher.LaunchedProcess`)."""

    proc: subprocess.Popen[bytes] | LaunchedProcess
    out_dir: Path
    log: Path
    started: float
    timeout_s: float


def start_child(request: dict, out_dir: str | Path, timeout_s: float = 3600.0,
                launcher: SlamLauncher | None = None) -> SlamChild:
    """Start ``python -m bracketry_emulator.slam.orbslam3_child`` on ``request`` (written to
    ``out_dir/request.json``; see that module), its stdout/stderr file descriptors into ``out_dir/orbslam3.log``.
    With a ``launcher`` (:mod:`.launcher`) the child is forked by that server, which has imported everything the
    child needs (the same ``main`` on the same request; ~0.6 CPU-s less per run); should it fail, the child is
    started here."""
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    for old in (*out.glob("CameraTrajectory*.txt"), out / "frames.csv", out / "slam.json"):
        old.unlink(missing_ok=True)
    (out / "request.json").write_text(json.dumps({**request, "out_dir": str(out)}, indent=1))
    log = out / "orbslam3.log"
    if launcher is not None:
        from bracketry_emulator.slam.launcher import LaunchedProcess, LauncherError

        try:
            t0 = time.perf_counter()
            pid = launcher.launch(out / "request.json", log)
            return SlamChild(LaunchedProcess(launcher, pid), out, log, t0, timeout_s)
        except LauncherError:
            pass  # started here instead
    env = dict(os.environ, OMP_NUM_THREADS="1", OPENBLAS_NUM_THREADS="1")  # the runs share the cores
    with open(log, "wb") as fh:
        proc = subprocess.Popen([sys.executable, "-m", "bracketry_emulator.slam.orbslam3_child",
                                 str(out / "request.json")], stdin=subprocess.DEVNULL, stdout=fh,
                                stderr=subprocess.STDOUT, env=env)
    return SlamChild(proc, out, log, time.perf_counter(), timeout_s)


def wait_child(child: SlamChild) -> dict:
    """Wait for a child of :func:`start_child`; its ``slam.json`` plus ``wall_s`` and ``cpu_s`` (user + system CPU
    of the whole child process, all its threads). A crash, an exit code or no ``slam.json`` raises
    :class:`SlamRunError` naming the exit status and the log's last line; past its timeout the child is killed."""
    if isinstance(child.proc, subprocess.Popen):
        rc, cpu_s = _wait_started(child)
    else:
        rc, cpu_s = _wait_launched(child, child.proc)
    wall_s = time.perf_counter() - child.started
    result_file = child.out_dir / "slam.json"
    if rc != 0 or not result_file.is_file():
        why = f"killed by {_signal_name(rc)}" if rc < 0 else f"exit code {rc}"
        last = _last_line(child.log)
        name = "ORB-SLAM3" if _backend(child) == "orbslam3" else "the SLAM process"
        raise SlamRunError(f"{name} failed ({why}){': ' + last if last else ''} (log: {child.log})")
    return {**json.loads(result_file.read_text()), "wall_s": wall_s, "cpu_s": cpu_s}


def child_ended(child: SlamChild) -> bool:
    """True once ``child`` has exited or is past its timeout (without collecting it: :func:`wait_child` then
    returns, or kills it, at once); a fork server gone counts as ended."""
    if time.perf_counter() > child.started + child.timeout_s:
        return True
    if isinstance(child.proc, subprocess.Popen):  # peek (WNOWAIT): wait_child reaps it with its CPU time
        try:
            return os.waitid(os.P_PID, child.proc.pid, os.WEXITED | os.WNOHANG | os.WNOWAIT) is not None
        except ChildProcessError:
            return True
    from bracketry_emulator.slam.launcher import LauncherError

    try:
        return child.proc.poll() is not None
    except LauncherError:
        return True


def _timed_out(child: SlamChild) -> SlamRunError:
    return SlamRunError(f"the SLAM run did not finish within {child.timeout_s:g} s (log: {child.log})")


def _wait_started(child: SlamChild) -> tuple[int, float]:
    """(exit code, CPU seconds) of a child started here."""
    pid = child.proc.pid
    deadline = child.started + child.timeout_s
    while True:
        wpid, status, usage = os.wait4(pid, os.WNOHANG)
        if wpid == pid:
            break
        if time.perf_counter() > deadline:
            child.proc.kill()
            os.wait4(pid, 0)
            child.proc.returncode = -signal.SIGKILL
            raise _timed_out(child)
        time.sleep(0.05)
    rc = os.waitstatus_to_exitcode(status)
    child.proc.returncode = rc  # reaped here: Popen must not wait again
    return rc, usage.ru_utime + usage.ru_stime


def _wait_launched(child: SlamChild, proc: LaunchedProcess) -> tuple[int, float]:
    """(exit code, CPU seconds) of a child forked by a fork server (a server gone: the run failed)."""
    from bracketry_emulator.slam.launcher import LauncherError

    try:
        rc = proc.wait(max(0.0, child.started + child.timeout_s - time.perf_counter()))
    except subprocess.TimeoutExpired:
        proc.kill()
        with contextlib.suppress(subprocess.TimeoutExpired, LauncherError):
            proc.wait(30.0)
        raise _timed_out(child) from None
    except LauncherError as exc:
        raise SlamRunError(f"the SLAM run's fork server ended before the run ({exc}) (log: {child.log})") from None
    return rc, float(proc.cpu_s or 0.0)


def _backend(child: SlamChild) -> str:
    try:
        return str(json.loads((child.out_dir / "request.json").read_text()).get("backend", "orbslam3"))
    except (OSError, ValueError):
        return "orbslam3"


def orbslam3_request(run_dir: str | Path | None, calibration_dir: str | Path, options: OrbSlam3Options,
                     max_frames: int | None = None, frames_fifo: str | Path | None = None,
                     fps: float | None = None) -> dict:
    """The child's request for an ORB-SLAM3 run over a run folder's PNGs (``run_dir``) or an in-memory frame
    stream (``frames_fifo``, then ``fps``: the frame rate ORB-SLAM3's settings get)."""
    if not Path(options.vocabulary).is_file():
        raise SlamRunError(f"ORB-SLAM3 vocabulary not found: {options.vocabulary}")
    return {"backend": "orbslam3", "run_dir": str(run_dir) if run_dir else None,
            "frames_fifo": str(frames_fifo) if frames_fifo else None, "fps": fps,
            "calibration_dir": str(calibration_dir), "max_frames": max_frames, "options": asdict(options)}


def run_orbslam3(run_dir: str | Path, calibration_dir: str | Path, out_dir: str | Path, options: OrbSlam3Options,
                 max_frames: int | None = None) -> dict:
    """Track a whole run folder with ORB-SLAM3 in a child process; write the VO output layout; return
    ``slam.json`` (plus the child's ``wall_s`` and ``cpu_s``)."""
    request = orbslam3_request(run_dir, calibration_dir, options, max_frames)
    return wait_child(start_child(request, out_dir, options.timeout_s))
