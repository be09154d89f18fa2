"""Stereo frames as a stream of records: how the benchmark hands emulated images to a SLAM child process.

The closed loop writes each step's images as records (one writer per SLAM run) instead of PNG files; the SLAM child
(:mod:`bracketry_emulator.slam.orbslam3_child`) reads them (:func:`read_stream`). The images are the arrays the PNG
route would have encoded (:meth:`~bracketry_emulator.emulation.EmulatedImage.to_depth`: uint16 12-bit RGGB mosaics,
or uint8 at depth 8), named by the same timestamp, so SLAM receives the same pixels. Two writers: :class:`FrameFeed`
into a named pipe the child reads as the loop runs (the set-up check), :class:`FrameSpool` into a file the child
reads once the loop is done (the benchmark: its SLAM runs then share the cores a few at a time, see
:mod:`bracketry_emulator.benchmark.stream`).

Wire format (little-endian), one record per stereo frame::

    b"BRKF" | int64 t_ns | uint32 height | uint32 width | uint32 bytes per pixel (1|2) | uint32 kind (0 frame)
    left pixels (row-major) | right pixels

and a last record of kind 1 whose ``t_ns`` is the number of frames sent (no pixels). A stream that ends without it
(the producer failed) is an error for the reader. A named pipe rather than the child's stdin: the closed loop may
run in forked worker processes, which open the FIFO (or the spool file) by path.
"""

from __future__ import annotations

import contextlib
import errno
import os
import queue
import stat
import struct
import threading
import time
from collections.abc import Iterator
from pathlib import Path
from typing import IO

import numpy as np

from bracketry_base.errors import BracketryError

_HEADER = struct.Struct("<4sqIIII")
_MAGIC = b"BRKF"
_FRAME, _END = 0, 1


class StreamError(BracketryError):
    """The frame stream is malformed or ended before its end record."""


def write_frame(fh: IO[bytes], t_ns: int, left: np.ndarray, right: np.ndarray) -> None:
    """One stereo frame record (``left``/``right``: uint8 or uint16 HxW of the same shape and dtype)."""
    if left.shape != right.shape or left.dtype != right.dtype or left.ndim != 2 or left.dtype not in (np.uint8,
                                                                                                     np.uint16):
        raise ValueError(f"a stereo frame needs two uint8/uint16 HxW images alike, got {left.dtype} {left.shape} "
                         f"and {right.dtype} {right.shape}")
    h, w = left.shape
    fh.write(_HEADER.pack(_MAGIC, int(t_ns), h, w, left.dtype.itemsize, _FRAME))
    fh.write(np.ascontiguousarray(left, dtype=left.dtype.newbyteorder("<")).data)
    fh.write(np.ascontiguousarray(right, dtype=right.dtype.newbyteorder("<")).data)


def write_end(fh: IO[bytes], n_frames: int) -> None:
    """The end record: ``n_frames`` frames were sent."""
    fh.write(_HEADER.pack(_MAGIC, int(n_frames), 0, 0, 0, _END))
    fh.flush()


def _read_exact(fh: IO[bytes], n: int) -> bytearray:
    buf = bytearray(n)
    view = memoryview(buf)
    got = 0
    while got < n:
        k = fh.readinto(view[got:])  # type: ignore[attr-defined]
        if not k:
            raise StreamError(f"the frame stream ended after {got} of {n} bytes of a record (the producer stopped)")
        got += k
    return buf


def iter_records(fh: IO[bytes]) -> Iterator[tuple[int, np.ndarray, np.ndarray]]:
    """(t_ns, left, right) of every frame record until the end record; StreamError on a bad or short stream."""
    n = 0
    while True:
        head = _read_exact(fh, _HEADER.size)
        magic, t_ns, h, w, nbytes, kind = _HEADER.unpack(head)
        if magic != _MAGIC:
            raise StreamError(f"bad frame record {n} (magic {magic!r})")
        if kind == _END:
            if t_ns != n:
                raise StreamError(f"the frame stream announced {t_ns} frames but carried {n}")
            return
        if kind != _FRAME or nbytes not in (1, 2):
            raise StreamError(f"bad frame record {n} (kind {kind}, {nbytes} bytes per pixel)")
        dtype = np.dtype("<u2") if nbytes == 2 else np.dtype(np.uint8)
        size = h * w * nbytes
        data = _read_exact(fh, 2 * size)
        left = np.frombuffer(data, dtype, h * w, 0).reshape(h, w)
        right = np.frombuffer(data, dtype, h * w, size).reshape(h, w)
        yield int(t_ns), left.astype(dtype.newbyteorder("="), copy=False), right.astype(dtype.newbyteorder("="),
                                                                                          copy=False)
        n += 1


def read_stream(path: str | Path, max_buffered_bytes: int = 256 << 20) -> Iterator[tuple[int, np.ndarray, np.ndarray]]:
    """The frames of the FIFO at ``path`` as (t_ns, left, right), read ahead on a thread.

    The reader thread keeps up to ``max_buffered_bytes`` of frames waiting (a paced consumer does not hold up the
    producer until then); beyond, the producer's writes wait. Raises StreamError when the stream is bad or short.
    """
    q: queue.Queue[tuple[int, np.ndarray, np.ndarray] | BaseException | None] = queue.Queue()
    budget = {"bytes": 0}
    cond = threading.Condition()

    def reader() -> None:
        try:
            with open(path, "rb", buffering=1 << 20) as fh:
                for rec in iter_records(fh):
                    size = rec[1].nbytes * 2
                    with cond:
                        while budget["bytes"] > 0 and budget["bytes"] + size > max_buffered_bytes:
                            cond.wait()
                        budget["bytes"] += size
                    q.put(rec)
            q.put(None)
        except BaseException as exc:  # handed to the consumer, which raises it
            q.put(exc)

    thread = threading.Thread(target=reader, name="bracketry-frames", daemon=True)
    thread.start()
    while True:
        item = q.get()
        if item is None:
            return
        if isinstance(item, BaseException):
            raise item
        with cond:
            budget["bytes"] -= item[1].nbytes * 2
            cond.notify_all()
        yield item


