"""RunWriter: the emulation output layout (as the authors' TFR2024 code writes it, plus steps.csv).

``out_dir/<method>/images_left|images_right/<timestamp_ns>.png`` (12-bit codes in a 16-bit PNG, or 8-bit codes
code >> 4 at depth 8; the name is the timestamp of the source bracket frame), ``times_images_left|right.txt``
(``<name> <timestamp_ns> <target_ms>`` per step) and ``steps.csv`` (step, timestamp_ns, target_exposure_ms,
source_exposure_ms, factor, selection, mode, exposure_ms, gain_db; one row per step; ``mode`` = the AE methods' mode,
default or upstream; ``exposure_ms`` and ``gain_db`` = the camera exposure and analog gain the image stands for: the
target and 0 dB, or beyond the longest bracket that bracket's exposure and the rest as gain).

One stereo step = one capture: every side's image of a step must come from the same source bracket (the emulator's
:meth:`~.emulator.Emulator.select_stereo`), and all sides carry the same name and timestamp, those of the first
side's source frame (the authors' SLAM entry program pairs left and right by identical file names).

PNG encoding (``png_compression``): one of :data:`bracketry_base.png.PNG_COMPRESSIONS`, the PNG writer both packages
share (its docstring gives the choices); ``opencv`` is the default of :class:`RunWriter`, as the authors' script
writes its images. ``stored`` is built in one pass by the compiled ``_pngcodec`` extension where it was built (the
bytes Python's ``zlib.compress(raw, 0)`` makes, blocks, Adler-32 and CRC included), by zlib elsewhere.
"""

from __future__ import annotations

import csv
from pathlib import Path
from types import TracebackType
from typing import IO

import numpy as np

from bracketry_base import png
from bracketry_base.errors import BracketryError
from bracketry_base.png import PNG_COMPRESSIONS, write_file
from bracketry_base.png import WRITE_PIECE_BYTES as WRITE_PIECE_BYTES

from ..dataset.imageio import png_codec
from ..dataset.model import BracketSequence
from .emulator import EmulatedImage

STEPS_HEADER = ("step", "timestamp_ns", "target_exposure_ms", "source_exposure_ms", "factor", "selection",
                "mode", "exposure_ms", "gain_db")


def encode_png(image: np.ndarray, compression: str = "stored") -> bytes:
    """:func:`bracketry_base.png.encode_png`; ``stored`` built in one pass by the compiled ``_pngcodec`` extension
    where it was built (the same bytes, without the copies). Raises ValueError for another dtype, shape or
    compression."""
    codec = png_codec()
    if compression == "stored" and codec is not None:
        png.check_image(image, compression)
        h, w = image.shape
        nbytes = image.dtype.itemsize
        return codec.encode_stored(np.ascontiguousarray(image), h, w, nbytes, png.png_head(image),  # type: ignore[no-any-return]
                                   png.stored_blocks(h * (1 + nbytes * w)))
    return png.encode_png(image, compression)


def encode_png_stored(image: np.ndarray) -> bytes:
    """:func:`encode_png` with ``stored`` (deflate level 0)."""
    return encode_png(image, "stored")


def write_png(path: Path, image: np.ndarray, compression: str = "stored") -> None:
    """:func:`bracketry_base.png.write_png`, ``stored`` through the compiled encoder (:func:`encode_png`). Raises
    OSError when the file cannot be written (BracketryError for OpenCV's encoder, which gives no reason)."""
    if compression == "stored":
        write_file(path, encode_png(image, compression))
    else:
        png.write_png(path, image, compression)


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

    def write_image(self, path: Path, em: EmulatedImage, key: tuple[int, str, float, float]) -> None:
        """Write one emulated image as a lossless PNG (``png_compression``, see the module docstring).

        ``key`` = (sequence index, side, target exposure us, gain dB) identifies the image's content, for subclasses
        that share identical images between runs (hard links) instead of writing them again. A file already at
        ``path`` is replaced, never written through (it may be a hard link of an earlier run)."""
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
            self.write_image(self.image_path(side, ts), side_images[side],
                             (seq.index, side, float(target_us), float(side_images[side].gain_db)))
            self._times[side].write(f"{ts} {ts} {target_us / 1000.0:.6f}\n")
        self._steps.writerow([step, ts, f"{target_us / 1000.0:.6f}", f"{em.source_exposure_us / 1000.0:.6f}",
                              f"{em.factor:.6f}", em.selection, self.mode, f"{em.camera_exposure_us / 1000.0:.6f}",
                              f"{em.gain_db:.4f}"])
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
