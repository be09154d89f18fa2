"""The shared frame buffer decodes each frame once for every worker process, and only when asked (with
``--parity upstream``, only the other camera's bracket the AE camera picks)."""

from __future__ import annotations

import csv
import multiprocessing as mp
import threading
import time
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path
from types import SimpleNamespace
from typing import Any

import cv2
import numpy as np
import pytest
from ae_scenes import irradiance, render

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
        fb.prefetch(tasks, pool)
        for task in tasks:
            fb.fetch(task)


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
    fb.close()


def _read_positions(fb: FrameBuffer, reader: int, delay_s: float, conn: Any) -> None:
    """A worker reading every frame of positions 0..3 in turn, holding each position ``delay_s``."""
    from bracketry_emulator.ae.decode import RELEASED_ALL

    ok = True
    with ThreadPoolExecutor(1) as pool:
        for pos in range(4):
            fb.release(reader, pos)
            tasks = [(pos, pos, si, ei) for si in range(2) for ei in range(3)]
            fb.prefetch(tasks[::-1] if reader else tasks, pool)
            for task in tasks:
                fb.fetch(task)
            for wait in (0.0, delay_s):  # read again after the pause: nobody refilled the slot meanwhile
                time.sleep(wait)
                ok = ok and all(np.array_equal(fb.view(p, si, ei), frame_value(q, si, ei)) for p, q, si, ei in tasks)
    fb.release(reader, RELEASED_ALL)
    conn.send(ok)


def test_two_workers_share_a_two_slot_ring() -> None:
    """Two forked workers fetch every frame of four positions through two slots, one of them slow: each frame is
    decoded once, and the fast one waits (on the buffer's condition) until the slow one released a slot's sequence
    before refilling it."""
    ctx = mp.get_context("fork")
    counter = ctx.Value("i", 0)
    fb = FrameBuffer(sequences(counter, n_seq=4), ("left", "right"), SHAPE, 3, slots=2, positions=4, readers=2)
    pipes = [ctx.Pipe() for _ in range(2)]
    procs = [ctx.Process(target=_read_positions, args=(fb, r, 0.05 if r else 0.0, pipes[r][1])) for r in range(2)]
    for p in procs:
        p.start()
    for (parent, _), p in zip(pipes, procs, strict=True):
        assert parent.poll(60) and parent.recv() is True
        p.join(30)
        assert p.exitcode == 0
    assert counter.value == 4 * 2 * 3
    fb.close()


def _fetch_and_report(fb: FrameBuffer, task: tuple[int, int, int, int], conn: Any) -> None:
    try:
        fb.fetch(task)
        conn.send("ok")
    except Exception as exc:
        conn.send(str(exc))


def test_a_failed_decode_is_reported_to_the_waiting_worker() -> None:
    """A decode that fails raises its own error where it ran (again on every later fetch there), and a clear
    'failed in another worker process' in a worker that waited for it."""
    ctx = mp.get_context("fork")
    counter = ctx.Value("i", 0)
    seqs = sequences(counter)
    gate = ctx.Event()

    def wrong_shape() -> np.ndarray:
        gate.wait(30)
        return np.zeros((3, 3), np.uint16)

    seqs[0].frames["left"][1000].load = wrong_shape
    fb = FrameBuffer(seqs, ("left", "right"), SHAPE, 3, slots=1)
    task = (0, 0, 0, 0)
    with ThreadPoolExecutor(1) as pool:
        (mine,) = fb.prefetch([task], pool)
        assert fb.prefetch([task], pool) == []  # queued already: not again
        while fb.state[0] != 2:  # running on the decode thread (blocked on the gate)
            time.sleep(0.01)
        parent, child = ctx.Pipe()
        other = ctx.Process(target=_fetch_and_report, args=(fb, task, child))
        other.start()  # waits for this process's decode
        time.sleep(0.2)
        gate.set()
        with pytest.raises(Exception, match="differs"):
            mine.result()
        with pytest.raises(Exception, match="differs"):
            fb.fetch(task)
        assert parent.poll(30) and "failed in another worker process" in parent.recv()
        other.join(30)
    fb.close()


