"""Runs many methods' closed loops over one dataset: worker processes, shared decoding, step order.

The methods are split over ``workers`` forked processes, balanced by the cost each method declares
(:func:`~.registry.method_traits`: ``step_cost``; methods of one ``step_group`` take identical first steps and stay
on one worker, whose writer then links images instead of encoding them again; methods of one ``start_up`` share it
on one worker where the balance allows). The decoded sequences live in one
shared :class:`~.decode.FrameBuffer`, a ring of :data:`RING_SLOTS` sequences at most (within the memory budget): a
slot is refilled once every worker is past the sequence it held. Every worker advances its methods through the
sequences, one by one (all methods of a worker take step k before any takes step k+1). Frames are
decoded on demand on a decode thread of each worker, only the brackets the methods' current targets can select
(:func:`~.emulation_cache.needed_brackets`), the next sequence's as soon as a method's next target is known, and
ONCE for all workers (the buffer's shared state table: a frame another worker decodes is waited for, not decoded
again). One worker runs in this process instead, the same way (two decode threads).

Each method's loop is :func:`~.loop.iter_loop`; images are emulated once per (sequence, side, target) for all the
methods of a worker (:class:`~.emulation_cache.EmulationCache`) and written by :mod:`.writers`.
"""

from __future__ import annotations

import contextlib
import functools
import gc
import itertools
import multiprocessing as mp
import os
import threading
import traceback
from collections.abc import Callable, Iterator
from concurrent.futures import Future, ThreadPoolExecutor
from dataclasses import dataclass
from multiprocessing.connection import Connection, wait
from pathlib import Path
from typing import Any

import numpy as np

from bracketry.errors import BracketryError

from ..dataset import BracketSequence
from ..emulation import EmulatedImage, Emulator, EmulatorConfig, RunWriter
from ..stages import StageTimes
from .decode import RELEASED_ALL, DecodeTask, FrameBuffer, frame_shape
from .emulation_cache import EmulationCache, needed_brackets
from .loop import Frame, MethodRun, Step, initial_exposure_us, iter_loop
from .registry import MethodTraits, get_method
from .writers import ImageSink, LinkingRunWriter, method_folder

#: Sequences held in the shared frame buffer at most (its ring of slots): a worker decodes at most this many sequences
#: ahead of the slowest one (it waits otherwise); every slot's pages stay mapped in every process once touched.
RING_SLOTS = 4

#: Estimated cost of emulating and writing one step (both cameras, stored PNGs; ~ms of CPU per 1920x1200 step here),
#: in the unit of the methods' ``step_cost``.
EMULATION_COST = 16


@dataclass(frozen=True)
class LoopSettings:
    """What every worker needs to know of a run (picklable; see :class:`~.runner.LoopConfig`).

    Exposures in us; ``ae_camera`` the side whose image the methods see; ``write_sides`` the sides written;
    ``emulate_sides`` every side emulated (write sides + AE camera)."""

    emulator: EmulatorConfig
    ae_camera: str
    write_sides: tuple[str, ...]
    emulate_sides: tuple[str, ...]
    init_exposure_us: float
    min_exposure_us: float
    max_exposure_us: float
    seed: int
    drl_weights: str | None
    write_images: bool
    png_compression: str
    overwrite: bool


def partition(traits: dict[str, MethodTraits], n: int) -> list[list[str]]:
    """Longest-processing-time-first split of the methods (in ``traits`` order) over ``n`` workers; the methods of
    one ``step_group`` stay together, and those of one ``start_up`` too (paid once per worker) where together they
    cost no more than an equal share of all; the order is kept within a worker."""
    specs = list(traits)
    grouped: dict[str, list[str]] = {}
    singles: list[list[str]] = []
    for spec in specs:
        group = traits[spec].step_group
        if group:
            grouped.setdefault(group, []).append(spec)
        else:
            singles.append([spec])
    units = [*grouped.values(), *singles]

    def cost(unit: list[str]) -> int:
        return sum(EMULATION_COST + traits[s].step_cost for s in unit)

    share = sum(cost(u) for u in units) / max(n, 1)
    for name in dict.fromkeys(traits[s].start_up for s in specs if traits[s].start_up):
        sharing = [u for u in units if any(traits[s].start_up == name for s in u)]
        merged = [s for u in sharing for s in u]
        if len(sharing) > 1 and cost(merged) <= share:
            units = [u for u in units if u not in sharing] + [merged]

    loads = [0] * n
    groups: list[list[str]] = [[] for _ in range(n)]
    for unit in sorted(units, key=cost, reverse=True):
        i = int(np.argmin(loads))
        groups[i].extend(unit)
        loads[i] += cost(unit)
    order = {s: k for k, s in enumerate(specs)}
    return [sorted(g, key=order.__getitem__) for g in groups if g]


