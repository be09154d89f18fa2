"""A fork server for SLAM child processes: Python's start and the child's imports paid once, not once per run.

Every SLAM run is still its own process (a crash or an ``exit()`` in ORB-SLAM3 stays one failed run, every run gets
a fresh ``ORB_SLAM3::System``), but instead of ``python -m bracketry_emulator.slam.orbslam3_child`` per run (an
interpreter plus numpy, OpenCV, SciPy, pyorbslam3 and our modules: ~0.6 CPU-s, a third of a demo-suite run's
~2 CPU-s), one server process (``python -m bracketry_emulator.slam.launcher``) imports them once and forks a child
per run, which calls the same :func:`bracketry_emulator.slam.orbslam3_child.main` on the same ``request.json`` with
its stdout/stderr file descriptors in ``orbslam3.log``: the run computes what a started child computes.

The server knows its child module by name only (:data:`CHILD_MODULE`, its command-line argument): it imports it at
start and calls its ``preload()`` (the child's imports and runtime profile) and, in each forked child, its
``main([request])``. So this module imports nothing of SLAM (no import cycle with :mod:`.orbslam3` and its child).

The server is single-threaded when it forks (checked at start: it refuses to serve otherwise, and the caller starts
children as before). It applies the child's runtime profile (one OpenCV thread) before forking, as the child would.

Protocol (lines of UTF-8 on the server's stdin / stdout)::

    -> run <token> {"request": "<request.json>", "log": "<orbslam3.log>"}     (the paths as one JSON object)
    <- started <token> <pid>   (or: failed <token> <why>)
    <- exit <pid> <exit code, -signal when killed> <cpu s>

``ready`` is the server's first line. When its stdin closes (the benchmark ended or died), the server kills the
children still running, reaps them and exits. The parent side is :class:`SlamLauncher`; :func:`shared_launcher`
gives one per process (started at first use, None where it cannot start: the caller starts children itself).
"""

from __future__ import annotations

import atexit
import contextlib
import importlib
import json
import os
import select
import signal
import subprocess
import sys
import threading
import time
from collections.abc import Callable
from pathlib import Path

#: how long the server may take to import everything and say ``ready``
START_TIMEOUT_S = 120.0
#: the module whose ``preload()`` the server calls once and whose ``main([request])`` each forked child runs
CHILD_MODULE = "bracketry_emulator.slam.orbslam3_child"


# ---------------------------------------------------------------------------------------------------- server side


def _threads() -> int:
    try:
        return len(os.listdir("/proc/self/task"))
    except OSError:
        return threading.active_count()


def _write(fd: int, line: str) -> None:
    data = (line + "\n").encode()
    while data:
        data = data[os.write(fd, data):]


def _child(run: Callable[[list[str]], int], request: str, log: str, close_fds: tuple[int, ...]) -> None:
    """In the forked child: the run's log as stdout/stderr, the default signal handlers, then ``run([request])`` (the
    child module's main)."""
    rc = 1
    try:
        signal.set_wakeup_fd(-1)
        signal.signal(signal.SIGCHLD, signal.SIG_DFL)
        signal.signal(signal.SIGINT, signal.default_int_handler)
        signal.signal(signal.SIGTERM, signal.SIG_DFL)
        for fd in close_fds:
            with contextlib.suppress(OSError):
                os.close(fd)
        out = os.open(log, os.O_WRONLY | os.O_CREAT | os.O_TRUNC, 0o644)
        os.dup2(out, 1)
        os.dup2(out, 2)
        os.close(out)
        null = os.open(os.devnull, os.O_RDONLY)
        os.dup2(null, 0)
        os.close(null)
        rc = run([request])
    except BaseException as exc:  # one line in the run's log and exit 1, as a started child does
        with contextlib.suppress(BaseException):
            print(f"error: {type(exc).__name__}: {exc}".replace("\n", " "), file=sys.stderr)
        rc = 1
    finally:
        with contextlib.suppress(BaseException):
            sys.stdout.flush()
            sys.stderr.flush()
        os._exit(rc)  # no interpreter teardown (see orbslam3_child)


def _reap(out_fd: int, children: set[int], block: bool = False) -> None:
    while children:
        try:
            pid, status, usage = os.wait4(-1, 0 if block else os.WNOHANG)
        except ChildProcessError:
            children.clear()
            return
        if pid == 0:
            return
        children.discard(pid)
        _write(out_fd, f"exit {pid} {os.waitstatus_to_exitcode(status)} {usage.ru_utime + usage.ru_stime:.6f}")


