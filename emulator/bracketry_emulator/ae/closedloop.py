"""Closed-loop runs of AE methods on a bracketed dataset: decode once, emulate for all, parallel over processes.

Python API::

    from bracketry_emulator.ae import run_methods
    summary = run_methods("path/to/dataset", ["ae50", "shim", "kim"], "out/", workers=2)

At step k (the k-th complete bracket sequence) every method's current target exposure is emulated for every camera
side, the images are written (the emulator output layout, :class:`RunWriter`), and the method sees the image of
``ae_side`` (default left, as the authors) to choose the next target, which is clamped to the run's bounds.

Bounds (explicit, documented; the authors clamp nothing in the loop): ``min_exposure_us`` = 20 us (the authors'
only floor, Zhang's 0.02 ms) and ``max_exposure_us`` = 64 ms (2x the sample's longest bracket: beyond it the
emulation extrapolates more than one stop above any recorded frame). The first target is ``init_exposure_us``
(4 ms, as the authors) unless a method carries its own ``init_exposure_us`` attribute (constant-<ms>).

Parallelism: the methods are split over ``workers`` forked processes (balanced by an estimated cost); the
sequences are processed in chunks that fit ``memory_budget_bytes``: each chunk's PNGs are decoded ONCE (split over
the workers) into one shared anonymous memory map, then every worker runs its methods through the chunk. Within a
worker, identical emulations (same sequence, side and target) are computed once and identical output images are
hard links (see :class:`_LinkingRunWriter`). ``workers`` = 1 runs in-process, and so does ``workers`` = 0
(auto) below :data:`AUTO_FORK_MIN_SEQUENCES` sequences; in-process, a sequence's frames are decoded on demand on 2
threads, only the brackets the methods' current targets can select (:func:`_needed_brackets`).
With ``write_images=False`` only the exposure trajectories (ae.csv, summaries, plot) are written. Images
are lossless PNGs written stored (``stored_png``, default: ~4x faster to encode, ~20% larger; see
:mod:`..emulation.writer`) on background threads.

Outputs in ``out_dir``: ``<method>/`` (images_left|right/, times_images_*.txt, steps.csv, plus ``ae.csv``: step,
timestamp_ns, exposure_ms, next_exposure_ms, ae_ms, and ``summary.json``), ``exposures.csv`` (one column per
method), ``summary.json`` and ``exposure_times.png`` (exposure versus time of every method).
"""

from __future__ import annotations

import contextlib
import json
import mmap
import multiprocessing as mp
import os
import threading
import time
import traceback
from bisect import bisect_left
from collections import deque
from collections.abc import Callable
from concurrent.futures import Future, ThreadPoolExecutor
from dataclasses import asdict, dataclass, field
from multiprocessing.connection import Connection, wait
from pathlib import Path
from typing import Any

import numpy as np

from bracketry.errors import BracketryError

from ..dataset import BracketSequence, Dataset, open_dataset
from ..emulation import EmulatedImage, Emulator, EmulatorConfig, RunWriter
from ..emulation.selection import SatCount, saturation_fraction
from .base import AEMethod, SharedGray
from .registry import get_method

DEFAULT_INIT_EXPOSURE_US = 4000.0
DEFAULT_MIN_EXPOSURE_US = 20.0
DEFAULT_MAX_EXPOSURE_US = 64000.0
#: ``workers=0`` (auto) forks worker processes only from this many sequences on; shorter runs are faster in one
#: process (forking, per-worker method start-up and result pickling cost more than they save; decoding and PNG
#: encoding use threads in-process anyway).
AUTO_FORK_MIN_SEQUENCES = 8
#: Estimated relative cost of one step per method (emulation + writing ~ 20), for balancing the workers.
_COST = {"fix": 1, "ae30": 1, "ae50": 1, "ae70": 1, "drl": 3, "shim": 10, "wang": 20, "zhang": 10, "kim": 40}