def test_a_waiting_thread_decodes_a_frame_still_queued() -> None:
    """The decode thread is busy (blocked here): a thread that needs a frame queued behind decodes it itself, and
    the decode thread, when it gets there, does not decode it again."""
    counter = mp.Value("i", 0)
    seqs = sequences(counter)
    gate = threading.Event()
    first = seqs[0].frames["left"][1000]
    slow = first.load

    def blocked() -> np.ndarray:
        gate.wait(30)
        return slow()

    first.load = blocked
    fb = FrameBuffer(seqs, ("left", "right"), SHAPE, 3, slots=1)
    with ThreadPoolExecutor(1) as pool:
        busy, queued = fb.prefetch([(0, 0, 0, 0), (0, 0, 1, 2)], pool)
        fb.fetch((0, 0, 1, 2))  # decoded here while the decode thread is blocked on the first frame
        assert np.array_equal(fb.view(0, 1, 2), frame_value(0, 1, 2)) and counter.value == 1
        assert not busy.done()
        gate.set()
        busy.result()
        queued.result()
    assert counter.value == 2  # the queued frame was not decoded a second time
    fb.close()


def _bracket_tree(root: Path, n_seq: int, brighter_per_sequence: float = 1.0) -> Path:
    """A BorealHDR tree of 40x56 frames, the right camera brighter than the left (saturated at other brackets), a
    dark half (black at 1 ms): the upstream selection takes the longer bracket of some pairs, the shorter of others.
    Each sequence's scene ``brighter_per_sequence`` times the previous one's."""
    irr = irradiance(40, 56, seed=4, dynamic_range=30.0)
    irr[:, :28] *= 0.001
    t_ns = 1_700_000_000_000_000_000
    for q in range(n_seq):
        for ms in (1.0, 2.0, 4.0, 8.0, 16.0, 32.0):
            for side, gain in (("left", brighter_per_sequence ** q), ("right", 2.5 * brighter_per_sequence ** q)):
                d = root / f"camera_{side}" / f"{ms:.1f}"
                d.mkdir(parents=True, exist_ok=True)
                cv2.imwrite(str(d / f"{t_ns}.png"), render(irr * gain, ms * 1000))
            t_ns += 46_000_000
    return root


@pytest.mark.parametrize("workers", [1, 2])
def test_upstream_parity_decodes_only_the_source_bracket_of_the_other_camera(
        tmp_path: Path, workers: int, monkeypatch: pytest.MonkeyPatch) -> None:
    """--parity upstream: the AE camera alone picks each step's source bracket, so the right camera decodes just
    the picked bracket of each pair (each once); the outputs equal those of a run decoding both brackets."""
    from bracketry_emulator.ae import LoopConfig, run_methods
    from bracketry_emulator.ae import scheduler as sch
    from bracketry_emulator.ae.decode_plan import EveryCamera
    from bracketry_emulator.ae.emulation_cache import needed_brackets
    from bracketry_emulator.emulation.settings import emulator_config

    rec = _bracket_tree(tmp_path / "rec", 3)
    log = tmp_path / "decodes.txt"
    load = FrameBuffer._load

    def counted(fb: FrameBuffer, task: tuple[int, int, int, int]) -> None:
        with open(log, "a") as f:  # one line per decode, from every worker process
            f.write(f"{task[1]} {fb.sides[task[2]]} {fb.sequences[task[1]].exposures_us[task[3]]}\n")
        load(fb, task)

    monkeypatch.setattr(FrameBuffer, "_load", counted)
    methods = ["fix", "ae30", "ae50", "ae70", "shim"]

    def run(out: Path) -> list[tuple[int, str, int]]:
        log.write_text("")
        cfg = LoopConfig(emulator=emulator_config("upstream", "srgb", "upstream"), init_exposure_us=3000.0)
        run_methods(rec, methods, out, workers=workers, config=cfg, progress=False)
        return [(int(q), side, int(e)) for q, side, e in (line.split() for line in log.read_text().splitlines())]

    picked = run(tmp_path / "picked")
    assert len(picked) == len(set(picked))  # each frame decoded once
    exps = (1000, 2000, 4000, 8000, 16000, 32000)
    kinds = set()
    for q in range(3):
        steps = [row for m in methods
                 for row in csv.DictReader((tmp_path / "picked" / m / "steps.csv").read_text().splitlines())
                 if int(row["step"]) == q]
        sources = {round(float(r["source_exposure_ms"]) * 1000) for r in steps}
        for r in steps:
            pair = needed_brackets(exps, float(r["target_exposure_ms"]) * 1000, "upstream")
            if len(pair) == 2:
                kinds.add("shorter" if round(float(r["source_exposure_ms"]) * 1000) == pair[0] else "longer")
        needed = {e for r in steps for e in needed_brackets(exps, float(r["target_exposure_ms"]) * 1000, "upstream")}
        assert {e for s, side, e in picked if s == q and side == "right"} == sources
        assert {e for s, side, e in picked if s == q and side == "left"} == needed
    assert sum(side == "right" for _, side, _ in picked) < sum(side == "left" for _, side, _ in picked)
    assert {"shorter", "longer"} <= kinds  # the AE camera picked each bracket of a pair somewhere

    monkeypatch.setattr(sch, "decode_strategy", lambda selection, parity, n_sides, ae_side: EveryCamera(selection,
                                                                                                          n_sides))
    everything = run(tmp_path / "both")
    assert set(picked) < set(everything)
    for f in sorted((tmp_path / "both").rglob("*")):
        if f.is_file() and f.name not in ("summary.json", "ae.csv", "exposure_times.png"):
            assert f.read_bytes() == (tmp_path / "picked" / f.relative_to(tmp_path / "both")).read_bytes(), f