class Worker:
    """Advances a group of methods through the sequences; the same object serves in-process and forked modes."""

    def __init__(self, specs: list[str], settings: LoopSettings, sequences: list[BracketSequence], out_dir: Path,
                 frames: FrameBuffer, write_threads: int = 1, feeds: dict[str, list[Any]] | None = None,
                 reader: int = 0) -> None:
        self.settings = s = settings
        #: this worker's reader number in ``frames`` (:meth:`FrameBuffer.release`)
        self.reader = reader
        #: where this worker's time goes (decode, emulation, png_write; the AE methods' is in their steps)
        self.stages = StageTimes()
        #: {method: [objects with RunWriter.write_step and close]}: each step's images also go there (e.g. to a
        #: SLAM process, :class:`~bracketry_emulator.slam.frame_stream.FrameFeed`); closed by :meth:`close`
        self.feeds = feeds or {}
        #: set: decode on demand (only the brackets the methods' targets need) on this pool's threads
        self.decode_pool: ThreadPoolExecutor | None = None
        self._decoded: dict[tuple[int, int, int], Any] = {}  # (position, side, exposure index): future-like
        # --parity upstream, single-bracket selections: the AE camera alone decides each step's source bracket, so
        # the other cameras need only that bracket of a pair: a decode thread picks it once the AE camera's pair is
        # decoded (:meth:`_decode_picked`). (position, target us): (the pick's future, the AE camera's pair of tasks).
        self._ae_i = s.emulate_sides.index(s.ae_camera)
        self._pick_alone = (s.emulator.parity == "upstream" and s.emulator.selection in ("upstream", "highernosat")
                            and len(s.emulate_sides) > 1)
        self._picks: dict[tuple[int, float], tuple[Future[list[DecodeTask]], list[DecodeTask]]] = {}
        self.sequences = sequences
        self.frames = frames
        frames.stages = self.stages
        self.emu = EmulationCache(s.emulator)
        self.sink = ImageSink(write_threads if s.write_images else 0, stages=self.stages)
        self.targets: dict[str, float] = {}
        self.runs: dict[str, MethodRun] = {}
        self.writers: dict[str, RunWriter] = {}
        self._loops: dict[str, Iterator[Step]] = {}
        self._brackets: dict[str, dict[int, np.ndarray]] = {}  # the current sequence's {side: {exposure_us: frame}}
        self._seq_i = -1
        for spec in specs:
            method = get_method(spec, seed=s.seed, drl_weights=s.drl_weights, parity=s.emulator.parity)
            self.targets[spec] = initial_exposure_us(method, s.init_exposure_us)
            self.runs[spec] = MethodRun(spec)
            self._loops[spec] = iter_loop(method, itertools.count(), functools.partial(self._emulate, spec), name=spec,
                                          init_exposure_us=s.init_exposure_us, min_exposure_us=s.min_exposure_us,
                                          max_exposure_us=s.max_exposure_us)
            self.writers[spec] = LinkingRunWriter(out_dir, method_folder(spec), s.write_sides, s.emulator.depth,
                                                  s.overwrite, self.sink, s.png_compression,
                                                  s.emulator.parity, images=s.write_images)

    def run(self, seq_indices: list[int], progress: Callable[[int], None]) -> None:
        """Advance every method of this worker through the given sequences (position = place in the list).

        Frames are decoded on demand on :attr:`decode_pool`'s threads (set it first), only the brackets that the
        methods' targets can select, once for every worker (:meth:`FrameBuffer.ensure`): a method's next target is
        known as soon as its step is done, so the next sequence's frames decode while the other methods run. Each
        position is released (:meth:`FrameBuffer.release`) once every method of this worker took its step (the
        emulated images are copies: nothing reads the buffer's frames of that position later)."""
        assert self.decode_pool is not None, "set decode_pool before run"
        self.emu.clear()
        self._decoded.clear()
        self._picks.clear()
        try:
            for pos, seq_i in enumerate(seq_indices):
                seq = self.sequences[seq_i]
                self.emu.clear()  # one sequence at a time: bounded memory; saturation keys use this slot's array ids
                self._brackets = {}
                self.frames.release(self.reader, pos)
                for t in self.targets.values():
                    self._prefetch(pos, seq_i, t)
                self._wait_needed(pos, seq_i)
                self._seq_i = seq_i
                self._brackets = {side: {e: self.frames.view(pos, si, ei) for ei, e in enumerate(seq.exposures_us)}
                                  for si, side in enumerate(self.settings.emulate_sides)}
                nxt = seq_indices[pos + 1] if pos + 1 < len(seq_indices) else None
                for spec, loop in self._loops.items():
                    step = next(loop)
                    self.runs[spec].steps.append(step)
                    self.targets[spec] = step.next_exposure_us
                    if nxt is not None:
                        self._prefetch(pos + 1, nxt, self.targets[spec])
                    progress(1)
        finally:
            self._brackets = {}
            handles = [*(f for f, _ in self._picks.values()), *self._decoded.values()]
            for f in handles:
                f.cancel()
            for f in handles:
                if not f.cancelled():
                    f.exception()  # wait: no decode of this worker may write into the buffer after this
            self.frames.release(self.reader, RELEASED_ALL)  # finished or failed: nobody waits for this worker
        self.emu.clear()

    def _images(self, seq_i: int, target_us: float) -> dict[str, EmulatedImage]:
        """Every emulated side of the current sequence at ``target_us``, all from one source bracket."""
        s = self.settings
        seq = self.sequences[seq_i]
        needed = needed_brackets(seq.exposures_us, target_us, s.emulator.selection)
        subsets = {side: {e: self._brackets[side][e] for e in needed} for side in s.emulate_sides}
        # one source bracket for every camera of the step; --parity upstream: the AE camera decides alone, as the
        # authors' left emulator (their right emulator decides on its own, which the joint decision corrects)
        decide = (s.ae_camera,) if s.emulator.parity == "upstream" else None
        source = self.emu.source(seq_i, subsets, target_us, decide)
        return {side: self.emu.emulate(seq_i, side, subsets[side], target_us, source) for side in s.emulate_sides}

    def _emulate(self, spec: str, seq_i: int, target_us: float) -> Frame:
        """The ``emulate`` of method ``spec``'s loop: the AE camera's image of the current sequence at ``target_us``.
        Every side is emulated and, before the method sees the image, written to the method's run (one step =
        one stereo capture)."""
        if seq_i != self._seq_i:
            raise RuntimeError(f"a method's loop asked for sequence {seq_i} while {self._seq_i} is loaded")
        s = self.settings
        seq = self.sequences[seq_i]
        with self.stages.time("emulation"):
            images = self._images(seq_i, target_us)
        self.writers[spec].write_step(seq_i, seq, {side: images[side] for side in s.write_sides}, target_us)
        for feed in self.feeds.get(spec, ()):
            feed.write_step(seq_i, seq, {side: images[side] for side in s.write_sides}, target_us)
        ae_img = images[s.ae_camera]
        return Frame(ae_img.image, seq.timestamps_ns[s.ae_camera][ae_img.source_exposure_us],
                     ae_img.source_exposure_us, seq.index,
                     {"side": s.ae_camera, "response": self.emu.emulator.response,
                      "shared_gray": self.emu.shared_gray(seq_i, s.ae_camera, target_us)})

    def _needed_keys(self, seq: BracketSequence, targets: list[float]) -> list[tuple[int, int]]:
        """(side index, exposure index) of the frames that emulating ``targets`` from ``seq`` can use."""
        exps = {e for t in targets for e in needed_brackets(seq.exposures_us, t, self.settings.emulator.selection)}
        return [(si, ei) for si in range(len(self.settings.emulate_sides)) for ei, e in enumerate(seq.exposures_us)
                if e in exps]

    def _prefetch(self, pos: int, seq_i: int, target_us: float) -> None:
        """Start decoding (on the pool's threads) the frames of ``seq_i`` that ``target_us`` needs, once each; with
        :attr:`_pick_alone` and a pair of brackets, the other cameras' frame once the AE camera's pair tells which."""
        assert self.decode_pool is not None
        keys = self._needed_keys(self.sequences[seq_i], [target_us])
        pick = self._pick_alone and len({ei for _, ei in keys}) > 1
        if pick:
            keys = [(si, ei) for si, ei in keys if si == self._ae_i]
        tasks = [(pos, seq_i, si, ei) for si, ei in keys if (pos, si, ei) not in self._decoded]
        futures = self.frames.ensure(tasks, self.decode_pool)
        for (_, _, si, ei), f in zip(tasks, futures, strict=True):
            self._decoded[(pos, si, ei)] = f
        if pick and (pos, float(target_us)) not in self._picks:
            pair = [(pos, seq_i, si, ei) for si, ei in keys]  # claimed before: no decode thread waits on a task
            fut = self.decode_pool.submit(self._decode_picked, pos, seq_i, target_us, pair)  # queued after it
            self._picks[(pos, float(target_us))] = (fut, pair)

    def _decode_picked(self, pos: int, seq_i: int, target_us: float, pair: list[DecodeTask]) -> list[DecodeTask]:
        """On a decode thread (or the worker's thread when it has not started): wait for the AE camera's pair of
        brackets, decide the step's source bracket as :meth:`_images` does (the AE camera alone), decode the other
        cameras' frame of it unless another thread or worker has claimed it. Returns those frames' tasks."""
        for task in pair:
            self.frames.wait(task)
        s = self.settings
        seq = self.sequences[seq_i]
        exps = needed_brackets(seq.exposures_us, target_us, s.emulator.selection)
        views = {s.ae_camera: {e: self.frames.view(pos, self._ae_i, seq.exposures_us.index(e)) for e in exps}}
        # a new emulator (the worker's caches belong to its main thread), the same decision
        source = Emulator(s.emulator, self.emu.emulator.response).select_stereo(views, target_us, (s.ae_camera,))
        ei = seq.exposures_us.index(source)
        tasks = [(pos, seq_i, si, ei) for si in range(len(s.emulate_sides)) if si != self._ae_i]
        for task in tasks:
            if self.frames.claim(task):
                self.frames.run_claimed(task)
        return tasks

    def _wait_needed(self, pos: int, seq_i: int) -> None:
        """Wait until every frame the current targets need is in the buffer (decoded by any worker; the frames whose
        decode has not started are decoded by this thread first, instead of waiting for the decode thread's
        queue)."""
        seq = self.sequences[seq_i]
        targets = list(dict.fromkeys(float(t) for t in self.targets.values()))
        frames: list[tuple[int, int]] = []
        for t in targets:
            pick = self._picks.get((pos, t))
            frames += [(si, ei) for si, ei in self._needed_keys(seq, [t]) if pick is None or si == self._ae_i]
        frames = list(dict.fromkeys(frames))
        for si, ei in frames:
            if self.frames.take((pos, seq_i, si, ei)):
                self.frames.run_taken((pos, seq_i, si, ei))
        for si, ei in frames:
            self._wait_frame(pos, seq_i, si, ei)
        for t in targets:
            pick = self._picks.get((pos, t))
            if pick is not None:
                fut, pair = pick
                # not started on the decode thread (queued behind other frames): pick and decode here
                tasks = self._decode_picked(pos, seq_i, t, pair) if fut.cancel() else fut.result()
                for task in tasks:
                    self.frames.wait(task)

    def _wait_frame(self, pos: int, seq_i: int, si: int, ei: int) -> None:
        try:
            self.frames.wait((pos, seq_i, si, ei))
        except BracketryError:
            self._decoded[(pos, si, ei)].result()  # a decode of this worker failed: raise its own error
            raise

    def close(self) -> tuple[dict[str, MethodRun], dict[str, dict[str, float]]]:
        """Finish the writes and the feeds; returns (the runs, this worker's stage times)."""
        try:
            for w in self.writers.values():
                w.close()
        finally:
            self.sink.close()
            for feed in (f for fs in self.feeds.values() for f in fs):
                feed.close()
        return self.runs, self.stages.as_dict()