@dataclass
class LoopConfig:
    """Settings of a closed-loop run (see the module docstring)."""

    emulator: EmulatorConfig = field(default_factory=EmulatorConfig)
    camera: str = "both"
    ae_side: str = "left"
    init_exposure_us: float = DEFAULT_INIT_EXPOSURE_US
    min_exposure_us: float = DEFAULT_MIN_EXPOSURE_US
    max_exposure_us: float = DEFAULT_MAX_EXPOSURE_US
    seed: int = 0
    drl_weights: str | None = None
    write_images: bool = True
    stored_png: bool = True
    overwrite: bool = False
    max_sequences: int | None = None
    memory_budget_bytes: int = 1 << 30

    def validate(self) -> None:
        if self.camera not in ("left", "right", "both"):
            raise BracketryError(f"--camera must be left, right or both, got {self.camera}")
        if self.ae_side not in ("left", "right"):
            raise BracketryError(f"the AE side must be left or right, got {self.ae_side}")
        if not 0 < self.min_exposure_us < self.max_exposure_us:
            raise BracketryError(f"bad exposure bounds [{self.min_exposure_us}, {self.max_exposure_us}] us")
        if not self.min_exposure_us <= self.init_exposure_us <= self.max_exposure_us:
            raise BracketryError(f"initial exposure {self.init_exposure_us / 1000:g} ms is outside the bounds "
                                 f"[{self.min_exposure_us / 1000:g}, {self.max_exposure_us / 1000:g}] ms")
        self.emulator.validate()


@dataclass
class StepRecord:
    """One closed-loop step of one method."""

    step: int
    sequence_index: int
    timestamp_ns: int
    exposure_us: float
    next_exposure_us: float
    source_exposure_us: int
    ae_s: float


@dataclass
class MethodRun:
    """The result of one method: its steps and cost."""

    method: str
    steps: list[StepRecord] = field(default_factory=list)

    @property
    def exposures_ms(self) -> list[float]:
        return [s.exposure_us / 1000.0 for s in self.steps]

    def summary(self) -> dict[str, Any]:
        exp = np.array(self.exposures_ms) if self.steps else np.zeros(0)
        cost = np.array([s.ae_s for s in self.steps]) * 1000.0 if self.steps else np.zeros(0)
        return {"method": self.method, "steps": len(self.steps),
                "exposure_ms": {"first": float(exp[0]) if exp.size else None,
                                "last": float(exp[-1]) if exp.size else None,
                                "mean": float(exp.mean()) if exp.size else None,
                                "min": float(exp.min()) if exp.size else None,
                                "max": float(exp.max()) if exp.size else None},
                "ae_ms_per_step": {"median": float(np.median(cost)) if cost.size else None,
                                   "mean": float(cost.mean()) if cost.size else None}}


@dataclass
class RunSummary:
    """All methods of one run."""

    out_dir: Path
    runs: dict[str, MethodRun]
    n_sequences: int
    sides: tuple[str, ...]
    wall_s: float
    plot_path: Path | None = None
    #: the dataset's problems (incomplete sequences, skipped files; one line each), also in summary.json
    problems: list[str] = field(default_factory=list)


class _ImageSink:
    """Encodes the images of a worker's writers on background threads (cv2.imwrite releases the GIL), so PNG
    encoding overlaps emulation and the AE methods. At most ``max_pending`` images are in flight (bounded memory);
    a failed write raises from the next :meth:`submit` or from :meth:`drain`. ``threads`` = 0 writes inline."""

    def __init__(self, threads: int, max_pending: int = 8) -> None:
        self.pool = ThreadPoolExecutor(threads, thread_name_prefix="bracketry-png") if threads > 0 else None
        self.max_pending = max(1, max_pending)
        self.pending: deque[Future[None]] = deque()
        #: (sequence index, side, target us) -> (path, its write) of every image written by this worker
        self.written: dict[tuple[int, str, float], tuple[Path, Future[None] | None]] = {}

    def submit(self, fn: Callable[..., None], *args: Any) -> Future[None] | None:
        if self.pool is None:
            fn(*args)
            return None
        fut = self.pool.submit(fn, *args)
        self.pending.append(fut)
        while len(self.pending) > self.max_pending:
            self.pending.popleft().result()
        return fut

    def drain(self) -> None:
        """Wait for every pending write (raises the first failure)."""
        while self.pending:
            self.pending.popleft().result()

    def close(self) -> None:
        try:
            self.drain()
        finally:
            if self.pool is not None:
                self.pool.shutdown(wait=True, cancel_futures=True)


