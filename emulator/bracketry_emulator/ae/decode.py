"""The decoded frames of a chunk of bracket sequences, in one anonymous shared memory map (shared by forked workers).

Layout: ``slot`` (position of the sequence in the chunk) x ``side`` x ``exposure`` frames of uint16 HxW raw Bayer
codes, C order. A decode task is ``(slot, sequence index, side index, exposure index)``.
"""

from __future__ import annotations

import contextlib
import mmap
from concurrent.futures import Future, ThreadPoolExecutor
from pathlib import Path

import numpy as np

from bracketry.errors import BracketryError

from ..dataset import BracketSequence

#: (slot, sequence index, side index, exposure index) of one frame to decode
DecodeTask = tuple[int, int, int, int]


class FrameBuffer:
    """``slots`` sequences x ``len(sides)`` cameras x ``n_exp`` brackets of uint16 ``shape`` frames in one
    anonymous memory map (inherited by forked workers: decoded once, read by every worker).

    ``preloaded``: {(sequence index, side index, exposure index): uint16 HxW} frames already decoded (copied
    instead of decoded again)."""

    def __init__(self, sequences: list[BracketSequence], sides: tuple[str, ...], shape: tuple[int, int], n_exp: int,
                 slots: int, preloaded: dict[tuple[int, int, int], np.ndarray] | None = None) -> None:
        self.sequences, self.sides, self.shape, self.n_exp = sequences, sides, shape, n_exp
        self.preloaded = preloaded or {}
        self.mmap = mmap.mmap(-1, slots * self.sequence_bytes(len(sides), n_exp, shape))

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

    def decode(self, tasks: list[DecodeTask], pool: ThreadPoolExecutor | None = None) -> list[Future[None]]:
        """Decode frames into the buffer: with ``pool`` on its threads (cv2.imread releases the GIL; the futures
        are returned: wait on them before reading), else inline."""

        def one(task: DecodeTask) -> None:
            slot, seq_i, side_i, exp_i = task
            seq = self.sequences[seq_i]
            img = self.preloaded.get((seq_i, side_i, exp_i))
            if img is None:
                img = seq.frames[self.sides[side_i]][seq.exposures_us[exp_i]].load()
            if img.shape != self.shape:
                raise BracketryError(f"sequence {seq.index}: frame shape {img.shape} differs from {self.shape}")
            self.view(slot, side_i, exp_i)[...] = img

        if pool is None:
            for task in tasks:
                one(task)
            return []
        return [pool.submit(one, task) for task in tasks]

    def close(self) -> None:
        """Free the map (a BufferError while numpy views of it are alive: then it is freed with them)."""
        with contextlib.suppress(BufferError):
            self.mmap.close()


def decode_tasks(seq_indices: list[int], n_sides: int, n_exp: int) -> list[DecodeTask]:
    """Every frame of ``seq_indices`` (slot = position in the list)."""
    return [(slot, seq_i, si, ei) for slot, seq_i in enumerate(seq_indices) for si in range(n_sides)
            for ei in range(n_exp)]


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
