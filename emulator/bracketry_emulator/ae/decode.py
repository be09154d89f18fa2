"""The decoded frames of a run's bracket sequences, in one anonymous shared memory map (shared by forked workers).

A run's sequences are numbered by their ``position`` in the run (0, 1, ...); their frames live in a ring of ``slots``
sequence slots (position ``p`` in slot ``p % slots``), each ``side`` x ``exposure`` frames of uint16 HxW raw Bayer
codes, C order. A decode task is ``(position, sequence index, side index, exposure index)``.

Decode once per run, shared by every process: :meth:`FrameBuffer.fetch` is the one call that puts a frame in the
buffer: the first thread (of any process) that needs a frame decodes it, every other one waits for it (on a condition
shared with the forked workers), so each bracket is decoded at most once per trajectory and only when a method's
target needs it. :meth:`FrameBuffer.prefetch` asks for frames ahead, on a pool's threads.

Slot reuse: each reader (a worker; :meth:`FrameBuffer.release`) tells which positions it no longer reads; a frame of
position ``p`` is written only once every reader is past position ``p - slots`` (the sequence that held the slot
before; waited for on the same condition). A ring of a few slots keeps the frames on pages already mapped: fresh
pages of a shared map are allocated and zeroed by the kernel on first touch (and mapped again in every process that
reads them), which cost a fifth of the system time of a run when every sequence had its own slot.
"""

from __future__ import annotations

import contextlib
import functools
import mmap
import multiprocessing as mp
from concurrent.futures import Future, ThreadPoolExecutor
from pathlib import Path
from typing import Any

import numpy as np

from bracketry_base.errors import BracketryError

from ..dataset import BracketSequence

#: (position, sequence index, side index, exposure index) of one frame to decode
DecodeTask = tuple[int, int, int, int]

#: :meth:`FrameBuffer.release` position of a reader that reads nothing more (finished or failed)
RELEASED_ALL = 1 << 62

#: states of a frame in the shared table: free, queued on a decode thread (not started), being decoded, done, failed
_FREE, _QUEUED, _RUNNING, _DONE, _FAILED = 0, 1, 2, 3, 4


class _SharedCondition:
    """A condition variable shared by forked processes (use under ``with``) whose :meth:`notify_all` never blocks:
    each waiting thread sleeps on a semaphore of its own, one of ``n`` made before the fork (multiprocessing's
    Condition makes the notifier wait until every woken thread has run, a stall of the decoding thread on a busy
    machine). A woken thread re-checks its predicate; a wake-up may be spurious."""

    def __init__(self, ctx: Any, n: int) -> None:
        self._lock = ctx.Lock()
        self._sems = [ctx.Semaphore(0) for _ in range(n)]
        self._waiting = mmap.mmap(-1, n)  # per semaphore: 0 free, 1 a thread waits on it, 2 released

    def __enter__(self) -> bool:
        return bool(self._lock.acquire())

    def __exit__(self, *exc: object) -> None:
        self._lock.release()

    def acquire(self, timeout: float | None = None) -> bool:
        return bool(self._lock.acquire(timeout=timeout))

    def release(self) -> None:
        self._lock.release()

    def wait(self) -> None:
        """Release the lock until :meth:`notify_all` (the lock held by the caller, held again on return)."""
        k = self._waiting.find(b"\0")
        if k < 0:
            raise RuntimeError(f"more than {len(self._sems)} threads wait for the frame buffer")
        self._waiting[k] = 1
        self._lock.release()
        try:
            self._sems[k].acquire()
        finally:
            self._lock.acquire()
            self._waiting[k] = 0

    def notify_all(self) -> None:
        """Wake every waiting thread (the lock held by the caller)."""
        waiting = self._waiting
        k = waiting.find(b"\1")
        while k >= 0:
            waiting[k] = 2
            self._sems[k].release()
            k = waiting.find(b"\1", k + 1)


