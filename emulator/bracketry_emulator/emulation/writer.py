"""RunWriter: the emulation output layout (as the authors' TFR2024 code writes it, plus steps.csv).

``out_dir/<method>/images_left|images_right/<timestamp_ns>.png`` (12-bit codes in a 16-bit PNG, or 8-bit codes
code >> 4 at depth 8; the name is the timestamp of the source bracket frame), ``times_images_left|right.txt``
(``<name> <timestamp_ns> <target_ms>`` per step) and ``steps.csv`` (step, timestamp_ns, target_exposure_ms,
source_exposure_ms, factor, selection, mode; one row per step; ``mode`` = the AE methods' mode, default or upstream).

One stereo step = one capture: every side's image of a step must come from the same source bracket (the emulator's
:meth:`~.emulator.Emulator.select_stereo`), and all sides carry the same name and timestamp, those of the first
side's source frame (the authors' SLAM entry program pairs left and right by identical file names).

PNG encoding (``png_compression``, every choice a lossless gray PNG that any reader, OpenCV and the authors' tools
included, decodes to exactly the same codes; time and size of each on this project's machine: emulator/DATASET.md):

- ``stored``: deflate without compression (:func:`encode_png`, level 0): the fastest, the largest (2 bytes a pixel;
  the noisy 12-bit raw mosaic compresses poorly anyway). Built in one pass by the compiled ``_pngcodec`` extension
  (the bytes Python's ``zlib.compress(raw, 0)`` makes, blocks, Adler-32 and CRC included), by zlib where it was not
  built;
- ``fast``: deflate with Huffman coding only (zlib level 1, ``Z_HUFFMAN_ONLY``);
- ``small``: deflate with string matching (zlib level 1): the smallest of the four, the slowest;
- ``opencv``: ``cv2.imwrite``'s defaults, as the authors' script writes its images (the default of
  :class:`RunWriter`).
"""

from __future__ import annotations

import csv
import functools
import os
import struct
import zlib
from pathlib import Path
from types import TracebackType
from typing import IO

import cv2
import numpy as np

from bracketry.errors import BracketryError

from ..dataset.imageio import png_codec
from ..dataset.model import BracketSequence
from ..defaults import PNG_COMPRESSIONS
from .emulator import EmulatedImage

STEPS_HEADER = ("step", "timestamp_ns", "target_exposure_ms", "source_exposure_ms", "factor", "selection",
                "mode")
_PNG_SIGNATURE = b"\x89PNG\r\n\x1a\n"


def _png_chunk(tag: bytes, data: bytes) -> bytes:
    return struct.pack(">I", len(data)) + tag + data + struct.pack(">I", zlib.crc32(data, zlib.crc32(tag)))


#: our encoder's choices: (zlib level, zlib strategy)
_DEFLATE = {"stored": (0, zlib.Z_DEFAULT_STRATEGY), "fast": (1, zlib.Z_HUFFMAN_ONLY),
            "small": (1, zlib.Z_DEFAULT_STRATEGY)}


@functools.lru_cache(maxsize=8)
def _stored_blocks(raw_bytes: int) -> bytes:
    """The sizes (native uint16 each) of the stored deflate blocks that ``zlib.compress(raw, 0)`` makes of
    ``raw_bytes`` bytes: the layout depends on zlib (its version) and the length only, never on the bytes, so the
    compiled encoder reproduces zlib's stream exactly (learnt once per length from zeros)."""
    z = zlib.compress(bytes(raw_bytes), 0)
    sizes, pos = [], 2
    while True:
        final, size = z[pos] & 1, int.from_bytes(z[pos + 1:pos + 3], "little")
        if z[pos] & 6:
            raise RuntimeError("zlib level 0 did not write stored blocks")
        sizes.append(size)
        pos += 5 + size
        if final:
            break
    if z[:2] != b"\x78\x01" or pos + 4 != len(z) or sum(sizes) != raw_bytes:
        raise RuntimeError("unexpected zlib stored stream")
    return np.array(sizes, np.uint16).tobytes()


