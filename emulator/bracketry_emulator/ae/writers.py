"""The files of a closed-loop run: emulated images (PNG, hard links between methods), CSV, JSON and the plot.

Layout in ``out_dir``: ``<method>/`` (the emulation output layout of :class:`~..emulation.RunWriter`: images_left|
right/, times_images_*.txt, steps.csv; plus ``ae.csv``: step, timestamp_ns, exposure_ms, next_exposure_ms,
source_exposure_ms, ae_ms, gain_db, saturated_share, dark_share, and ``summary.json``), ``exposures.csv`` (one column
per method), ``summary.json`` and ``exposure_times.png`` (exposure versus time of every method).
"""

from __future__ import annotations

import functools
import json
import os
from collections import deque
from collections.abc import Callable
from concurrent.futures import Future, ThreadPoolExecutor
from pathlib import Path
from typing import Any

from ..emulation import EmulatedImage, RunWriter
from .loop import MethodRun


def method_folder(spec: str) -> str:
    """Output folder name of a method: its name (:func:`~.registry.resolve_methods` checks it is a safe folder
    name, so it is kept as it is; an old run's plugin id 'pkg.mod:Cls' -> 'pkg.mod-Cls')."""
    return spec.replace(":", "-").replace("/", "_")


class ImageSink:
    """Encodes the images of a worker's writers on background threads (cv2.imwrite releases the GIL), so PNG
    encoding overlaps emulation and the AE methods. At most ``max_pending`` images are in flight (bounded memory);
    a failed write raises from the next :meth:`submit` or from :meth:`drain`. ``threads`` = 0 writes inline."""

    def __init__(self, threads: int, max_pending: int = 8, stages: Any = None) -> None:
        #: set: every write is timed there (stage ``png_write``; :mod:`~bracketry_emulator.stages`)
        self.stages = stages
        self.pool = ThreadPoolExecutor(threads, thread_name_prefix="bracketry-png") if threads > 0 else None
        self.max_pending = max(1, max_pending)
        self.pending: deque[Future[None]] = deque()
        #: (sequence index, side, target us, gain dB) -> (path, its write) of every image written by this worker
        self.written: dict[tuple[int, str, float, float], tuple[Path, Future[None] | None]] = {}

    def submit(self, fn: Callable[..., None], *args: Any) -> Future[None] | None:
        if self.stages is not None:
            fn = functools.partial(self._timed, fn)
        if self.pool is None:
            fn(*args)
            return None
        fut = self.pool.submit(fn, *args)
        self.pending.append(fut)
        while len(self.pending) > self.max_pending:
            self.pending.popleft().result()
        return fut

    def _timed(self, fn: Callable[..., None], *args: Any) -> None:
        with self.stages.time("png_write"):
            fn(*args)

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


class LinkingRunWriter(RunWriter):
    """:class:`RunWriter` (same layout, same decoded pixels) that shares images between the methods of a run:

    - an image identical to one already written by another method of the same worker (same sequence, side, target
      exposure and gain, so the same emulated pixels) becomes a hard link to that file instead of a second encoding
      (falls back to writing when the file system refuses links). Treat run outputs as read-only.
    - images are encoded on the worker's :class:`ImageSink` threads; :meth:`close` waits for them.
    """

    def __init__(self, out_dir: Path, method: str, sides: tuple[str, ...], depth: int, overwrite: bool,
                 sink: ImageSink, png_compression: str, mode: str = "default", images: bool = True) -> None:
        super().__init__(out_dir, method, sides, depth=depth, overwrite=overwrite, png_compression=png_compression,
                         mode=mode, images=images)
        self._sink = sink

    def write_image(self, path: Path, em: EmulatedImage, key: tuple[int, str, float, float]) -> None:
        """Hard-link the image when another method already wrote the same (sequence, side, target, gain); else write
        it."""
        src = self._sink.written.get(key)
        if src is not None and src[0] != path:
            self._sink.submit(self._link, src, path, em, key)
            return
        fut = self._sink.submit(super().write_image, path, em, key)
        self._sink.written[key] = (path, fut)

    def _link(self, src: tuple[Path, Future[None] | None], path: Path, em: EmulatedImage,
              key: tuple[int, str, float, float]) -> None:
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


def write_method_files(folder: Path, run: MethodRun, mode: str) -> None:
    """``ae.csv`` (one row per step; exposures in ms, AE cost in ms, the analog gain the image stands for in dB, the
    saturated and dark shares of the step's image: :func:`~.loop.image_shares`) and ``summary.json`` of one
    method."""
    with open(folder / "ae.csv", "w") as f:
        f.write("step,timestamp_ns,exposure_ms,next_exposure_ms,source_exposure_ms,ae_ms,gain_db,saturated_share,"
                "dark_share\n")
        for s in run.steps:
            f.write(f"{s.step},{s.timestamp_ns},{s.exposure_us / 1000:.6f},{s.next_exposure_us / 1000:.6f},"
                    f"{s.source_exposure_us / 1000:.6f},{s.ae_s * 1000:.3f},{s.gain_db:.4f},"
                    f"{s.saturated_share:.6f},{s.dark_share:.6f}\n")
    (folder / "summary.json").write_text(json.dumps({**run.summary(), "mode": mode}, indent=2) + "\n")


def write_exposures_csv(path: Path, runs: dict[str, MethodRun]) -> None:
    """``exposures.csv``: step, timestamp_ns (of the first method's frames) and one ``<method>_ms`` column each."""
    with open(path, "w") as f:
        specs = list(runs)
        f.write("step,timestamp_ns," + ",".join(f"{s}_ms" for s in specs) + "\n")
        first = next(iter(runs.values()))
        for k, st in enumerate(first.steps):
            row = [f"{runs[s].steps[k].exposure_us / 1000:.6f}" for s in specs]
            f.write(f"{st.step},{st.timestamp_ns}," + ",".join(row) + "\n")


def write_run_files(out_dir: Path, runs: dict[str, MethodRun], settings: dict[str, Any], mode: str) -> Path:
    """Every file of a run but the images: each method's files, ``exposures.csv``, ``summary.json`` (``settings``
    followed by each method's summary) and the plot ``exposure_times.png`` (its path is returned)."""
    from .plot import plot_exposures

    for spec, run in runs.items():
        write_method_files(out_dir / method_folder(spec), run, mode)
    write_exposures_csv(out_dir / "exposures.csv", runs)
    doc = {**settings, "methods": {s: r.summary() for s, r in runs.items()}}
    (out_dir / "summary.json").write_text(json.dumps(doc, indent=2, default=str) + "\n")
    t0_ns = min((s.timestamp_ns for r in runs.values() for s in r.steps), default=0)
    series = {s: ([(st.timestamp_ns - t0_ns) / 1e9 for st in r.steps], r.exposures_ms) for s, r in runs.items()}
    return plot_exposures(series, out_dir / "exposure_times.png")
