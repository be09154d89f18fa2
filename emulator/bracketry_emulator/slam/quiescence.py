"""Wait until this process's background threads are idle: the lockstep feed of ORB-SLAM3 (``--slam-pace lockstep``).

ORB-SLAM3 tracks in the caller's thread and maps in its own (local mapping, loop closing, a global bundle adjustment
when a loop closes). Fed faster than they keep up, tracking races them, and what a frame meets (how many keyframes,
which map points) depends on the machine's load. Fed in lockstep, each frame is tracked only once those threads are
idle: every frame meets the map its predecessors left, whatever the load.

pyorbslam3 has no "local mapping idle" call, so idleness is read from the threads themselves, never from the wall
clock: ``/proc/self/task/<tid>/stat`` (state: ``R`` runnable, ``D`` in I/O) and ``.../schedstat`` (nanoseconds on a
CPU). Idle ORB-SLAM3 threads sleep in short polls (local mapping 3 ms, loop closing 5 ms) and run a few microseconds
per poll; a thread at work is runnable (``R``, running or waiting for a CPU) or runs for most of a poll. The
threads are idle when, over :data:`QUIET_WINDOW_S` (longer than those polls, so a keyframe just queued is seen), no
sample found one runnable or in I/O, and together they ran less than :data:`MAX_IDLE_RUN_FRACTION` of the window.

A sample reads two small files per thread; :class:`ThreadSampler` keeps them open and re-reads them with ``pread``
(about half the CPU of opening and closing them each time: ~0.06 ms against ~0.13 ms a sample of ORB-SLAM3's three
threads, where a run of the demo samples 1,000-5,000 times). Polled every millisecond through a local bundle
adjustment that lasts seconds, the waiting thread
alone would take about half a core from the threads it waits for. While a thread is busy the polls therefore space
out, doubling up to :data:`MAX_BUSY_POLL_S`; once none is, they return to :data:`POLL_S` for the quiet window. The
spacing only delays the end of a wait (by at most :data:`MAX_BUSY_POLL_S`); what counts as idle is unchanged.
"""

from __future__ import annotations

import os
import time
from collections.abc import Callable, Iterable
from dataclasses import dataclass

#: how long the background threads must stay idle (longer than ORB-SLAM3's idle polls: 3 ms and 5 ms)
QUIET_WINDOW_S = 0.012
#: seconds between two samples of the threads
POLL_S = 0.001
#: longest sleep between two samples while some thread is busy (polls double from :data:`POLL_S` up to it)
MAX_BUSY_POLL_S = 0.008
#: at most this share of the window may the threads together run and still count as idle (their idle polls)
MAX_IDLE_RUN_FRACTION = 0.1
#: give up waiting after this long (a thread that never sleeps): the feed goes on and the run counts it
MAX_WAIT_S = 60.0

TASK_DIR = "/proc/self/task"


@dataclass(frozen=True)
class ThreadSample:
    """One thread at one instant: its state letter (``R``, ``S``, ``D``, ...) and nanoseconds it ran on a CPU."""

    state: str
    run_ns: int


def thread_ids() -> set[int]:
    """This process's thread ids (empty where ``/proc`` is missing)."""
    try:
        return {int(t) for t in os.listdir(TASK_DIR)}
    except OSError:
        return set()


def sample_threads(tids: Iterable[int]) -> dict[int, ThreadSample]:
    """The state and run time of each thread of ``tids`` still alive."""
    out = {}
    for tid in tids:
        try:
            out[tid] = _parse(_read(f"{TASK_DIR}/{tid}/stat"), _read(f"{TASK_DIR}/{tid}/schedstat"))
        except (OSError, ValueError, IndexError):
            continue  # ended meanwhile
    return out


def _parse(stat: bytes, schedstat: bytes) -> ThreadSample:
    """A thread's sample from its ``stat`` (the state letter after the command's closing parenthesis) and
    ``schedstat`` (first field: nanoseconds on a CPU) bytes; ValueError or IndexError when either is cut short."""
    return ThreadSample(chr(stat[stat.rindex(b")") + 2]), int(schedstat.split()[0]))


def _read(path: str) -> bytes:
    """A small /proc file's bytes (unbuffered: a third of ``open().read()``'s cost)."""
    fd = os.open(path, os.O_RDONLY)
    try:
        return os.read(fd, 4096)
    finally:
        os.close(fd)