class _LinkingRunWriter(RunWriter):
    """:class:`RunWriter` (same layout, same decoded pixels) that shares images between the methods of a run:

    - an image identical to one already written by another method of the same worker (same sequence, side and
      target exposure, so the same emulated pixels) becomes a hard link to that file instead of a second encoding
      (falls back to writing when the file system refuses links). Treat run outputs as read-only.
    - images are encoded on the worker's :class:`_ImageSink` threads; :meth:`close` waits for them.
    """

    def __init__(self, out_dir: Path, method: str, sides: tuple[str, ...], depth: int, overwrite: bool,
                 sink: _ImageSink, stored_png: bool, mode: str = "default") -> None:
        super().__init__(out_dir, method, sides, depth=depth, overwrite=overwrite, stored_png=stored_png, mode=mode)
        self._sink = sink

    def write_image(self, path: Path, em: EmulatedImage, key: tuple[int, str, float]) -> None:
        """Hard-link the image when another method already wrote the same (sequence, side, target); else write it."""
        src = self._sink.written.get(key)
        if src is not None and src[0] != path:
            self._sink.submit(self._link, src, path, em, key)
            return
        fut = self._sink.submit(super().write_image, path, em, key)
        self._sink.written[key] = (path, fut)

    def _link(self, src: tuple[Path, Future[None] | None], path: Path, em: EmulatedImage,
              key: tuple[int, str, float]) -> None:
        """Runs on a sink thread: the source write was submitted earlier (FIFO), so it is running or done."""
        if src[1] is not None:
            src[1].result()
        try:
            if path.exists():
                path.unlink()
            os.link(src[0], path)
            return
        except OSError:
            pass
        RunWriter.write_image(self, path, em, key)

    def close(self) -> None:
        try:
            self._sink.drain()
        finally:
            super().close()


class _CachedEmulator(Emulator):
    """:class:`Emulator` whose bracket selection reuses each bracket's saturated fraction (computed once per decoded
    bracket instead of once per emulation: many methods and targets share one sequence). Same rules as
    :meth:`Emulator.select` and :meth:`Emulator.select_stereo`."""

    def __init__(self, config: EmulatorConfig) -> None:
        super().__init__(config)
        self._sat: dict[tuple[int, str], float] = {}

    def clear(self) -> None:
        self._sat.clear()

    def _saturation(self, image: np.ndarray, count: SatCount) -> float:
        key = (id(image), count)
        val = self._sat.get(key)
        if val is None:
            val = saturation_fraction(image, self.response.saturated_code, count)
            self._sat[key] = val
        return val


class _Emulators:
    """The emulator plus per-chunk caches: saturation-driven selection and identical emulations."""

    def __init__(self, config: EmulatorConfig) -> None:
        self.emulator = _CachedEmulator(config)
        self._cache: dict[tuple[int, str, float], EmulatedImage] = {}
        self._gray: dict[tuple[int, str, float], SharedGray] = {}
        self._source: dict[tuple[int, float], int] = {}

    def clear(self) -> None:
        """Forget the chunk (call before the shared buffer is refilled: cache keys use array identity)."""
        self._cache.clear()
        self._source.clear()
        self._gray.clear()
        self.emulator.clear()

    def source(self, seq_index: int, images: dict[str, dict[int, np.ndarray]], target_us: float,
               decide: tuple[str, ...] | None) -> int:
        """The step's ONE source bracket for every camera (:meth:`Emulator.select_stereo`), cached per target."""
        key = (seq_index, float(target_us))
        hit = self._source.get(key)
        if hit is None:
            hit = self._source[key] = self.emulator.select_stereo(images, target_us, decide)
        return hit

    def emulate(self, seq_index: int, side: str, images: dict[int, np.ndarray], target_us: float,
                source_us: int | None = None) -> EmulatedImage:
        key = (seq_index, side, float(target_us))
        hit = self._cache.get(key)
        if hit is None:
            hit = self.emulator.emulate(images, target_us, source_us)
            self._cache[key] = hit
        return hit

    def shared_gray(self, seq_index: int, side: str, target_us: float) -> SharedGray:
        """The gray-conversion memo of an image emulated by :meth:`emulate` (shared by the methods that see it)."""
        key = (seq_index, side, float(target_us))
        shared = self._gray.get(key)
        if shared is None:
            shared = self._gray[key] = SharedGray(self._cache[key].image)
        return shared


def _method_cost(spec: str) -> int:
    return 20 + _COST.get(spec.lower(), 1 if spec.lower().startswith("constant-") else 10)


#: Methods that take the same classical-50 steps at the start (identical images): kept on one worker so the
#: writer links instead of re-encoding.
_AFFINITY = ("fix", "ae50", "drl")