def serve(in_fd: int, out_fd: int, run: Callable[[list[str]], int]) -> int:
    """The server's loop (see the module docstring) on the command pipe ``in_fd`` and the reply pipe ``out_fd``;
    ``run``: what each forked child calls with ``[request]``."""
    wake_r, wake_w = os.pipe()
    os.set_blocking(wake_r, False)
    os.set_blocking(wake_w, False)
    signal.set_wakeup_fd(wake_w)
    signal.signal(signal.SIGCHLD, lambda *_: None)  # a handler, so that SIGCHLD reaches the wakeup pipe
    signal.signal(signal.SIGINT, signal.SIG_IGN)  # the benchmark handles Ctrl-C and closes our stdin
    children: set[int] = set()
    pending = b""
    _write(out_fd, "ready")
    while True:
        ready, _, _ = select.select([in_fd, wake_r], [], [])
        if wake_r in ready:
            with contextlib.suppress(BlockingIOError):
                while os.read(wake_r, 4096):
                    pass
            _reap(out_fd, children)
        if in_fd not in ready:
            continue
        data = os.read(in_fd, 65536)
        if not data:
            break
        pending += data
        while b"\n" in pending:
            line, pending = pending.split(b"\n", 1)
            parts = line.decode().split(" ", 2)
            try:
                if len(parts) != 3 or parts[0] != "run":
                    raise ValueError(parts[0])
                paths = json.loads(parts[2])
                request, log = str(paths["request"]), str(paths["log"])
            except (ValueError, TypeError, KeyError):
                _write(out_fd, f"failed {parts[1] if len(parts) > 1 else '?'} bad command {line[:80]!r}")
                continue
            token = parts[1]
            sys.stdout.flush()
            sys.stderr.flush()
            try:
                pid = os.fork()
            except OSError as exc:
                _write(out_fd, f"failed {token} cannot fork: {exc}")
                continue
            if pid == 0:
                _child(run, request, log, (in_fd, out_fd, wake_r, wake_w))
            children.add(pid)
            _write(out_fd, f"started {token} {pid}")
        _reap(out_fd, children)
    for pid in list(children):
        with contextlib.suppress(ProcessLookupError):
            os.kill(pid, signal.SIGKILL)
    _reap(out_fd, children, block=True)
    return 0


def main(argv: list[str] | None = None) -> int:
    """``python -m bracketry_emulator.slam.launcher [CHILD_MODULE]``: import the child module (default
    :data:`CHILD_MODULE`), call its ``preload()``, then serve."""
    args = sys.argv[1:] if argv is None else argv
    # the replies get a descriptor of their own; anything a library prints to stdout goes to stderr instead
    out_fd = os.dup(1)
    os.dup2(2, 1)
    child = importlib.import_module(args[0] if args else CHILD_MODULE)
    child.preload()
    if _threads() != 1:  # forking a process with threads running is unsafe: refuse, the caller starts children
        print(f"slam launcher: {_threads()} threads after the imports, not forking", file=sys.stderr)
        return 3
    return serve(0, out_fd, child.main)


# ---------------------------------------------------------------------------------------------------- parent side


class LauncherError(RuntimeError):
    """The fork server is gone or did not answer."""