class ThreadSampler:
    """Samples of this process's threads but ``exclude`` (what :func:`sample_threads` reads) from descriptors kept
    open: a thread's ``stat`` and ``schedstat`` are opened when it is first seen and re-read with ``pread`` (the
    kernel makes a /proc file anew at each read from offset 0); a thread that ended is dropped. :meth:`close` (or
    ``with``) closes them."""

    def __init__(self, exclude: set[int]) -> None:
        self.exclude = set(exclude)
        self._fds: dict[int, tuple[int, int]] = {}

    def __enter__(self) -> ThreadSampler:
        return self

    def __exit__(self, *_exc: object) -> None:
        self.close()

    def _drop(self, tid: int) -> None:
        for fd in self._fds.pop(tid, ()):
            os.close(fd)

    def _open(self, tid: int) -> tuple[int, int] | None:
        try:
            stat = os.open(f"{TASK_DIR}/{tid}/stat", os.O_RDONLY)
        except OSError:
            return None
        try:
            sched = os.open(f"{TASK_DIR}/{tid}/schedstat", os.O_RDONLY)
        except OSError:
            os.close(stat)
            return None
        self._fds[tid] = (stat, sched)
        return stat, sched

    def __call__(self) -> dict[int, ThreadSample]:
        """The state and run time of every thread alive now but the excluded ones."""
        tids = thread_ids() - self.exclude
        for gone in set(self._fds) - tids:
            self._drop(gone)
        out = {}
        for tid in tids:
            got = self._read(tid, self._fds.get(tid))
            if got is None:  # first seen, or its files went with an ended thread whose id came back: open anew
                self._drop(tid)
                got = self._read(tid, self._open(tid))
            if got is None:
                self._drop(tid)  # ended meanwhile
            else:
                out[tid] = got
        return out

    @staticmethod
    def _read(tid: int, fds: tuple[int, int] | None) -> ThreadSample | None:
        if fds is None:
            return None
        try:
            return _parse(os.pread(fds[0], 4096, 0), os.pread(fds[1], 4096, 0))
        except (OSError, ValueError, IndexError):
            return None

    def close(self) -> None:
        for tid in list(self._fds):
            self._drop(tid)


def busy_now(sample: dict[int, ThreadSample]) -> bool:
    """Some thread is runnable (running or waiting for a CPU) or waits for I/O."""
    return any(s.state in ("R", "D") for s in sample.values())


def run_ns_between(first: dict[int, ThreadSample], last: dict[int, ThreadSample]) -> int:
    """Nanoseconds the threads ran from ``first`` to ``last`` (a thread born meanwhile: all its run time)."""
    return sum(s.run_ns - (first[t].run_ns if t in first else 0) for t, s in last.items())


def window_idle(first: dict[int, ThreadSample], last: dict[int, ThreadSample], window_s: float,
                max_run_fraction: float = MAX_IDLE_RUN_FRACTION) -> bool:
    """Over a window of ``window_s`` whose samples found no thread busy (:func:`busy_now`), the threads ran little
    enough to be idle: less than ``max_run_fraction`` of the window together."""
    return run_ns_between(first, last) < max_run_fraction * window_s * 1e9


@dataclass
class LockstepStats:
    """What the waits of one run cost: waits, seconds spent waiting, waits that gave up (:data:`MAX_WAIT_S`)."""

    waits: int = 0
    wait_s: float = 0.0
    timeouts: int = 0
    #: samples taken (each costs ~0.1 ms of CPU a thread)
    polls: int = 0


def wait_idle(exclude: set[int], stats: LockstepStats, window_s: float = QUIET_WINDOW_S, poll_s: float = POLL_S,
              max_busy_poll_s: float = MAX_BUSY_POLL_S, max_wait_s: float = MAX_WAIT_S,
              clock: Callable[[], float] = time.monotonic, sleep: Callable[[float], None] = time.sleep,
              sample: Callable[[], dict[int, ThreadSample]] | None = None) -> bool:
    """Return once this process's threads but ``exclude`` (the caller's and its helpers') have been idle for
    ``window_s`` (see the module docstring); False when ``max_wait_s`` passed first. Samples every ``poll_s``, spaced
    out up to ``max_busy_poll_s`` while a thread is busy. ``sample``: the threads' state now (default:
    :func:`sample_threads` of every thread not in ``exclude``; a run's waits share one :class:`ThreadSampler`)."""

    def now_sample() -> dict[int, ThreadSample]:
        stats.polls += 1
        if sample is not None:
            return sample()
        return sample_threads(thread_ids() - exclude)

    t_start = clock()
    stats.waits += 1
    first, t_first = now_sample(), clock()
    ok = True
    gap_s = poll_s
    while True:
        sleep(gap_s)
        cur, t_cur = now_sample(), clock()
        if busy_now(cur):
            first, t_first = cur, t_cur
            gap_s = min(2.0 * gap_s, max(max_busy_poll_s, poll_s))
        else:
            gap_s = poll_s
            if t_cur - t_first >= window_s:
                if window_idle(first, cur, t_cur - t_first):
                    break
                first, t_first = cur, t_cur
        if t_cur - t_start > max_wait_s:
            stats.timeouts += 1
            ok = False
            break
    stats.wait_s += clock() - t_start
    return ok