def _partition(specs: list[str], n: int) -> list[list[str]]:
    """Longest-processing-time-first split of the methods over ``n`` workers (order kept within a worker)."""
    units: list[list[str]] = []
    together = [s for s in specs if s.lower() in _AFFINITY]
    if together:
        units.append(together)
    units += [[s] for s in specs if s.lower() not in _AFFINITY]
    loads = [0] * n
    groups: list[list[str]] = [[] for _ in range(n)]
    for unit in sorted(units, key=lambda u: sum(map(_method_cost, u)), reverse=True):
        i = int(np.argmin(loads))
        groups[i].extend(unit)
        loads[i] += sum(map(_method_cost, unit))
    order = {s: k for k, s in enumerate(specs)}
    return [sorted(g, key=order.__getitem__) for g in groups if g]


class _Worker:
    """Runs a group of methods through the sequences; the same object serves in-process and forked modes."""

    def __init__(self, specs: list[str], cfg: LoopConfig, dataset: Dataset, out_dir: Path,
                 emu_sides: tuple[str, ...], write_sides: tuple[str, ...], buffer: Any, shape: tuple[int, int],
                 n_exp: int, write_threads: int = 1,
                 preloaded: dict[tuple[int, int, int], np.ndarray] | None = None) -> None:
        self.cfg = cfg
        self.preloaded = preloaded or {}
        #: set: decode on demand (only the brackets the methods' targets need) on this pool's threads
        self.decode_pool: ThreadPoolExecutor | None = None
        self._decoded: dict[tuple[int, int, int], Future[None]] = {}  # (slot, side, exposure index)
        self.dataset = dataset
        self.sequences = dataset.sequences()
        self.emu_sides, self.write_sides = emu_sides, write_sides
        self.buffer, self.shape, self.n_exp = buffer, shape, n_exp
        self.emu = _Emulators(cfg.emulator)
        self.methods: dict[str, AEMethod] = {}
        self.targets: dict[str, float] = {}
        self.runs: dict[str, MethodRun] = {}
        self.writers: dict[str, RunWriter] = {}
        self.sink = _ImageSink(write_threads if cfg.write_images else 0)
        for spec in specs:
            method = get_method(spec, seed=cfg.seed, drl_weights=cfg.drl_weights, parity=cfg.emulator.parity)
            init = getattr(method, "init_exposure_us", None) or cfg.init_exposure_us
            method.reset(float(init))
            self.methods[spec] = method
            self.targets[spec] = float(init)
            self.runs[spec] = MethodRun(spec)
            self.writers[spec] = _LinkingRunWriter(out_dir, _folder(spec), write_sides, cfg.emulator.depth,
                                                   cfg.overwrite, self.sink, cfg.stored_png, cfg.emulator.parity)

    def _view(self, slot: int, side_i: int, exp_i: int) -> np.ndarray:
        return _buffer_view(self.buffer, self.shape, len(self.emu_sides), self.n_exp, slot, side_i, exp_i)

    def decode(self, tasks: list[tuple[int, int, int, int]]) -> None:
        """Decode frames (slot, seq index, side index, exposure index) into the shared buffer."""
        _decode_into(self.buffer, self.shape, self.sequences, self.emu_sides, self.n_exp, tasks,
                     preloaded=self.preloaded)

    def run(self, seq_indices: list[int], progress: Callable[[int], None]) -> None:
        """Advance every method of this worker through the given sequences (slot = position in the list).

        Without :attr:`decode_pool` the frames must already be decoded (:meth:`decode`); with it, frames are decoded
        on demand, only the brackets that the methods' targets can select: a method's next target is known as soon
        as its step is done, so the next sequence's frames decode while the other methods run."""
        self.emu.clear()
        self._decoded.clear()
        try:
            for slot, seq_i in enumerate(seq_indices):
                seq = self.sequences[seq_i]
                self.emu.clear()  # one sequence at a time: bounded memory; saturation keys use this slot's array ids
                if self.decode_pool is not None:
                    for t in self.targets.values():
                        self._prefetch(slot, seq_i, t)
                    for key in self._needed_keys(seq, list(self.targets.values())):
                        self._decoded[(slot, *key)].result()
                brackets = {side: {e: self._view(slot, si, ei) for ei, e in enumerate(seq.exposures_us)}
                            for si, side in enumerate(self.emu_sides)}
                nxt = seq_indices[slot + 1] if slot + 1 < len(seq_indices) else None
                for spec, method in self.methods.items():
                    self._step(spec, method, seq_i, seq, brackets)
                    if self.decode_pool is not None and nxt is not None:
                        self._prefetch(slot + 1, nxt, self.targets[spec])
                    progress(1)
        finally:
            for f in self._decoded.values():
                f.cancel()
            for f in self._decoded.values():
                if not f.cancelled():
                    f.exception()  # wait: no decode may write into the buffer after this chunk
        self.emu.clear()

    def _needed_keys(self, seq: BracketSequence, targets: list[float]) -> list[tuple[int, int]]:
        """(side index, exposure index) of the frames that emulating ``targets`` from ``seq`` can use."""
        exps = {e for t in targets for e in _needed_brackets(seq.exposures_us, t, self.cfg.emulator.selection)}
        return [(si, ei) for si in range(len(self.emu_sides)) for ei, e in enumerate(seq.exposures_us) if e in exps]

    def _prefetch(self, slot: int, seq_i: int, target_us: float) -> None:
        """Start decoding (on the pool's threads) the frames of ``seq_i`` that ``target_us`` needs, once each."""
        assert self.decode_pool is not None
        tasks = [(slot, seq_i, si, ei) for si, ei in self._needed_keys(self.sequences[seq_i], [target_us])
                 if (slot, si, ei) not in self._decoded]
        futures = _decode_into(self.buffer, self.shape, self.sequences, self.emu_sides, self.n_exp, tasks,
                               self.decode_pool, self.preloaded)
        for (_, _, si, ei), f in zip(tasks, futures, strict=True):
            self._decoded[(slot, si, ei)] = f

    def _step(self, spec: str, method: AEMethod, seq_i: int, seq: BracketSequence,
              brackets: dict[str, dict[int, np.ndarray]]) -> None:
        cfg = self.cfg
        target = self.targets[spec]
        needed = _needed_brackets(seq.exposures_us, target, cfg.emulator.selection)
        subsets = {side: {e: brackets[side][e] for e in needed} for side in self.emu_sides}
        # one source bracket for every camera of the step; --parity upstream: the AE camera decides alone, as the
        # authors' left emulator (their right emulator decides on its own, which the joint decision corrects)
        decide = (cfg.ae_side,) if cfg.emulator.parity == "upstream" else None
        source = self.emu.source(seq_i, subsets, target, decide)
        images = {side: self.emu.emulate(seq_i, side, subsets[side], target, source) for side in self.emu_sides}
        if cfg.write_images:
            self.writers[spec].write_step(seq_i, seq, {s: images[s] for s in self.write_sides}, target)
        ae_img = images[cfg.ae_side]
        ts = seq.timestamps_ns[cfg.ae_side][ae_img.source_exposure_us]
        meta = {"step": seq_i, "timestamp_ns": ts, "side": cfg.ae_side, "sequence_index": seq.index,
                "response": self.emu.emulator.response, "source_exposure_us": ae_img.source_exposure_us,
                "bounds_us": (cfg.min_exposure_us, cfg.max_exposure_us),
                "shared_gray": self.emu.shared_gray(seq_i, cfg.ae_side, target)}
        t0 = time.perf_counter()
        try:
            nxt = float(method.next_exposure_us(ae_img.image, target, meta))
        except BracketryError:
            raise
        except Exception as exc:
            raise BracketryError(f"AE method {spec} failed at step {seq_i}: {type(exc).__name__}: {exc}") from exc
        ae_s = time.perf_counter() - t0
        if not np.isfinite(nxt):
            raise BracketryError(f"AE method {spec} returned a non-finite exposure at step {seq_i}")
        nxt = float(np.clip(nxt, cfg.min_exposure_us, cfg.max_exposure_us))
        self.runs[spec].steps.append(StepRecord(seq_i, seq.index, ts, target, nxt, ae_img.source_exposure_us, ae_s))
        self.targets[spec] = nxt

    def close(self) -> dict[str, MethodRun]:
        try:
            for w in self.writers.values():
                w.close()
        finally:
            self.sink.close()
        return self.runs