def _alive(pid: int | None) -> bool:
    """False once process ``pid`` has exited (also while it is an unreaped zombie); True when unknown."""
    if pid is None:
        return True
    try:
        with open(f"/proc/{pid}/stat") as fh:
            return fh.read().rsplit(") ", 1)[1][:1] != "Z"
    except FileNotFoundError:
        return False
    except (OSError, IndexError):
        try:
            os.kill(pid, 0)
        except ProcessLookupError:
            return False
        except PermissionError:
            pass
        return True


class FrameFeed:
    """The producer's end of one SLAM run's FIFO: :meth:`write_step` for each closed-loop step, then :meth:`close`.

    Opened on the first frame (in whatever process runs the closed loop; the SLAM child opens its end first). When
    the child is gone (crashed, or never opened the FIFO within ``open_timeout_s``; ``reader_pid``: the child, whose
    exit ends that wait at once) the feed stops writing and
    records why in :attr:`failed`; the closed loop and the other runs go on, and the run's own exit status tells
    the story. ``depth``: the emulated images' code depth (12: uint16, 8: uint8), as the PNG writer would store them.
    """

    #: what a failed write means (the start of :attr:`failed`)
    _write_error = "the SLAM process stopped reading"

    def __init__(self, path: str | Path, sides: tuple[str, ...] = ("left", "right"), depth: int = 12,
                 open_timeout_s: float = 120.0, reader_pid: int | None = None) -> None:
        self.path = Path(path)
        self.reader_pid = reader_pid
        self.sides = tuple(sides)
        self.depth = depth
        self.open_timeout_s = open_timeout_s
        self.n_frames = 0
        self.failed: str | None = None
        self._fh: IO[bytes] | None = None

    @staticmethod
    def make_fifo(path: str | Path) -> Path:
        """Create the FIFO at ``path`` (replacing a stale one)."""
        p = Path(path)
        if p.exists() or p.is_symlink():
            if not stat.S_ISFIFO(p.lstat().st_mode):
                raise BracketryError(f"{p} exists and is not a FIFO")
            p.unlink()
        os.mkfifo(p, 0o600)
        return p

    def _open(self) -> IO[bytes] | None:
        deadline = time.monotonic() + self.open_timeout_s
        while True:
            try:  # non-blocking open fails (ENXIO) until the reader has its end open: never hang on a dead child
                fd = os.open(self.path, os.O_WRONLY | os.O_NONBLOCK)
                break
            except OSError as exc:
                if exc.errno != errno.ENXIO or time.monotonic() > deadline or not _alive(self.reader_pid):
                    self.failed = f"cannot open the frame stream {self.path}: {exc.strerror or exc}"
                    return None
                time.sleep(0.05)
        os.set_blocking(fd, True)
        return os.fdopen(fd, "wb", buffering=1 << 20)

    def send(self, t_ns: int, left: np.ndarray, right: np.ndarray) -> None:
        """Send one stereo frame (dropped once the feed failed)."""
        if self.failed is not None:
            return
        if self._fh is None:
            self._fh = self._open()
            if self._fh is None:
                return
        try:
            write_frame(self._fh, t_ns, left, right)
            self.n_frames += 1
        except (BrokenPipeError, ConnectionResetError, OSError) as exc:
            self.failed = f"{self._write_error}: {exc}"
            self._drop()

    def write_step(self, step: int, seq: object, side_images: dict, target_us: float) -> None:
        """The :class:`~bracketry_emulator.emulation.RunWriter` call of one step: the frame goes down the FIFO with
        the name the writer gives it (the timestamp of the first side's source frame) and the pixels it would
        encode."""
        del step, target_us
        em = side_images[self.sides[0]]
        ts = seq.timestamps_ns[self.sides[0]][em.source_exposure_us]  # type: ignore[attr-defined]
        left, right = (side_images[s].to_depth(self.depth) for s in self.sides)
        self.send(int(ts), left, right)

    def close(self) -> None:
        """Send the end record and close (a feed never opened is opened first, so the child sees an empty run)."""
        if self.failed is None and self._fh is None:
            self._fh = self._open()
        if self._fh is not None and self.failed is None:
            try:
                write_end(self._fh, self.n_frames)
            except (BrokenPipeError, ConnectionResetError, OSError) as exc:
                self.failed = f"{self._write_error}: {exc}"
        self._drop()

    def _drop(self) -> None:
        if self._fh is not None:
            with contextlib.suppress(OSError):
                self._fh.close()
            self._fh = None


class FrameSpool(FrameFeed):
    """The writer of one SLAM run's frames into the file ``path`` (created, or replaced), for a child started once the
    closed loop is done: :meth:`write_step` for each step, then :meth:`close` (the end record). A write that fails
    (a full disk) stops the spool and says why in :attr:`failed`; the child then reads a stream without its end
    record and the run fails with that error."""

    _write_error = "cannot write the frame spool"

    def __init__(self, path: str | Path, sides: tuple[str, ...] = ("left", "right"), depth: int = 12) -> None:
        super().__init__(path, sides, depth)

    def _open(self) -> IO[bytes] | None:
        try:
            return open(self.path, "wb", buffering=1 << 20)
        except OSError as exc:
            self.failed = f"cannot write the frame spool {self.path}: {exc.strerror or exc}"
            return None