#: ``workers=0`` (auto) forks worker processes only from this many sequences on; shorter runs are faster in one
#: process (forking, per-worker method start-up and result pickling cost more than they save; decoding and PNG
#: encoding use threads in-process anyway).
AUTO_FORK_MIN_SEQUENCES = 8


def run_scheduled(traits: dict[str, MethodTraits], settings: LoopSettings, sequences: list[BracketSequence],
                  out_dir: Path, *, workers: int, memory_budget_bytes: int,
                  progress: Callable[[int], None], feeds: dict[str, list[Any]] | None = None,
                  stages: StageTimes | None = None) -> dict[str, MethodRun]:
    """Every method's closed loop over ``sequences`` (at least one), its images written under ``out_dir``.

    ``traits``: {method id: what it declares}, in run order. ``workers``: processes (0 = min(methods, CPUs, 4)
    from :data:`AUTO_FORK_MIN_SEQUENCES` sequences on, else 1; 1 = in this process). ``progress(n)`` is called
    after every n method steps. Returns {method id: run} in ``traits`` order. Raises BracketryError (one line) on
    a failing method or worker. ``feeds``: see :class:`Worker`; ``stages``: receives the workers' stage times.
    ``memory_budget_bytes``: the shared frame buffer's size at most (a ring of :data:`RING_SLOTS` sequences at most,
    one at least).
    """
    specs = list(traits)
    n_seq = len(sequences)
    first = sequences[0]
    shape, first_img = frame_shape(first, settings.emulate_sides[0])
    preloaded = {} if first_img is None else {(0, 0, 0): first_img}  # decoded for the shape: reused
    n_exp = len(first.exposures_us)
    n_cpu = os.cpu_count() or 1
    if workers > 0:
        n_workers = workers
    else:  # auto: forking (and each worker's start-up) only pays off on long runs
        n_workers = min(len(specs), n_cpu, 4) if n_seq >= AUTO_FORK_MIN_SEQUENCES else 1
    can_fork = "fork" in mp.get_all_start_methods()
    n_workers = max(1, min(n_workers, len(specs))) if can_fork else 1
    groups = partition(traits, n_workers)
    seq_bytes = FrameBuffer.sequence_bytes(len(settings.emulate_sides), n_exp, shape)
    slots = max(1, min(n_seq, RING_SLOTS, memory_budget_bytes // max(seq_bytes, 1)))
    frames = FrameBuffer(sequences, settings.emulate_sides, shape, n_exp, slots, preloaded, positions=n_seq,
                         readers=len(groups))

    def make(reader: int, write_threads: int = 1) -> Callable[[], Worker]:
        group = groups[reader]
        return lambda: Worker(group, settings, sequences, out_dir, frames, write_threads,
                              {m: f for m, f in (feeds or {}).items() if m in group}, reader)

    runs: dict[str, MethodRun] = {}
    times = stages if stages is not None else StageTimes()
    try:
        if len(groups) == 1:
            runs.update(_run_in_process(make(0, min(2, n_cpu)), n_seq, progress, times))
        else:
            runs.update(_run_forked(len(groups), make, n_seq, frames, progress, times))
    finally:
        frames.close()  # on an error path the traceback may still hold views of the buffer: freed with them
    return {s: runs[s] for s in specs}


def _run_in_process(make: Callable[[], Worker], n_seq: int, progress: Callable[[int], None],
                    stages: StageTimes) -> dict[str, MethodRun]:
    """One worker in this process, decoding on demand on threads (cv2.imread releases the GIL); matplotlib is
    imported for the final plot on a thread meanwhile."""
    preload = threading.Thread(target=preload_plotting, name="bracketry-mpl-import", daemon=True)
    preload.start()
    try:
        with ThreadPoolExecutor(min(2, os.cpu_count() or 1), thread_name_prefix="bracketry-decode") as pool:
            w = make()
            w.decode_pool = pool
            try:
                w.run(list(range(n_seq)), progress)
            except BaseException:
                with contextlib.suppress(Exception):
                    w.sink.close()  # finish the images already submitted; the first error is the one raised
                raise
            runs, times = w.close()
            stages.merge(times)
            return runs
    finally:
        preload.join()


def _worker_loop(conn: Connection, worker: Callable[[], Worker]) -> None:
    """A forked worker: answers the parent's commands (decode, run, close) until closed; reports one error."""
    pool: ThreadPoolExecutor | None = None
    try:
        w = worker()
        # one decode thread per worker: the frames its methods need next decode while its methods run
        pool = w.decode_pool = ThreadPoolExecutor(1, thread_name_prefix="bracketry-decode")
        conn.send(("ready", None))
        while True:
            cmd, arg = conn.recv()
            if cmd == "run":
                w.run(arg, lambda n: conn.send(("progress", n)))
                conn.send(("ran", None))
            elif cmd == "close":
                conn.send(("closed", w.close()))
                return
    except BaseException as exc:  # report to the parent, which raises one clear line
        msg = str(exc) if isinstance(exc, BracketryError) else f"{type(exc).__name__}: {exc}"
        with contextlib.suppress(Exception):
            conn.send(("error", (msg, traceback.format_exc())))
    finally:
        if pool is not None:
            pool.shutdown(wait=True, cancel_futures=True)
        conn.close()


def _run_forked(n_workers: int, make: Callable[[int], Callable[[], Worker]], n_seq: int, frames: FrameBuffer,
                progress: Callable[[int], None], stages: StageTimes) -> dict[str, MethodRun]:
    ctx = mp.get_context("fork")
    procs: list[Any] = []
    conns: list[Connection] = []
    runs: dict[str, MethodRun] = {}
    done = False
    try:
        # the objects that exist at the fork (modules, the dataset) live as long as the run: frozen out of the
        # collector's reach, so the collections neither traverse them (a full one took 17-25 ms per worker) nor
        # copy their pages on write; collected again in this process after the run (a library caller lives on)
        gc.freeze()
        with _opencv_single_threaded():
            for reader in range(n_workers):
                parent, child = ctx.Pipe()
                p = ctx.Process(target=_worker_loop, args=(child, make(reader)), daemon=True)
                p.start()
                child.close()
                procs.append(p)
                conns.append(parent)
        # the parent only relays messages while the workers run: import matplotlib for the final plot meanwhile, on a
        # thread (the workers must not wait for it to be told to start)
        preload = threading.Thread(target=preload_plotting, name="bracketry-mpl-import", daemon=True)
        preload.start()
        _collect(conns, "ready", progress)
        for conn in conns:
            conn.send(("run", list(range(n_seq))))
        _collect(conns, "ran", progress)
        for conn in conns:
            conn.send(("close", None))
        for res, times in _collect(conns, "closed", progress):
            runs.update(res)
            stages.merge(times)
        preload.join()
        done = True
    finally:
        gc.unfreeze()
        if not done:
            frames.abort()  # a worker failed: the others stop waiting for its slots
        for conn in conns:
            conn.close()
        if done:  # every file is written: the workers' exit (freeing ~1 GB) is not waited for here
            threading.Thread(target=_reap, args=(procs,), name="bracketry-reap", daemon=True).start()
        else:
            _reap(procs)
    return runs


@contextlib.contextmanager
def _opencv_single_threaded() -> Iterator[None]:
    """OpenCV without its thread pool inside the block (the workers forked there inherit that; this process gets its
    thread count back after it). The work is spread over processes: the pool's threads only took CPU from the other
    workers and spun (sched_yield) after every parallel call (cvtColor, Sobel). Set before forking: a forked child
    must not change OpenCV's thread count itself, that waits forever on the pool the parent had running."""
    import cv2

    threads = cv2.getNumThreads()
    cv2.setNumThreads(1)
    try:
        yield
    finally:
        cv2.setNumThreads(threads)


def _reap(procs: list[Any]) -> None:
    """Wait for the worker processes to end (terminated after 10 s)."""
    for p in procs:
        p.join(timeout=10)
        if p.is_alive():
            p.terminate()
            p.join(timeout=5)


def preload_plotting() -> None:
    """Import matplotlib's figure module (when installed) and build its mathtext parser (the plot's log axis labels
    its ticks 10^k in mathtext; building the parser took ~40 ms of the final plot) while this process would
    otherwise wait."""
    import importlib.util

    if importlib.util.find_spec("matplotlib") is not None:
        import matplotlib.figure  # noqa: F401
        from matplotlib.mathtext import MathTextParser

        MathTextParser("agg").parse(r"$\mathdefault{10^{0}}$", 100)


def _collect(conns: list[Connection], expected: str, progress: Callable[[int], None]) -> list[Any]:
    """Wait until every worker answered ``expected`` (forwarding progress); raise on a worker error."""
    pending = {id(c): c for c in conns}
    results: dict[int, Any] = {}
    while pending:
        for c in wait(list(pending.values())):
            assert isinstance(c, Connection)
            try:
                kind, payload = c.recv()
            except EOFError as exc:
                raise BracketryError("an emulation worker process died (out of memory?)") from exc
            if kind == "progress":
                progress(payload)
            elif kind == "error":
                if os.environ.get("BRACKETRY_DEBUG") == "1":
                    print(payload[1])
                raise BracketryError(payload[0])
            elif kind == expected:
                results[id(c)] = payload
                del pending[id(c)]
    return [results[id(c)] for c in conns]