def _needed_brackets(exposures_us: tuple[int, ...], target_us: float, selection: str) -> tuple[int, ...]:
    """The brackets that the emulation of ``target_us`` can use: all for fusion; for the single-bracket selections
    the nearest one outside the range, the exact match (highernosat), else the bracketing pair. The selection
    rules give the same source on this subset as on every bracket (see :mod:`..emulation.selection`)."""
    exps = sorted(exposures_us)
    if selection not in ("highernosat", "upstream"):
        return tuple(exps)
    i = bisect_left(exps, target_us)
    if i >= len(exps):
        return (exps[-1],)
    if i == 0:
        return (exps[0],)
    if selection == "highernosat" and (exps[i] == target_us or target_us >= exps[-1]):
        return (exps[i],)
    return exps[i - 1], exps[i]


def _buffer_view(buffer: Any, shape: tuple[int, int], n_sides: int, n_exp: int, slot: int, side_i: int,
                 exp_i: int) -> np.ndarray:
    """uint16 HxW view of one frame's place in the shared decode buffer."""
    h, w = shape
    n = h * w
    off = ((slot * n_sides + side_i) * n_exp + exp_i) * n * 2
    return np.frombuffer(buffer, dtype=np.uint16, count=n, offset=off).reshape(h, w)


def _decode_into(buffer: Any, shape: tuple[int, int], sequences: list[BracketSequence], emu_sides: tuple[str, ...],
                 n_exp: int, tasks: list[tuple[int, int, int, int]], pool: ThreadPoolExecutor | None = None,
                 preloaded: dict[tuple[int, int, int], np.ndarray] | None = None) -> list[Future[None]]:
    """Decode frames (slot, seq index, side index, exposure index) into the shared buffer.

    With ``pool`` the decodes run on its threads (cv2.imread releases the GIL) and the futures are returned (wait
    on them before reading the buffer); else inline. ``preloaded``: {(seq index, side index, exposure index):
    image} already decoded (copied instead of decoded again)."""

    def one(task: tuple[int, int, int, int]) -> None:
        slot, seq_i, side_i, exp_i = task
        seq = sequences[seq_i]
        img = (preloaded or {}).get((seq_i, side_i, exp_i))
        if img is None:
            img = seq.frames[emu_sides[side_i]][seq.exposures_us[exp_i]].load()
        if img.shape != shape:
            raise BracketryError(f"sequence {seq.index}: frame shape {img.shape} differs from {shape}")
        _buffer_view(buffer, shape, len(emu_sides), n_exp, slot, side_i, exp_i)[...] = img

    if pool is None:
        for task in tasks:
            one(task)
        return []
    return [pool.submit(one, task) for task in tasks]


