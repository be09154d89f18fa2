"""The decoded frames of a run's bracket sequences, in one anonymous shared memory map (shared by forked workers).

A run's sequences are numbered by their ``position`` in the run (0, 1, ...); their frames live in a ring of ``slots``
sequence slots (position ``p`` in slot ``p % slots``), each ``side`` x ``exposure`` frames of uint16 HxW raw Bayer
codes, C order. A decode task is ``(position, sequence index, side index, exposure index)``.

Decode once per run, shared by every process: :meth:`FrameBuffer.ensure` claims a frame in a shared state table
(one byte per frame and position, under a lock inherited by the forked workers); the first process that needs a frame
decodes it, every other one waits for it, so each bracket is decoded at most once per trajectory and only when a
method's target needs it.

Slot reuse: each reader (a worker; :meth:`FrameBuffer.release`) tells which positions it no longer reads; a frame of
position ``p`` is written only once every reader is past position ``p - slots`` (the sequence that held the slot
before). A ring of a few slots keeps the frames on pages already mapped: fresh pages of a shared map are allocated and
zeroed by the kernel on first touch (and mapped again in every process that reads them), which cost a fifth of the
system time of a run when every sequence had its own slot.
"""

from __future__ import annotations

import contextlib
import functools
import mmap
import multiprocessing as mp
import time
from concurrent.futures import Future, ThreadPoolExecutor
from pathlib import Path
from typing import Any

import numpy as np

from bracketry.errors import BracketryError

from ..dataset import BracketSequence

#: (position, sequence index, side index, exposure index) of one frame to decode
DecodeTask = tuple[int, int, int, int]

#: :meth:`FrameBuffer.release` position of a reader that reads nothing more (finished or failed)
RELEASED_ALL = 1 << 62

#: states of a frame in the shared table: free, claimed (queued on a decode thread, not started), done, failed,
#: being decoded
_FREE, _CLAIMED, _DONE, _FAILED, _RUNNING = 0, 1, 2, 3, 4


class _Elsewhere:
    """A frame that another process (or an earlier call) decodes: :meth:`result` waits until it is in the buffer,
    decoding it in the calling thread when its decode has not started (claimed, still queued behind other frames on
    some decode thread) or was released. Future-like (``result``, ``exception``, ``cancel``, ``cancelled``)."""

    def __init__(self, frames: FrameBuffer, task: DecodeTask) -> None:
        self.frames, self.task = frames, task

    def result(self, timeout: float | None = None) -> None:
        fb = self.frames
        i = fb.state_index(self.task)
        delay = 0.0002
        while True:
            state = fb.state[i]
            if state == _DONE:
                return
            if state == _FAILED:
                _, seq_i, side_i, exp_i = self.task
                seq = fb.sequences[seq_i]
                source = getattr(seq.frames[fb.sides[side_i]][seq.exposures_us[exp_i]], "source", "?")
                raise BracketryError(f"cannot decode {source} (failed in another worker process)")
            if state in (_FREE, _CLAIMED) and fb.take(self.task):  # not started anywhere: decode it here
                fb.run_taken(self.task)
                return
            time.sleep(delay)
            delay = min(delay * 2, 0.005)

    def exception(self, timeout: float | None = None) -> BaseException | None:
        try:
            self.result()
        except BaseException as exc:
            return exc
        return None

    def cancel(self) -> bool:
        return False

    def cancelled(self) -> bool:
        return False


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
        #: one byte per frame of every position (free, claimed, done, failed, running), shared with forked workers;
        #: guarded by ``lock``
        self.state = mmap.mmap(-1, max(1, self.positions * len(sides) * n_exp))
        self.lock = mp.get_context("fork").Lock() if "fork" in mp.get_all_start_methods() else mp.Lock()
        # shared int64s: per reader the first position it may still read, then the abort flag
        self._sync = mmap.mmap(-1, 8 * (max(1, readers) + 1))
        self._released = memoryview(self._sync).cast("q")
        self.readers = max(1, readers)

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
        self._released[reader] = pos

    def abort(self) -> None:
        """Make every thread waiting for a slot (in any process) raise instead (a reader failed or the run stops)."""
        self._released[self.readers] = 1

    def _wait_writable(self, pos: int) -> None:
        """Return once every reader released position ``pos - slots`` (the slot's previous sequence)."""
        need = pos - self.slots + 1
        released = self._released
        delay = 0.0002
        while min(released[r] for r in range(self.readers)) < need:
            if released[self.readers]:
                raise BracketryError("the run was aborted")
            time.sleep(delay)
            delay = min(delay * 2, 0.005)

    def _decode_one(self, task: DecodeTask) -> None:
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

    def state_index(self, task: DecodeTask) -> int:
        pos, _, side_i, exp_i = task
        return (pos * len(self.sides) + side_i) * self.n_exp + exp_i

    def claim(self, task: DecodeTask) -> bool:
        """Mark a free frame as being decoded by the caller; False when it is claimed, decoded or failed."""
        i = self.state_index(task)
        with self.lock:
            if self.state[i] != _FREE:
                return False
            self.state[i] = _CLAIMED
            return True

    def take(self, task: DecodeTask) -> bool:
        """Start decoding a frame that is free or claimed but not started (the caller then calls
        :meth:`run_taken`); False when it is being decoded, decoded or failed."""
        i = self.state_index(task)
        with self.lock:
            if self.state[i] not in (_FREE, _CLAIMED):
                return False
            self.state[i] = _RUNNING
            return True

    def run_taken(self, task: DecodeTask) -> None:
        """Decode a frame the caller took; its state becomes done (or failed, then the error is raised)."""
        i = self.state_index(task)
        try:
            self._decode_one(task)
        except BaseException:
            self.state[i] = _FAILED
            raise
        self.state[i] = _DONE

    def run_claimed(self, task: DecodeTask) -> None:
        """Decode a frame the caller claimed, unless a thread waiting for it took it over meanwhile (then wait until
        that one has decoded it); raises when the decode failed."""
        if self.take(task):
            self.run_taken(task)
        else:
            _Elsewhere(self, task).result()

    def ensure(self, tasks: list[DecodeTask], pool: ThreadPoolExecutor) -> list[Any]:
        """Each frame decoded once for every process: the frames nobody has claimed are decoded on ``pool``'s
        threads, the others are waited for. Returns one future-like handle per task (``result()`` waits; a
        cancelled decode releases its claim)."""
        out: list[Any] = []
        for task in tasks:
            if self.claim(task):
                fut = pool.submit(self.run_claimed, task)
                fut.add_done_callback(functools.partial(self._release_if_cancelled, task))
                out.append(fut)
            else:
                out.append(_Elsewhere(self, task))
        return out

    def wait(self, task: DecodeTask) -> None:
        """Return once a claimed frame is in the buffer, decoded by any thread or worker, or here when its decode
        has not started yet (instead of waiting for the decode threads' queue). Raises BracketryError when its
        decode failed elsewhere (a decode that fails here raises its own error)."""
        _Elsewhere(self, task).result()

    def _release_if_cancelled(self, task: DecodeTask, fut: Future[None]) -> None:
        if fut.cancelled():
            i = self.state_index(task)
            with self.lock:
                if self.state[i] == _CLAIMED:
                    self.state[i] = _FREE

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
