"""The shared frame buffer decodes each frame once for every worker process, and only when asked."""

from __future__ import annotations

import multiprocessing as mp
from concurrent.futures import ThreadPoolExecutor
from types import SimpleNamespace
from typing import Any

import numpy as np
import pytest

from bracketry_emulator.ae.decode import FrameBuffer

SHAPE = (4, 6)


def frame_value(seq_i: int, side_i: int, exp_i: int) -> np.ndarray:
    return np.full(SHAPE, 100 * seq_i + 10 * side_i + exp_i, np.uint16)


class CountingFrame:
    def __init__(self, counter: Any, key: tuple[int, int, int]) -> None:
        self.counter, self.key = counter, key

    def load(self) -> np.ndarray:
        with self.counter.get_lock():
            self.counter.value += 1
        return frame_value(*self.key)

    def load_into(self, out: np.ndarray) -> np.ndarray:  # as Frame.load_into
        img = self.load()
        if img.shape != out.shape:
            return img
        out[...] = img
        return out


def sequences(counter: Any, n_seq: int = 2, exps: tuple[int, ...] = (1000, 2000, 4000)) -> list[Any]:
    return [SimpleNamespace(index=q, exposures_us=exps,
                            frames={side: {e: CountingFrame(counter, (q, si, ei)) for ei, e in enumerate(exps)}
                                    for si, side in enumerate(("left", "right"))})
            for q in range(n_seq)]


def _ensure_all(fb: FrameBuffer, tasks: list[tuple[int, int, int, int]]) -> None:
    with ThreadPoolExecutor(1) as pool:
        for handle in fb.ensure(tasks, pool):
            handle.result()


def test_frames_decode_once_across_forked_workers() -> None:
    ctx = mp.get_context("fork")
    counter = ctx.Value("i", 0)
    fb = FrameBuffer(sequences(counter), ("left", "right"), SHAPE, 3, slots=2)
    every = [(slot, slot, si, ei) for slot in range(2) for si in range(2) for ei in range(3)]
    some = every[:5]  # the frames the methods need: only these are decoded
    procs = [ctx.Process(target=_ensure_all, args=(fb, list(reversed(some)) if k else some)) for k in range(3)]
    for p in procs:
        p.start()
    _ensure_all(fb, some)
    for p in procs:
        p.join(timeout=60)
        assert p.exitcode == 0
    assert counter.value == len(some)  # 4 processes asked, each frame was decoded once
    for slot, seq_i, si, ei in some:
        assert np.array_equal(fb.view(slot, si, ei), frame_value(seq_i, si, ei))
    _ensure_all(fb, every)
    assert counter.value == len(every)
    fb.reset()  # the next chunk reuses the buffer: decoded again
    _ensure_all(fb, some)
    assert counter.value == len(every) + len(some)
    fb.close()


def test_a_failed_decode_is_reported_to_the_waiting_worker() -> None:
    counter = mp.Value("i", 0)
    seqs = sequences(counter)
    seqs[0].frames["left"][1000].load = lambda: np.zeros((3, 3), np.uint16)  # the wrong shape
    fb = FrameBuffer(seqs, ("left", "right"), SHAPE, 3, slots=1)
    task = (0, 0, 0, 0)
    with ThreadPoolExecutor(1) as pool:
        (mine,) = fb.ensure([task], pool)
        (theirs,) = fb.ensure([task], pool)  # claimed already: waits for the first
        with pytest.raises(Exception, match="differs"):
            mine.result()
        with pytest.raises(Exception, match="failed"):
            theirs.result()
    fb.close()
