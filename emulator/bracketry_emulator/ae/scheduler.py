"""Runs many methods' closed loops over one dataset: worker processes, shared decoding, step order.

The methods are split over ``workers`` forked processes, balanced by the cost each method declares
(:func:`~.registry.method_traits`: ``step_cost``; methods of one ``step_group`` take identical first steps and stay
on one worker, whose writer then links images instead of encoding them again; methods of one ``start_up`` share it
on one worker where the balance allows). Every worker steps its methods through the sequences, one by one (all
methods of a worker take step k before any takes step k+1), and writes their images (:mod:`.writers`). One worker
runs in this process instead, the same way.

Frames: one shared :class:`~.decode.FrameBuffer`, a ring of :data:`RING_SLOTS` sequences at most (within the memory
budget), each frame decoded once for all workers; a worker's :class:`~.frame_source.FrameSource` decodes what its
methods' targets need (:mod:`.decode_plan`), the next sequence's as soon as a method's next target is known. Images:
emulated once per (sequence, side, target) for all the methods of a worker (:class:`~.emulation_cache.EmulationCache`).
Each method's loop is :func:`~.loop.iter_loop`.
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
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass
from multiprocessing.connection import Connection, wait
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from bracketry_base.errors import BracketryError

from ..dataset import BracketSequence
from ..emulation import EmulatorConfig, RunWriter
from ..stages import StageTimes
from .decode import FrameBuffer, frame_shape
from .decode_plan import decode_strategy
from .emulation_cache import EmulationCache, needed_brackets
from .frame_source import FrameSource
from .loop import Frame, MethodRun, Step, initial_exposure_us, iter_loop
from .registry import MethodSpec, MethodTraits
from .truth import TruthCache
from .writers import ImageSink, LinkingRunWriter, method_folder

if TYPE_CHECKING:
    from .loop_config import LoopConfig

#: Sequences held in the shared frame buffer at most (its ring of slots): a worker decodes at most this many sequences
#: ahead of the slowest one (it waits otherwise); every slot's pages stay mapped in every process once touched.
RING_SLOTS = 4

#: Estimated cost of emulating and writing one step (both cameras, stored PNGs; ~ms of CPU per 1920x1200 step here),
#: in the unit of the methods' ``step_cost``.
EMULATION_COST = 16


@dataclass(frozen=True)
class LoopSettings:
    """What every worker needs to know of a run (picklable): the run's closed-loop settings ``loop``
    (:class:`~.runner.LoopConfig` itself, as the commands built it from the settings table) and what the run found
    in the dataset: ``write_sides`` the sides written, ``emulate_sides`` every side emulated (write sides + AE
    camera), ``truth_dir`` a synthetic trajectory whose world renders the images (truth runs, :mod:`.truth`; None:
    emulated)."""

    loop: LoopConfig
    write_sides: tuple[str, ...]
    emulate_sides: tuple[str, ...]
    truth_dir: str | None = None

    @property
    def emulator(self) -> EmulatorConfig:
        return self.loop.emulator

    @property
    def ae_camera(self) -> str:
        return self.loop.ae_camera


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
    """Steps a group of methods through the sequences and writes their images; the same object serves in-process
    and forked modes. Its frames come from a :class:`~.frame_source.FrameSource` (what to decode: the run's
    :func:`~.decode_plan.decode_strategy`)."""

    def __init__(self, methods: list[MethodSpec], settings: LoopSettings, sequences: list[BracketSequence],
                 out_dir: Path, frames: FrameBuffer, write_threads: int = 1, feeds: dict[str, list[Any]] | None = None,
                 reader: int = 0) -> None:
        self.settings = s = settings
        #: this worker's reader number in ``frames`` (:meth:`FrameBuffer.release`)
        self.reader = reader
        #: where this worker's time goes (decode, emulation, png_write; the AE methods' is in their steps)
        self.stages = StageTimes()
        #: {method: [objects with RunWriter.write_step and close]}: each step's images also go there (e.g. to a
        #: SLAM process, :class:`~bracketry_emulator.slam.frame_stream.FrameFeed`); closed by :meth:`close`
        self.feeds = feeds or {}
        self.sequences = sequences
        frames.stages = self.stages
        if s.truth_dir is not None:
            self.emu: EmulationCache = TruthCache(s.emulator, s.truth_dir)
        else:
            self.emu = EmulationCache(s.emulator)
        ae_i = s.emulate_sides.index(s.ae_camera)
        strategy = decode_strategy(s.emulator.selection, s.emulator.parity, len(s.emulate_sides), ae_i)
        self.source = FrameSource(frames, sequences, s.emulate_sides, strategy, self.emu.ae_choice(s.ae_camera),
                                  reader)
        self.sink = ImageSink(write_threads if s.loop.write_images else 0, stages=self.stages)
        #: each method's next camera exposure (us): what its next step's source bracket is chosen for
        self.targets: dict[str, float] = {}
        self.runs: dict[str, MethodRun] = {}
        self.writers: dict[str, RunWriter] = {}
        self._loops: dict[str, Iterator[Step]] = {}
        self._brackets: dict[str, dict[int, np.ndarray]] = {}  # the current sequence's {side: {exposure_us: frame}}
        self._seq_i = -1
        #: methods that read the next step's images (``looks_ahead``, non-causal controls such as the oracle)
        self._looking_ahead: set[str] = set()
        # the next sequence's emulations (a look-ahead's own cache; rendered too in a truth run)
        self._ahead_emu = (TruthCache(s.emulator, s.truth_dir) if s.truth_dir is not None
                           else EmulationCache(s.emulator))
        self._ahead: tuple[int, dict[str, dict[int, np.ndarray]]] | None = None  # (sequence, its brackets)
        for m in methods:  # each method created here, in the worker, from the spec it was handed
            spec = m.name
            method = m.create(seed=s.loop.seed, parity=s.emulator.parity)
            if getattr(method, "looks_ahead", False):
                self._looking_ahead.add(spec)
            self.targets[spec] = initial_exposure_us(method, s.loop.init_exposure_us)
            self.runs[spec] = MethodRun(spec)
            self._loops[spec] = iter_loop(method, itertools.count(), functools.partial(self._emulate, spec), name=spec,
                                          init_exposure_us=s.loop.init_exposure_us,
                                          min_exposure_us=s.loop.min_exposure_us,
                                          max_exposure_us=s.loop.max_exposure_us, warmup_steps=s.loop.warmup_steps,
                                          warmup=functools.partial(self._first_view, spec))
            self.writers[spec] = LinkingRunWriter(out_dir, method_folder(spec), s.write_sides, s.emulator.depth,
                                                  s.loop.overwrite, self.sink, s.loop.png_compression,
                                                  s.emulator.parity, images=s.loop.write_images)

    def run(self, seq_indices: list[int], progress: Callable[[int], None], decode_pool: ThreadPoolExecutor) -> None:
        """Step every method of this worker through the given sequences (position = place in the list): all take
        step k before any takes step k+1. A method's next target is known as soon as its step is done: the next
        sequence's frames it needs decode on ``decode_pool``'s threads while the other methods step."""
        self.emu.clear()
        self.source.start(decode_pool)
        try:
            for pos, seq_i in enumerate(seq_indices):
                self.emu.clear()  # one sequence at a time: bounded memory; saturation keys use this slot's array ids
                self._brackets = {}
                self._ahead = None
                self._ahead_emu.clear()
                self._brackets = self.source.load(pos, seq_i, self.targets.values())
                if pos == 0 and self.settings.loop.warmup_steps > 0:  # the warm-up's targets may need any bracket
                    self._brackets = self.source.peek(pos, seq_i)
                self._seq_i = seq_i
                nxt = seq_indices[pos + 1] if pos + 1 < len(seq_indices) else None
                if nxt is not None and self._looking_ahead:  # every bracket of the next sequence, kept in its slot
                    self._ahead = (nxt, self.source.peek(pos + 1, nxt))
                for spec, loop in self._loops.items():
                    step = next(loop)
                    self.runs[spec].steps.append(step)
                    self.targets[spec] = step.next_camera_exposure_us
                    if nxt is not None:
                        self.source.prefetch(pos + 1, nxt, step.next_camera_exposure_us)
                    progress(1)
        finally:
            self._brackets = {}
            self._ahead = None
            self.source.finish()
        self.emu.clear()
        self._ahead_emu.clear()

    def _emulate(self, spec: str, seq_i: int, target_us: float, gain_db: float | None = None,
                 record: bool = True) -> Frame:
        """The ``emulate`` of method ``spec``'s loop: the AE camera's image of the current sequence at ``target_us``
        (with ``gain_db``: the gain the method set). Every side is emulated and, before the method sees the image,
        written to the method's run (one step = one stereo capture; not with ``record`` False: a warm-up step)."""
        if seq_i != self._seq_i:
            raise RuntimeError(f"a method's loop asked for sequence {seq_i} while {self._seq_i} is loaded")
        s = self.settings
        seq = self.sequences[seq_i]
        with self.stages.time("emulation"):
            images = self.emu.stereo(seq_i, self._brackets, target_us, s.ae_camera, seq.timestamps_ns, gain_db)
        if record:
            self.writers[spec].write_step(seq_i, seq, {side: images[side] for side in s.write_sides}, target_us)
            for feed in self.feeds.get(spec, ()):
                feed.write_step(seq_i, seq, {side: images[side] for side in s.write_sides}, target_us)
        ae_img = images[s.ae_camera]
        meta: dict[str, Any] = {"side": s.ae_camera, "response": self.emu.emulator.response,
                                "shared_gray": self.emu.shared_gray(seq_i, s.ae_camera, target_us, gain_db)}
        if spec in self._looking_ahead:
            meta["look_ahead"] = self._look_ahead
        return Frame(ae_img.image, seq.timestamps_ns[s.ae_camera][ae_img.source_exposure_us],
                     ae_img.source_exposure_us, seq.index, meta, ae_img.gain_db)

    def _first_view(self, spec: str, target_us: float, gain_db: float | None = None) -> Frame:
        """A warm-up step's image: the first sequence (loaded) at ``target_us`` (and ``gain_db``), not written."""
        return self._emulate(spec, self._seq_i, target_us, gain_db, record=False)

    def _look_ahead(self, target_us: float, offset: int) -> np.ndarray | None:
        """The AE camera's image (uint16 HxW, read-only) at ``target_us`` of the current sequence (``offset`` 0) or
        the next one (1; None after the last), emulated as the loop would emulate it (the same source bracket of the
        stereo decision). Given only to methods that declare ``looks_ahead`` (non-causal controls)."""
        s = self.settings
        if offset == 0:
            seq_i, brackets, emu = self._seq_i, self._brackets, self.emu
        elif offset == 1:
            if self._ahead is None:
                return None
            (seq_i, brackets), emu = self._ahead, self._ahead_emu
        else:
            raise ValueError(f"look_ahead offset must be 0 or 1, got {offset}")
        exps = tuple(next(iter(brackets.values())))
        needed = needed_brackets(exps, target_us, s.emulator.selection)
        subsets = {side: {e: frames[e] for e in needed} for side, frames in brackets.items()}
        decide = (s.ae_camera,) if s.emulator.parity == "upstream" else None
        source = emu.source(seq_i, subsets, target_us, decide)
        times = self.sequences[seq_i].timestamps_ns.get(s.ae_camera)
        return emu.emulate(seq_i, s.ae_camera, subsets[s.ae_camera], target_us, source, times).image

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