class FrameBuffer:
    """A ring of ``slots`` sequences x ``len(sides)`` cameras x ``n_exp`` brackets of uint16 ``shape`` frames in one
    anonymous memory map (inherited by forked workers: decoded once, read by every worker) for the ``positions``
    sequences of a run (default: ``slots``, every position its own slot).

    ``readers``: how many readers (workers, numbered from 0) :meth:`release` positions; a frame of position ``p``
    is written once each of them released position ``p - slots``.
    ``preloaded``: {(sequence index, side index, exposure index): uint16 HxW} frames already decoded (copied
    instead of decoded again)."""

    def __init__(self, sequences: list[BracketSequence], sides: tuple[str, ...], shape: tuple[int, int], n_exp: int,
                 slots: int, preloaded: dict[tuple[int, int, int], np.ndarray] | None = None, *,
                 positions: int | None = None, readers: int = 1) -> None:
        self.sequences, self.sides, self.shape, self.n_exp = sequences, sides, shape, n_exp
        self.slots = slots
        self.positions = slots if positions is None else positions
        self.preloaded = preloaded or {}
        #: set: decodes are timed there (stage ``decode``; see :mod:`~bracketry_emulator.stages`)
        self.stages: Any = None
        self.mmap = mmap.mmap(-1, slots * self.sequence_bytes(len(sides), n_exp, shape))
        #: one byte per frame of every position (free, queued, running, done, failed), shared with forked workers;
        #: changed under ``_changed``, which is notified when a frame is done or failed and when a reader releases
        self.state = mmap.mmap(-1, max(1, self.positions * len(sides) * n_exp))
        ctx = mp.get_context("fork") if "fork" in mp.get_all_start_methods() else mp.get_context()
        #: waiting threads at most: the main and decode threads of every reader, with room to spare
        self._changed = _SharedCondition(ctx, 8 + 4 * max(1, readers))
        # shared int64s: per reader the first position it may still read, then the abort flag
        self._sync = mmap.mmap(-1, 8 * (max(1, readers) + 1))
        self._released = memoryview(self._sync).cast("q")
        self.readers = max(1, readers)
        self._errors: dict[int, BaseException] = {}  # this process's failed decodes, by state index

    @staticmethod
    def sequence_bytes(n_sides: int, n_exp: int, shape: tuple[int, int]) -> int:
        """Bytes of one sequence's frames (every side and bracket)."""
        return n_sides * n_exp * shape[0] * shape[1] * 2

    def view(self, pos: int, side_i: int, exp_i: int) -> np.ndarray:
        """uint16 HxW view of one frame's place in the buffer (position ``pos``: slot ``pos % slots``)."""
        h, w = self.shape
        n = h * w
        off = (((pos % self.slots) * len(self.sides) + side_i) * self.n_exp + exp_i) * n * 2
        return np.frombuffer(self.mmap, dtype=np.uint16, count=n, offset=off).reshape(h, w)

    def release(self, reader: int, pos: int) -> None:
        """Reader ``reader`` reads no frame of the positions before ``pos`` any more (their slots may be refilled;
        :data:`RELEASED_ALL`: it reads nothing more)."""
        with self._changed:
            self._released[reader] = pos
            self._changed.notify_all()

    def abort(self) -> None:
        """Make every thread waiting for a slot (in any process) raise instead (a reader failed or the run stops)."""
        self._released[self.readers] = 1
        if self._changed.acquire(timeout=5):  # not held forever by a worker that died
            try:
                self._changed.notify_all()
            finally:
                self._changed.release()

    def fetch(self, task: DecodeTask, *, wait: bool = True) -> None:
        """Return once frame ``task`` is in the buffer: decoded here when nobody has started it (free, or queued on
        a decode thread), else waited for (decoded by another thread or worker). ``wait=False``: return at once when
        another thread decodes it. Raises a decode's error (BracketryError when it failed in another process)."""
        i = self._index(task)
        with self._changed:
            while True:
                state = self.state[i]
                if state == _DONE:
                    return
                if state == _FAILED:
                    raise self._failure(task, i)
                if state in (_FREE, _QUEUED):
                    self.state[i] = _RUNNING
                    break
                if not wait:
                    return
                self._changed.wait()
        try:
            self._decode(task)
        except BaseException as exc:
            self._errors[i] = exc
            self._set(i, _FAILED)
            raise
        self._set(i, _DONE)

    def prefetch(self, tasks: list[DecodeTask], pool: ThreadPoolExecutor) -> list[Future[None]]:
        """Queue the frames nobody has asked for yet on ``pool``'s threads (:meth:`fetch` without waiting; a
        frame queued in any process is not queued again). Returns the queued decodes (cancelling one that has not
        started gives its frame back to whoever fetches it)."""
        out = []
        for task in tasks:
            i = self._index(task)
            with self._changed:
                if self.state[i] != _FREE:
                    continue
                self.state[i] = _QUEUED
            fut = pool.submit(self.fetch, task, wait=False)
            fut.add_done_callback(functools.partial(self._unqueue_if_cancelled, i))
            out.append(fut)
        return out

    def _index(self, task: DecodeTask) -> int:
        pos, _, side_i, exp_i = task
        return (pos * len(self.sides) + side_i) * self.n_exp + exp_i

    def _set(self, i: int, state: int) -> None:
        with self._changed:
            self.state[i] = state
            self._changed.notify_all()

    def _failure(self, task: DecodeTask, i: int) -> BaseException:
        own = self._errors.get(i)
        if own is not None:
            return own
        _, seq_i, side_i, exp_i = task
        seq = self.sequences[seq_i]
        source = getattr(seq.frames[self.sides[side_i]][seq.exposures_us[exp_i]], "source", "?")
        return BracketryError(f"cannot decode {source} (failed in another worker process)")

    def _unqueue_if_cancelled(self, i: int, fut: Future[None]) -> None:
        if fut.cancelled():
            with self._changed:
                if self.state[i] == _QUEUED:
                    self.state[i] = _FREE

    def _wait_writable(self, pos: int) -> None:
        """Return once every reader released position ``pos - slots`` (the slot's previous sequence)."""
        need = pos - self.slots + 1
        released = self._released
        with self._changed:
            while min(released[r] for r in range(self.readers)) < need:
                if released[self.readers]:
                    raise BracketryError("the run was aborted")
                self._changed.wait()

    def _decode(self, task: DecodeTask) -> None:
        self._wait_writable(task[0])
        if self.stages is None:
            return self._load(task)
        with self.stages.time("decode"):
            return self._load(task)

    def _load(self, task: DecodeTask) -> None:
        pos, seq_i, side_i, exp_i = task
        seq = self.sequences[seq_i]
        view = self.view(pos, side_i, exp_i)
        img = self.preloaded.get((seq_i, side_i, exp_i))
        if img is None:  # decoded straight into the buffer (a PNG), else copied there
            img = seq.frames[self.sides[side_i]][seq.exposures_us[exp_i]].load_into(view)
        if img.shape != self.shape:
            raise BracketryError(f"sequence {seq.index}: frame shape {img.shape} differs from {self.shape}")
        if img is not view:
            view[...] = img

    def close(self) -> None:
        """Free the maps (a BufferError while numpy views of it are alive: then it is freed with them)."""
        self._released.release()
        for m in (self.mmap, self.state, self._sync):
            with contextlib.suppress(BufferError):
                m.close()


def frame_shape(seq: BracketSequence, side: str) -> tuple[tuple[int, int], np.ndarray | None]:
    """(H, W) of a sequence's first frame: from the PNG header when the frame is a PNG file (no decode), else by
    loading it (then returned too, to be reused)."""
    frame = seq.frames[side][seq.exposures_us[0]]
    path = Path(frame.source)
    if path.suffix.lower() == ".png" and path.is_file():
        with open(path, "rb") as fh:
            head = fh.read(24)
        if len(head) == 24 and head[:8] == b"\x89PNG\r\n\x1a\n" and head[12:16] == b"IHDR":
            return (int.from_bytes(head[20:24], "big"), int.from_bytes(head[16:20], "big")), None
    img = frame.load()
    return (int(img.shape[0]), int(img.shape[1])), img