def encode_png(image: np.ndarray, compression: str = "stored") -> bytes:
    """A lossless gray PNG of ``image`` (uint16 HxW -> 16-bit, uint8 HxW -> 8-bit), no row filter, deflated as
    ``compression`` says (``stored``, ``fast`` or ``small``, see the module docstring). Any PNG reader returns
    exactly ``image``. Raises ValueError for another dtype, shape or compression."""
    if image.ndim != 2 or image.dtype not in (np.uint8, np.uint16):
        raise ValueError(f"encode_png needs uint8 or uint16 HxW, got {image.dtype} {image.shape}")
    if compression not in _DEFLATE:
        raise ValueError(f"unknown PNG compression {compression!r} (use {', '.join(_DEFLATE)})")
    level, strategy = _DEFLATE[compression]
    h, w = image.shape
    nbytes = image.dtype.itemsize
    ihdr = struct.pack(">IIBBBBB", w, h, 8 * nbytes, 0, 0, 0, 0)  # gray, deflate, no filter, no interlace
    codec = png_codec()
    if level == 0 and codec is not None:  # the same bytes, built in one pass without the copies
        head = _PNG_SIGNATURE + _png_chunk(b"IHDR", ihdr)
        blocks = _stored_blocks(h * (1 + nbytes * w))
        return codec.encode_stored(np.ascontiguousarray(image), h, w, nbytes, head, blocks)
    raw = np.empty((h, 1 + nbytes * w), np.uint8)
    raw[:, 0] = 0  # filter type None
    raw[:, 1:].view(">u2" if nbytes == 2 else np.uint8)[...] = image  # PNG samples are big-endian
    if level == 0:
        data = zlib.compress(raw.data, 0)
    else:
        z = zlib.compressobj(level, zlib.DEFLATED, 15, 9, strategy)
        data = z.compress(raw.data) + z.flush()
    return b"".join((_PNG_SIGNATURE, _png_chunk(b"IHDR", ihdr), _png_chunk(b"IDAT", data), _png_chunk(b"IEND", b"")))


def encode_png_stored(image: np.ndarray) -> bytes:
    """:func:`encode_png` with ``stored`` (deflate level 0)."""
    return encode_png(image, "stored")


#: bytes per ``write()`` of :func:`write_file`: on this project's machine (ext4, Linux 6.18) one write() of 2 MB or
#: more costs 7-10x the time of the same bytes in pieces of 64 KB-1 MB (4.6 MB: ~10 ms against ~1 ms)
WRITE_PIECE_BYTES = 1 << 18


def write_file(path: Path, data: bytes) -> None:
    """Write ``data`` to a new (or truncated) file at ``path``, in pieces of :data:`WRITE_PIECE_BYTES` (no copies).
    Raises OSError."""
    fd = os.open(path, os.O_WRONLY | os.O_CREAT | os.O_TRUNC | os.O_CLOEXEC, 0o666)
    try:
        view = memoryview(data)
        done = 0
        while done < len(view):
            done += os.write(fd, view[done:done + WRITE_PIECE_BYTES])
    finally:
        os.close(fd)


def write_png(path: Path, image: np.ndarray, compression: str = "stored") -> None:
    """Write ``image`` as a lossless PNG (``compression``: one of :data:`PNG_COMPRESSIONS`). Raises OSError when the
    file cannot be written (BracketryError for OpenCV's encoder, which gives no reason)."""
    if compression == "opencv":
        if not cv2.imwrite(str(path), image):
            raise BracketryError(f"cannot write {path}")
        return
    write_file(path, encode_png(image, compression))


def write_png_stored(path: Path, image: np.ndarray) -> None:
    """Write :func:`encode_png_stored` of ``image`` to ``path``."""
    write_png(path, image, "stored")