class SlamLauncher:
    """The parent's end of a fork server (see the module docstring). Thread-safe."""

    def __init__(self, start_timeout_s: float = START_TIMEOUT_S, child_module: str = CHILD_MODULE) -> None:
        env = dict(os.environ, OMP_NUM_THREADS="1", OPENBLAS_NUM_THREADS="1")  # as for a started child
        self.proc = subprocess.Popen([sys.executable, "-m", "bracketry_emulator.slam.launcher", child_module],
                                     stdin=subprocess.PIPE, stdout=subprocess.PIPE, env=env)
        assert self.proc.stdout is not None and self.proc.stdin is not None
        self._out = self.proc.stdout.fileno()
        self._in = self.proc.stdin.fileno()
        self._buf = b""
        self._lock = threading.Lock()
        self._tokens = 0
        self._started: dict[str, str] = {}
        self._exits: dict[int, tuple[int, float]] = {}
        self._running: set[int] = set()
        self._closed = False
        deadline = time.monotonic() + start_timeout_s
        while "ready" not in self._started:
            if time.monotonic() > deadline or not self._read(0.5):
                self.close()
                raise LauncherError("the SLAM fork server did not start")

    def _read(self, timeout_s: float) -> bool:
        """Read and file the replies that arrive within ``timeout_s`` (the caller holds the lock); False when the
        server is gone."""
        if self._closed:
            return False
        wait_s = max(0.0, timeout_s)
        while True:
            ready, _, _ = select.select([self._out], [], [], wait_s)
            if not ready:
                return self.alive()
            data = os.read(self._out, 65536)
            if not data:
                return False
            self._buf += data
            while b"\n" in self._buf:
                line, self._buf = self._buf.split(b"\n", 1)
                self._file(line.decode())
            wait_s = 0.0  # then whatever else is there already

    def _file(self, line: str) -> None:
        parts = line.split(" ", 3)
        if parts[0] == "ready":
            self._started["ready"] = ""
        elif parts[0] in ("started", "failed") and len(parts) >= 3:
            self._started[parts[1]] = f"{parts[0]} {' '.join(parts[2:])}"
        elif parts[0] == "exit" and len(parts) >= 4:
            pid = int(parts[1])
            self._exits[pid] = (int(parts[2]), float(parts[3]))
            self._running.discard(pid)

    def alive(self) -> bool:
        return not self._closed and self.proc.poll() is None

    def launch(self, request: str | Path, log: str | Path, timeout_s: float = 60.0) -> int:
        """Fork a child running ``orbslam3_child.main([request])`` with stdout/stderr in ``log``; its pid."""
        with self._lock:
            self._tokens += 1
            token = str(self._tokens)
            try:
                paths = json.dumps({"request": os.fspath(request), "log": os.fspath(log)})
                os.write(self._in, f"run {token} {paths}\n".encode())
            except OSError as exc:
                raise LauncherError(f"the SLAM fork server is gone ({exc})") from None
            deadline = time.monotonic() + timeout_s
            while token not in self._started:
                if time.monotonic() > deadline or not self._read(0.5):
                    raise LauncherError("the SLAM fork server did not start the run")
            answer = self._started.pop(token)
            if not answer.startswith("started "):
                raise LauncherError(f"the SLAM fork server: {answer}")
            pid = int(answer.split()[1])
            self._running.add(pid)
            return pid

    def poll(self, pid: int) -> tuple[int, float] | None:
        """(exit code, CPU seconds) of a child that ended, else None (replies read without waiting)."""
        return self.wait(pid, 0.0)

    def wait(self, pid: int, timeout_s: float | None = None) -> tuple[int, float] | None:
        """Wait up to ``timeout_s`` (None: for ever) for ``pid``'s end: (exit code, CPU seconds) or None.
        :class:`LauncherError` when the server is gone before saying."""
        deadline = None if timeout_s is None else time.monotonic() + timeout_s
        while True:
            with self._lock:
                alive = self._read(0.0) if pid not in self._exits else True
                if pid in self._exits:
                    return self._exits.pop(pid)
                if not alive:
                    self._running.discard(pid)
                    raise LauncherError("the SLAM fork server is gone")
                left = None if deadline is None else deadline - time.monotonic()
                if left is not None and left <= 0:
                    return None
                self._read(0.05 if left is None else min(0.05, left))

    def kill(self, pid: int) -> None:
        """SIGKILL a child still running (one that ended is not signalled: its pid may be another process's)."""
        with self._lock:
            if pid in self._running and pid not in self._exits:
                with contextlib.suppress(ProcessLookupError):
                    os.kill(pid, signal.SIGKILL)

    def close(self) -> None:
        """Close the server's stdin (it kills what still runs, reaps and exits) and wait for it."""
        with contextlib.suppress(OSError):
            if self.proc.stdin is not None:
                self.proc.stdin.close()
        try:
            self.proc.wait(timeout=30)
        except subprocess.TimeoutExpired:
            self.proc.kill()
            self.proc.wait()
        with self._lock:
            self._closed = True
            with contextlib.suppress(OSError):
                if self.proc.stdout is not None:
                    self.proc.stdout.close()


class LaunchedProcess:
    """A child forked by a :class:`SlamLauncher`, with the parts of :class:`subprocess.Popen` the benchmark uses
    (``pid``, ``returncode``, :meth:`kill`, :meth:`wait`)."""

    def __init__(self, launcher: SlamLauncher, pid: int) -> None:
        self.launcher = launcher
        self.pid = pid
        self.returncode: int | None = None
        self.cpu_s: float | None = None

    def poll(self) -> int | None:
        if self.returncode is None:
            got = self.launcher.poll(self.pid)
            if got is not None:
                self.returncode, self.cpu_s = got
        return self.returncode

    def wait(self, timeout: float | None = None) -> int:
        if self.returncode is None:
            got = self.launcher.wait(self.pid, timeout)
            if got is None:
                raise subprocess.TimeoutExpired(f"slam child {self.pid}", timeout or 0.0)
            self.returncode, self.cpu_s = got
        return self.returncode

    def kill(self) -> None:
        if self.returncode is None:
            self.launcher.kill(self.pid)


_shared: SlamLauncher | None = None
_shared_failed = False
_shared_lock = threading.Lock()


def shared_launcher() -> SlamLauncher | None:
    """This process's fork server, started at first use (again if it died); None where it cannot start (then the
    caller starts each child itself, as before). ``BRACKETRY_SLAM_LAUNCHER=0`` turns it off."""
    global _shared, _shared_failed
    if os.environ.get("BRACKETRY_SLAM_LAUNCHER", "1") == "0":
        return None
    with _shared_lock:
        if _shared is not None and _shared.alive():
            return _shared
        if _shared_failed:
            return None
        try:
            _shared = SlamLauncher()
        except (OSError, LauncherError):
            _shared, _shared_failed = None, True
            return None
        atexit.register(_shared.close)
        return _shared


def close_shared_launcher() -> None:
    """Close this process's fork server (:func:`shared_launcher` starts a new one when asked again). Its children's
    CPU time counts in this process's ``RUSAGE_CHILDREN`` only once the server is reaped: a caller that measures it
    (the demo's CPU per step) closes the server first."""
    global _shared
    with _shared_lock:
        server, _shared = _shared, None
    if server is not None:
        server.close()


if __name__ == "__main__":
    sys.exit(main())