def _folder(spec: str) -> str:
    """Output folder name of a method id (plugin specs 'pkg.mod:Cls' -> 'pkg.mod-Cls')."""
    return spec.replace(":", "-").replace("/", "_")


def _worker_loop(conn: Connection, worker: Callable[[], _Worker]) -> None:
    try:
        w = worker()
        conn.send(("ready", None))
        while True:
            cmd, arg = conn.recv()
            if cmd == "decode":
                w.decode(arg)
                conn.send(("decoded", None))
            elif cmd == "run":
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
        conn.close()


def run_methods(dataset_path: str | Path, methods: list[str], out_dir: str | Path, *, workers: int = 0,
                config: LoopConfig | None = None, progress: bool = True, **overrides: Any) -> RunSummary:
    """Run ``methods`` (ids, see :func:`get_method`) in closed loop on a dataset; see the module docstring.

    ``workers``: processes (0 = min(methods, CPUs, 4); 1 = in-process). ``overrides``: LoopConfig fields.
    Raises BracketryError (one line) on bad input or a failing method; outputs already written stay on disk.
    """
    t_start = time.perf_counter()
    cfg = config or LoopConfig()
    for k, v in overrides.items():
        if not hasattr(cfg, k):
            raise TypeError(f"unknown closed-loop option {k}")
        setattr(cfg, k, v)
    cfg.validate()
    specs = list(dict.fromkeys(methods))
    if not specs:
        raise BracketryError("no AE method given")
    # fail fast in the parent on unknown ids / missing weights
    for spec in specs:
        if spec.strip().lower() == "drl":  # torch is loaded in the workers only (no fork after torch threads)
            from .drl import check_weights_path

            check_weights_path(cfg.drl_weights)
        else:
            get_method(spec, seed=cfg.seed, drl_weights=cfg.drl_weights, parity=cfg.emulator.parity)
    dataset = open_dataset(dataset_path)
    write_sides = dataset.sides if cfg.camera == "both" else (cfg.camera,)
    for s in (*write_sides, cfg.ae_side):
        if s not in dataset.sides:
            raise BracketryError(f"the dataset has no {s} camera (sides: {', '.join(dataset.sides)})")
    emu_sides = tuple(dict.fromkeys([*write_sides, cfg.ae_side]))
    sequences = dataset.sequences()
    if cfg.max_sequences is not None:
        sequences = sequences[: cfg.max_sequences]
    n_seq = len(sequences)
    if n_seq == 0:
        raise BracketryError(f"no complete bracket sequence in {dataset_path}")
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    first = sequences[0]
    shape, first_img = _frame_shape(first, emu_sides[0])
    preloaded = {} if first_img is None else {(0, 0, 0): first_img}  # decoded for the shape: reused
    n_exp = len(first.exposures_us)
    seq_bytes = len(emu_sides) * n_exp * shape[0] * shape[1] * 2
    chunk = max(1, min(n_seq, cfg.memory_budget_bytes // max(seq_bytes, 1)))
    buffer = mmap.mmap(-1, chunk * seq_bytes)
    n_cpu = os.cpu_count() or 1
    if workers > 0:
        n_workers = workers
    else:  # auto: forking (and each worker's start-up) only pays off on long runs
        n_workers = min(len(specs), n_cpu, 4) if n_seq >= AUTO_FORK_MIN_SEQUENCES else 1
    can_fork = "fork" in mp.get_all_start_methods()
    n_workers = max(1, min(n_workers, len(specs))) if can_fork else 1
    groups = _partition(specs, n_workers)

    def make(group: list[str], write_threads: int = 1) -> Callable[[], _Worker]:
        return lambda: _Worker(group, cfg, dataset, out, emu_sides, write_sides, buffer, shape, n_exp,
                               write_threads, preloaded)

    bar = _progress_bar(progress, len(specs) * n_seq)
    runs: dict[str, MethodRun] = {}
    try:
        if len(groups) == 1:
            runs.update(_run_in_process(make(groups[0], min(2, n_cpu)), n_seq, chunk, bar))
        else:
            runs.update(_run_forked(groups, make, n_seq, chunk, len(emu_sides), n_exp, bar))
    finally:
        bar.close()
        # on an error path the traceback still holds numpy views of the buffer: it is freed with them instead
        with contextlib.suppress(BufferError):
            buffer.close()
    ordered = {s: runs[s] for s in specs}
    summary = RunSummary(out, ordered, n_seq, write_sides, time.perf_counter() - t_start,
                         problems=list(dataset.problems))
    _write_outputs(summary, cfg, dataset)
    summary.wall_s = time.perf_counter() - t_start
    return summary


def _run_in_process(make: Callable[[], _Worker], n_seq: int, chunk: int, bar: Any) -> dict[str, MethodRun]:
    """One worker in this process, decoding on demand on threads (cv2.imread releases the GIL); matplotlib is
    imported for the final plot on a thread meanwhile."""
    preload = threading.Thread(target=_preload_plotting, name="bracketry-mpl-import", daemon=True)
    preload.start()
    try:
        with ThreadPoolExecutor(min(2, os.cpu_count() or 1), thread_name_prefix="bracketry-decode") as pool:
            w = make()
            w.decode_pool = pool
            try:
                for c0 in range(0, n_seq, chunk):
                    w.run(list(range(c0, min(n_seq, c0 + chunk))), bar.update)
            except BaseException:
                with contextlib.suppress(Exception):
                    w.sink.close()  # finish the images already submitted; the first error is the one raised
                raise
            return w.close()
    finally:
        preload.join()


def _frame_shape(seq: BracketSequence, side: str) -> tuple[tuple[int, int], np.ndarray | None]:
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


def _decode_tasks(seq_indices: list[int], n_sides: int, n_exp: int) -> list[tuple[int, int, int, int]]:
    return [(slot, seq_i, si, ei) for slot, seq_i in enumerate(seq_indices) for si in range(n_sides)
            for ei in range(n_exp)]


def _run_forked(groups: list[list[str]], make: Callable[[list[str]], Callable[[], _Worker]], n_seq: int,
                chunk: int, n_sides: int, n_exp: int, bar: Any) -> dict[str, MethodRun]:
    ctx = mp.get_context("fork")
    procs: list[Any] = []
    conns: list[Connection] = []
    runs: dict[str, MethodRun] = {}
    try:
        for group in groups:
            parent, child = ctx.Pipe()
            p = ctx.Process(target=_worker_loop, args=(child, make(group)), daemon=True)
            p.start()
            child.close()
            procs.append(p)
            conns.append(parent)
        _preload_plotting()  # the parent is idle while the workers start: import matplotlib now
        _collect(conns, "ready", bar)
        for c0 in range(0, n_seq, chunk):
            idx = list(range(c0, min(n_seq, c0 + chunk)))
            tasks = _decode_tasks(idx, n_sides, n_exp)
            for k, conn in enumerate(conns):
                conn.send(("decode", tasks[k::len(conns)]))
            _collect(conns, "decoded", bar)
            for conn in conns:
                conn.send(("run", idx))
            _collect(conns, "ran", bar)
        for conn in conns:
            conn.send(("close", None))
        for res in _collect(conns, "closed", bar):
            runs.update(res)
    finally:
        for conn in conns:
            conn.close()
        for p in procs:
            p.join(timeout=10)
            if p.is_alive():
                p.terminate()
                p.join(timeout=5)
    return runs


def _preload_plotting() -> None:
    import importlib.util

    if importlib.util.find_spec("matplotlib") is not None:
        import matplotlib.figure  # noqa: F401


def _collect(conns: list[Connection], expected: str, bar: Any) -> list[Any]:
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
                bar.update(payload)
            elif kind == "error":
                if os.environ.get("BRACKETRY_DEBUG") == "1":
                    print(payload[1])
                raise BracketryError(payload[0])
            elif kind == expected:
                results[id(c)] = payload
                del pending[id(c)]
    return [results[id(c)] for c in conns]


class _NoBar:
    def update(self, n: int = 1) -> None:
        pass

    def close(self) -> None:
        pass


def _progress_bar(enabled: bool, total: int) -> Any:
    if not enabled:
        return _NoBar()
    from bracketry.progress import Progress

    return Progress("emulate", total=total, unit="step")


def _write_outputs(summary: RunSummary, cfg: LoopConfig, dataset: Dataset) -> None:
    from .plot import plot_exposures

    out = summary.out_dir
    t0_ns = min((s.timestamp_ns for r in summary.runs.values() for s in r.steps), default=0)
    for spec, run in summary.runs.items():
        folder = out / _folder(spec)
        with open(folder / "ae.csv", "w") as f:
            f.write("step,timestamp_ns,exposure_ms,next_exposure_ms,source_exposure_ms,ae_ms\n")
            for s in run.steps:
                f.write(f"{s.step},{s.timestamp_ns},{s.exposure_us / 1000:.6f},{s.next_exposure_us / 1000:.6f},"
                        f"{s.source_exposure_us / 1000:.6f},{s.ae_s * 1000:.3f}\n")
        (folder / "summary.json").write_text(json.dumps({**run.summary(), "mode": cfg.emulator.parity}, indent=2)
                                             + "\n")
    with open(out / "exposures.csv", "w") as f:
        specs = list(summary.runs)
        f.write("step,timestamp_ns," + ",".join(f"{s}_ms" for s in specs) + "\n")
        first = next(iter(summary.runs.values()))
        for k, st in enumerate(first.steps):
            row = [f"{summary.runs[s].steps[k].exposure_us / 1000:.6f}" for s in specs]
            f.write(f"{st.step},{st.timestamp_ns}," + ",".join(row) + "\n")
    emu = asdict(cfg.emulator)
    emu = {k: (str(v) if isinstance(v, Path) else v) for k, v in emu.items()}  # noise: {read_dn, dn_per_e}
    doc = {"dataset": str(dataset.path), "sequences": summary.n_sequences, "sides": list(summary.sides),
           "ae_side": cfg.ae_side, "mode": cfg.emulator.parity, "init_exposure_ms": cfg.init_exposure_us / 1000.0,
           "bounds_ms": [cfg.min_exposure_us / 1000.0, cfg.max_exposure_us / 1000.0], "seed": cfg.seed,
           "emulator": emu, "wall_s": round(summary.wall_s, 3), "dataset_problems": summary.problems,
           "methods": {s: r.summary() for s, r in summary.runs.items()}}
    (out / "summary.json").write_text(json.dumps(doc, indent=2, default=str) + "\n")
    series = {s: ([(st.timestamp_ns - t0_ns) / 1e9 for st in r.steps], r.exposures_ms)
              for s, r in summary.runs.items()}
    summary.plot_path = plot_exposures(series, out / "exposure_times.png")
