"""One worker's frames: the plan of what its methods' targets need (:mod:`.decode_plan`) carried out on the shared
:class:`~.decode.FrameBuffer`.

A worker asks ahead (:meth:`FrameSource.prefetch`, as soon as a method's next target is known: the frames decode on
the pool's threads while the other methods step) and then loads a sequence (:meth:`FrameSource.load`: every frame
the current targets need is in the buffer; one not started yet is decoded by the calling thread instead of waiting
for the pool's queue). A plan's :class:`~.decode_plan.Pick` is resolved on a decode thread once the AE camera's
candidates are decoded: ``choose`` (the emulator's decision from the AE camera's brackets) names the bracket, and the
other cameras decode only that one.
"""

from __future__ import annotations

from collections.abc import Callable, Iterable
from concurrent.futures import Future, ThreadPoolExecutor
from typing import Any

import numpy as np

from ..dataset import BracketSequence
from .decode import RELEASED_ALL, DecodeTask, FrameBuffer
from .decode_plan import DecodeStrategy, Pick

#: (AE camera's {exposure_us: uint16 HxW} candidates, target us) -> the source bracket's exposure (us)
Choose = Callable[[dict[int, np.ndarray], float], int]


class FrameSource:
    """The frames of reader ``reader`` of ``frames`` (positions: places in the run's list of sequences), decoded as
    ``strategy`` plans; ``sides``: the emulated sides, in the buffer's order."""

    def __init__(self, frames: FrameBuffer, sequences: list[BracketSequence], sides: tuple[str, ...],
                 strategy: DecodeStrategy, choose: Choose, reader: int = 0) -> None:
        self.frames, self.sequences, self.sides = frames, sequences, sides
        self.strategy, self.choose, self.reader = strategy, choose, reader
        self.pool: ThreadPoolExecutor | None = None
        self._asked: set[tuple[int, int, int]] = set()  # (position, side index, exposure index)
        self._picks: dict[tuple[int, float], Future[list[DecodeTask]]] = {}
        self._pending: list[Future[None]] = []

    def start(self, pool: ThreadPoolExecutor) -> None:
        """Decode ahead on ``pool``'s threads from now on (a new run: nothing asked yet)."""
        self.pool = pool
        self._asked.clear()
        self._picks.clear()
        self._pending.clear()

    def prefetch(self, pos: int, seq_i: int, target_us: float) -> None:
        """Ask for the frames of sequence ``seq_i`` (at position ``pos``) that emulating ``target_us`` needs."""
        assert self.pool is not None, "start the frame source first"
        plan = self.strategy.plan(self.sequences[seq_i].exposures_us, (target_us,))
        tasks = [(pos, seq_i, si, ei) for si, ei in plan.frames if (pos, si, ei) not in self._asked]
        self._asked.update((pos, si, ei) for _, _, si, ei in tasks)
        self._pending += self.frames.prefetch(tasks, self.pool)
        for pick in plan.picks:
            if (pos, pick.target_us) not in self._picks:  # queued after its AE frames: no decode thread waits long
                self._picks[(pos, pick.target_us)] = self.pool.submit(self._resolve, pos, seq_i, pick)

    def load(self, pos: int, seq_i: int, targets_us: Iterable[float]) -> dict[str, dict[int, np.ndarray]]:
        """Release the positions before ``pos``, then return sequence ``seq_i``'s {side: {exposure_us: uint16 HxW
        view}} once every frame ``targets_us`` need is in the buffer (views of frames not needed are not to be
        read)."""
        self.frames.release(self.reader, pos)
        targets = list(dict.fromkeys(float(t) for t in targets_us))
        for t in targets:
            self.prefetch(pos, seq_i, t)
        seq = self.sequences[seq_i]
        plan = self.strategy.plan(seq.exposures_us, targets)
        tasks = [(pos, seq_i, si, ei) for si, ei in plan.frames]
        for task in tasks:  # the frames nobody started first (decoded here), then those decoding elsewhere
            self.frames.fetch(task, wait=False)
        for task in tasks:
            self.frames.fetch(task)
        for pick in plan.picks:
            fut = self._picks[(pos, pick.target_us)]
            # not started on the decode thread (queued behind other frames): resolved here
            tasks = self._resolve(pos, seq_i, pick) if fut.cancel() else fut.result()
            for task in tasks:
                self.frames.fetch(task)
        return {side: {e: self.frames.view(pos, si, ei) for ei, e in enumerate(seq.exposures_us)}
                for si, side in enumerate(self.sides)}

    def peek(self, pos: int, seq_i: int) -> dict[str, dict[int, np.ndarray]]:
        """Every bracket of every side of sequence ``seq_i`` (at position ``pos``, after the one loaded last) as
        {side: {exposure_us: uint16 HxW view}}, without releasing the current position: for methods that read the
        next step (``looks_ahead``; the buffer holds two positions at least)."""
        assert self.pool is not None, "start the frame source first"
        seq = self.sequences[seq_i]
        keys = [(si, ei) for si in range(len(self.sides)) for ei in range(len(seq.exposures_us))]
        tasks = [(pos, seq_i, si, ei) for si, ei in keys if (pos, si, ei) not in self._asked]
        self._asked.update((pos, si, ei) for _, _, si, ei in tasks)
        self._pending += self.frames.prefetch(tasks, self.pool)
        for si, ei in keys:
            self.frames.fetch((pos, seq_i, si, ei))
        return {side: {e: self.frames.view(pos, si, ei) for ei, e in enumerate(seq.exposures_us)}
                for si, side in enumerate(self.sides)}

    def _resolve(self, pos: int, seq_i: int, pick: Pick) -> list[DecodeTask]:
        """The AE camera's candidates decoded, its choice of bracket; that bracket of the other cameras decoded
        unless another thread does it (then :meth:`load` waits for it). Returns their tasks."""
        seq = self.sequences[seq_i]
        for si, ei in pick.ae_frames:
            self.frames.fetch((pos, seq_i, si, ei))
        views = {seq.exposures_us[ei]: self.frames.view(pos, si, ei)
                 for si, ei in sorted(pick.ae_frames, key=lambda k: seq.exposures_us[k[1]])}
        ei = seq.exposures_us.index(self.choose(views, pick.target_us))
        tasks = [(pos, seq_i, si, e) for si, e in pick.frames(ei)]
        for task in tasks:
            self.frames.fetch(task, wait=False)
        return tasks

    def finish(self) -> None:
        """Release every position (finished or failed: nobody waits for this reader, and a decode of this reader
        waiting for a slot it held goes on), cancel the decodes not started and wait for the others (none writes
        into the buffer after this)."""
        handles: list[Future[Any]] = [*self._picks.values(), *self._pending]
        for f in handles:
            f.cancel()
        self.frames.release(self.reader, RELEASED_ALL)
        for f in handles:
            if not f.cancelled():
                f.exception()
        self._picks.clear()
        self._pending.clear()