def run_scheduled(methods: dict[str, MethodSpec], traits: dict[str, MethodTraits], settings: LoopSettings,
                  sequences: list[BracketSequence],
                  out_dir: Path, *, workers: int, memory_budget_bytes: int,
                  progress: Callable[[int], None], feeds: dict[str, list[Any]] | None = None,
                  stages: StageTimes | None = None) -> dict[str, MethodRun]:
    """Every method's closed loop over ``sequences`` (at least one), its images written under ``out_dir``.

    ``methods``: {method name: the method, created by each worker from it}; ``traits``: {method name: what it
    declares}, in run order. ``workers``: processes (0 = min(methods, CPUs, 4)
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
    if any(t.looks_ahead for t in traits.values()):  # the current sequence and the next one are read together
        slots = max(slots, min(n_seq, 2))
    frames = FrameBuffer(sequences, settings.emulate_sides, shape, n_exp, slots, preloaded, positions=n_seq,
                         readers=len(groups))

    def make(reader: int, write_threads: int = 1) -> Callable[[], Worker]:
        group = groups[reader]
        return lambda: Worker([methods[m] for m in group], settings, sequences, out_dir, frames, write_threads,
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
            try:
                w.run(list(range(n_seq)), progress, pool)
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
        pool = ThreadPoolExecutor(1, thread_name_prefix="bracketry-decode")
        conn.send(("ready", None))
        while True:
            cmd, arg = conn.recv()
            if cmd == "run":
                w.run(arg, lambda n: conn.send(("progress", n)), pool)
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