class RunWriter:
    """Writes one method's emulated run. Use as a context manager or call :meth:`close`.

    Refuses to write into a method folder that already holds files unless ``overwrite=True`` (then only the files
    of this layout are replaced), so nothing recorded is lost by accident. ``images=False`` records the steps
    (``steps.csv``) without images (no image folders, no times files): e.g. when the images went to SLAM in memory.
    """

    def __init__(self, out_dir: str | Path, method: str, sides: tuple[str, ...] | list[str] = ("left", "right"),
                 depth: int = 12, overwrite: bool = False, png_compression: str = "opencv", mode: str = "default",
                 images: bool = True) -> None:
        if depth not in (8, 12):
            raise BracketryError(f"depth must be 12 or 8, got {depth}")
        if png_compression not in PNG_COMPRESSIONS:
            raise BracketryError(f"unknown PNG compression {png_compression!r} (use {', '.join(PNG_COMPRESSIONS)})")
        if not method or "/" in method or method in (".", ".."):
            raise BracketryError(f"bad method name for a folder: {method!r}")
        self.root = Path(out_dir) / method
        self.sides = tuple(sides)
        self.depth = depth
        self.png_compression = png_compression
        self.mode = mode
        self.images = images
        if self.root.exists() and any(self.root.iterdir()) and not overwrite:
            raise BracketryError(f"output folder already holds a run: {self.root} (choose another --out)")
        self.root.mkdir(parents=True, exist_ok=True)
        self._times: dict[str, IO[str]] = {}
        for side in self.sides if images else ():
            (self.root / f"images_{side}").mkdir(exist_ok=True)
            self._times[side] = open(self.root / f"times_images_{side}.txt", "w")  # noqa: SIM115
        self._steps_file = open(self.root / "steps.csv", "w", newline="")  # noqa: SIM115
        self._steps = csv.writer(self._steps_file)
        self._steps.writerow(STEPS_HEADER)
        self.n_steps = 0

    def image_path(self, side: str, timestamp_ns: int) -> Path:
        """Where the image of ``side`` named by ``timestamp_ns`` goes."""
        return self.root / f"images_{side}" / f"{timestamp_ns}.png"

    def write_image(self, path: Path, em: EmulatedImage, key: tuple[int, str, float]) -> None:
        """Write one emulated image as a lossless PNG (``png_compression``, see the module docstring).

        ``key`` = (sequence index, side, target exposure us) identifies the image's content, for subclasses that
        share identical images between runs (hard links) instead of writing them again. A file already at ``path``
        is replaced, never written through (it may be a hard link of an earlier run)."""
        if path.is_file():
            path.unlink()
        try:
            write_png(path, em.to_depth(self.depth), self.png_compression)
        except OSError as exc:
            raise BracketryError(f"cannot write {path}: {exc.strerror or exc}") from exc

    def write_step(self, step: int, seq: BracketSequence, side_images: dict[str, EmulatedImage],
                   target_us: float) -> None:
        """Write one step: an image per side, a times line per side and one steps.csv row.

        Raises BracketryError when a side is missing or the sides' images come from different source brackets."""
        for side in self.sides:
            if side not in side_images:
                raise BracketryError(f"step {step}: no emulated image for side {side}")
        em = side_images[self.sides[0]]
        sources = {side_images[side].source_exposure_us for side in self.sides}
        if len(sources) != 1:
            raise BracketryError(f"step {step}: the cameras' images come from different source brackets "
                                 f"{sorted(sources)} us (one source bracket per stereo step)")
        ts = seq.timestamps_ns[self.sides[0]][em.source_exposure_us]
        for side in self.sides if self.images else ():
            self.write_image(self.image_path(side, ts), side_images[side], (seq.index, side, float(target_us)))
            self._times[side].write(f"{ts} {ts} {target_us / 1000.0:.6f}\n")
        self._steps.writerow([step, ts, f"{target_us / 1000.0:.6f}", f"{em.source_exposure_us / 1000.0:.6f}",
                              f"{em.factor:.6f}", em.selection, self.mode])
        self.n_steps += 1
        for f in (*self._times.values(), self._steps_file):
            f.flush()

    def close(self) -> None:
        """Close the text files (idempotent)."""
        for f in (*self._times.values(), self._steps_file):
            if not f.closed:
                f.close()

    def __enter__(self) -> RunWriter:
        return self

    def __exit__(self, exc_type: type[BaseException] | None, exc: BaseException | None,
                 tb: TracebackType | None) -> None:
        self.close()
