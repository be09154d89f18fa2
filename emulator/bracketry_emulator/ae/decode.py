"""The decoded frames of a chunk of bracket sequences, in one anonymous shared memory map (shared by forked workers).

Layout: ``slot`` (position of the sequence in the chunk) x ``side`` x ``exposure`` frames of uint16 HxW raw Bayer
codes, C order. A decode task is ``(slot, sequence index, side index, exposure index)``.

Decode once per chunk, shared by every process: :meth:`FrameBuffer.ensure` claims a frame in a shared state table
(one byte per frame, under a lock inherited by the forked workers); the first process that needs a frame decodes
it, every other one waits for it, so each bracket is decoded at most once per trajectory and only when a method's
target needs it.
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

#: (slot, sequence index, side index, exposure index) of one frame to decode
DecodeTask = tuple[int, int, int, int]

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
    """``slots`` sequences x ``len(sides)`` cameras x ``n_exp`` brackets of uint16 ``shape`` frames in one
    anonymous memory map (inherited by forked workers: decoded once, read by every worker).

    ``preloaded``: {(sequence index, side index, exposure index): uint16 HxW} frames already decoded (copied
    instead of decoded again)."""

    def __init__(self, sequences: list[BracketSequence], sides: tuple[str, ...], shape: tuple[int, int], n_exp: int,
                 slots: int, preloaded: dict[tuple[int, int, int], np.ndarray] | None = None) -> None:
        self.sequences, self.sides, self.shape, self.n_exp = sequences, sides, shape, n_exp
        self.preloaded = preloaded or {}
        #: set: decodes are timed there (stage ``decode``; see :mod:`~bracketry_emulator.stages`)
        self.stages: Any = None
        self.mmap = mmap.mmap(-1, slots * self.sequence_bytes(len(sides), n_exp, shape))
        #: one byte per frame (free, claimed, done, failed), shared with forked workers; guarded by ``lock``
        self.state = mmap.mmap(-1, max(1, slots * len(sides) * n_exp))
        self.lock = mp.get_context("fork").Lock() if "fork" in mp.get_all_start_methods() else mp.Lock()

    @staticmethod
    def sequence_bytes(n_sides: int, n_exp: int, shape: tuple[int, int]) -> int:
        """Bytes of one sequence's frames (every side and bracket)."""
        return n_sides * n_exp * shape[0] * shape[1] * 2

    def view(self, slot: int, side_i: int, exp_i: int) -> np.ndarray:
        """uint16 HxW view of one frame's place in the buffer."""
        h, w = self.shape
        n = h * w
        off = ((slot * len(self.sides) + side_i) * self.n_exp + exp_i) * n * 2
        return np.frombuffer(self.mmap, dtype=np.uint16, count=n, offset=off).reshape(h, w)

    def _decode_one(self, task: DecodeTask) -> None:
        if self.stages is None:
            return self._load(task)
        with self.stages.time("decode"):
            return self._load(task)

    def _load(self, task: DecodeTask) -> None:
        slot, seq_i, side_i, exp_i = task
        seq = self.sequences[seq_i]
        view = self.view(slot, side_i, exp_i)
        img = self.preloaded.get((seq_i, side_i, exp_i))
        if img is None:  # decoded straight into the buffer (a PNG), else copied there
            img = seq.frames[self.sides[side_i]][seq.exposures_us[exp_i]].load_into(view)
        if img.shape != self.shape:
            raise BracketryError(f"sequence {seq.index}: frame shape {img.shape} differs from {self.shape}")
        if img is not view:
            view[...] = img

    def decode(self, tasks: list[DecodeTask], pool: ThreadPoolExecutor | None = None) -> list[Future[None]]:
        """Decode frames into the buffer (unconditionally, without the state table): with ``pool`` on its threads
        (the decoders release the GIL; the futures are returned: wait on them before reading), else inline."""
        if pool is None:
            for task in tasks:
                self._decode_one(task)
            return []
        return [pool.submit(self._decode_one, task) for task in tasks]

    def state_index(self, task: DecodeTask) -> int:
        slot, _, side_i, exp_i = task
        return (slot * len(self.sides) + side_i) * self.n_exp + exp_i

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

    def reset(self) -> None:
        """Forget which frames are decoded (before the buffer is reused for the next chunk; nobody may be
        decoding)."""
        self.state[:] = bytes(len(self.state))

    def close(self) -> None:
        """Free the map (a BufferError while numpy views of it are alive: then it is freed with them)."""
        with contextlib.suppress(BufferError):
            self.mmap.close()
        with contextlib.suppress(BufferError):
            self.state.close()


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