def test_a_ring_slot_is_refilled_only_once_every_reader_passed_its_sequence() -> None:
    """Positions 0..3 in 2 slots: position 2 reuses position 0's slot; its decode waits until both readers released
    position 0, and an aborted buffer makes a waiting decode raise."""
    counter = mp.Value("i", 0)
    fb = FrameBuffer(sequences(counter, n_seq=4), ("left", "right"), SHAPE, 3, slots=2, positions=4, readers=2)
    assert np.shares_memory(fb.view(2, 1, 2), fb.view(0, 1, 2))
    assert not np.shares_memory(fb.view(1, 0, 0), fb.view(0, 0, 0))
    _ensure_all(fb, [(0, 0, 0, 0), (1, 1, 0, 0)])  # both slots filled at once: nobody has to release anything
    with ThreadPoolExecutor(1) as pool:
        (third,) = fb.prefetch([(2, 2, 0, 0)], pool)
        fb.release(0, 1)  # reader 0 is past position 0, reader 1 still reads it
        with pytest.raises(TimeoutError):
            third.result(timeout=0.3)
        assert np.array_equal(fb.view(0, 0, 0), frame_value(0, 0, 0))  # not overwritten while read
        fb.release(1, 1)
        third.result(timeout=30)
    assert np.array_equal(fb.view(2, 0, 0), frame_value(2, 0, 0)) and counter.value == 3
    with ThreadPoolExecutor(1) as pool:
        (fourth,) = fb.prefetch([(3, 3, 0, 0)], pool)  # slot 1: reader 0 is still at position 1
        fb.abort()
        with pytest.raises(Exception, match="aborted"):
            fourth.result(timeout=30)
    fb.close()


@pytest.mark.parametrize("workers", [1, 2])
def test_a_run_through_a_two_slot_ring_gives_the_outputs_of_a_run_without_reuse(
        tmp_path: Path, workers: int, monkeypatch: pytest.MonkeyPatch) -> None:
    """6 sequences (each scene brighter) through 2 frame-buffer slots; the methods of both workers keep targets
    near each other (they read the same frames) and the second worker is slowed down (the first one runs ahead and
    must wait for it before refilling a slot): every output file equals that of a run with a slot per sequence."""
    from bracketry_emulator.ae import LoopConfig, run_methods
    from bracketry_emulator.ae import scheduler as sch
    from bracketry_emulator.emulation.settings import emulator_config

    rec = _bracket_tree(tmp_path / "rec", 6, brighter_per_sequence=1.15)
    emulate = sch.Worker._emulate

    def slow_second_worker(self: sch.Worker, *args: Any) -> Any:
        if self.reader == 1:
            time.sleep(0.02)
        return emulate(self, *args)

    monkeypatch.setattr(sch.Worker, "_emulate", slow_second_worker)
    methods = ["fix", "constant-3", "ae50"]
    cfg = LoopConfig(emulator=emulator_config("upstream", "srgb", "upstream"), init_exposure_us=3000.0)
    for name, slots in (("ring", 2), ("all", 64)):
        monkeypatch.setattr(sch, "RING_SLOTS", slots)
        run_methods(rec, methods, tmp_path / name, workers=workers, config=cfg, progress=False)
    files = sorted(f.relative_to(tmp_path / "all") for f in (tmp_path / "all").rglob("*") if f.is_file())
    assert sum(f.suffix == ".png" for f in files) == 6 * 2 * len(methods) + 1
    for f in files:
        if f.name not in ("summary.json", "ae.csv", "exposure_times.png"):
            assert (tmp_path / "ring" / f).read_bytes() == (tmp_path / "all" / f).read_bytes(), f


FORK_AFTER_OPENCV = """
import gc
import sys
import cv2
import numpy as np
from bracketry_emulator.ae import LoopConfig, run_methods
from bracketry_emulator.emulation.settings import emulator_config

threads = cv2.getNumThreads()
for _ in range(20):  # OpenCV's thread pool running in this process before the workers fork
    cv2.cvtColor(np.zeros((1200, 1920), np.uint16), cv2.COLOR_BAYER_RG2GRAY)
cfg = LoopConfig(emulator=emulator_config("upstream", "srgb", "upstream"), init_exposure_us=3000.0)
summary = run_methods(sys.argv[1], ["ae50", "shim"], sys.argv[2], workers=2, config=cfg, progress=False)
assert summary.stages["png_write"]["count"] > 0  # written by the workers
assert cv2.getNumThreads() == threads  # given back to this process after forking
assert gc.get_freeze_count() == 0  # the objects frozen for the workers' sake are collectable here again
print("done")
"""


def test_forked_workers_after_this_process_ran_opencv_threads(tmp_path: Path) -> None:
    """The workers are forked with OpenCV single-threaded; a process whose OpenCV pool was running before still gets
    its run (a child that changed OpenCV's thread count itself waited forever on the parent's pool), and its OpenCV
    thread count and garbage collection (the objects frozen at the fork) back afterwards."""
    import subprocess
    import sys

    rec = _bracket_tree(tmp_path / "rec", 2)
    out = subprocess.run([sys.executable, "-c", FORK_AFTER_OPENCV, str(rec), str(tmp_path / "out")],
                         capture_output=True, text=True, timeout=120)
    assert out.returncode == 0 and out.stdout.strip() == "done", out.stderr[-2000:]


def _wait_once(cond: Any, flag: Any, conn: Any) -> None:
    with cond:
        while not flag.value:
            cond.wait()
    conn.send("woken")


def test_the_shared_condition_wakes_waiters_in_other_processes_and_threads() -> None:
    """notify_all wakes every thread waiting in any forked process (each on its own semaphore); a thread too many
    is refused instead of waiting unseen."""
    from bracketry_emulator.ae.decode import _SharedCondition

    ctx = mp.get_context("fork")
    cond, flag = _SharedCondition(ctx, 3), ctx.Value("i", 0)
    pipes = [ctx.Pipe() for _ in range(2)]
    procs = [ctx.Process(target=_wait_once, args=(cond, flag, child)) for _, child in pipes]
    for p in procs:
        p.start()
    thread_pipe = ctx.Pipe()
    waiter = threading.Thread(target=_wait_once, args=(cond, flag, thread_pipe[1]))
    waiter.start()
    while True:  # all three waiting: every semaphore taken
        with cond:
            if cond._waiting.find(b"\0") < 0:
                with pytest.raises(RuntimeError, match="more than 3 threads"):
                    cond.wait()
                break
        time.sleep(0.01)
    with cond:
        flag.value = 1
        cond.notify_all()
    for parent, _ in [*pipes, thread_pipe]:
        assert parent.poll(30) and parent.recv() == "woken"
    waiter.join(30)
    for p in procs:
        p.join(30)
        assert p.exitcode == 0


FAIL_AFTER_PREFETCH = """
import sys
from bracketry_emulator.ae import LoopConfig, run_methods
from bracketry_emulator.ae import scheduler as sch

sch.RING_SLOTS = 1  # the next sequence's decode waits for this worker to leave the current one
try:
    run_methods(sys.argv[1], ["ae50", "failing_ae:FailsAtStep2"], sys.argv[2], workers=int(sys.argv[3]),
                config=LoopConfig(), progress=False)
except Exception as exc:
    print(str(exc))
"""

FAILING_METHOD = """
import time


class FailsAtStep2:
    name = "fails"

    def reset(self, init_exposure_us):
        self.n = 0

    def next_exposure_us(self, image, exposure_us, meta):
        self.n += 1
        if self.n == 2:
            time.sleep(0.5)  # ae50's next sequence is decoding (waiting for the slot) by now
            raise ValueError("boom")
        return exposure_us * 1.5
"""


@pytest.mark.parametrize("workers", [1, 2])
def test_a_method_failing_after_another_asked_for_the_next_sequence_ends_the_run(tmp_path: Path,
                                                                                 workers: int) -> None:
    """One slot: ae50's next sequence decodes on the decode thread, waiting for the worker to leave the current
    one; the next method fails there: the run ends with its error (the decode was waited for before the worker
    released its slot, forever)."""
    import os
    import subprocess
    import sys

    rec = _bracket_tree(tmp_path / "rec", 3)
    (tmp_path / "failing_ae.py").write_text(FAILING_METHOD)
    env = {**os.environ, "PYTHONPATH": os.pathsep.join([str(tmp_path), os.environ.get("PYTHONPATH", "")])}
    out = subprocess.run([sys.executable, "-c", FAIL_AFTER_PREFETCH, str(rec), str(tmp_path / "out"), str(workers)],
                         capture_output=True, text=True, timeout=120, env=env)
    assert out.returncode == 0 and "boom" in out.stdout, out.stderr[-2000:]
