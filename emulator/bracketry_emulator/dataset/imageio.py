"""Read and write 16-bit single-channel PNGs of 12-bit raw Bayer codes.

Every bracket is read by :func:`read_png12`. Gray 8- and 16-bit non-interlaced PNGs (what the cameras' recordings,
the BorealHDR sample and the synthetic worlds hold) are decoded by the ``_pngcodec`` extension (``_pngcodec.c`` next
to this file, linked with libdeflate, built with the package; about 3x faster than OpenCV here, and it writes
straight into the caller's array, e.g. a slot of the shared frame buffer). Any other PNG, and any file that is not
valid in every respect the extension checks (CRCs, zlib checksum, sizes), is read by OpenCV as before, so images and
errors are OpenCV's. Where the extension was not built, or with ``BRACKETRY_NO_CKERNEL=1``, OpenCV reads every file.
"""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path
from typing import Any

import cv2
import numpy as np

from ..extensions import optional_extension
from .model import DatasetError

#: Largest code of a 12-bit image.
MAX_CODE_12BIT = 4095

def png_codec() -> Any:
    """The compiled ``_pngcodec`` extension (``decode``, ``encode_stored``), or None when it was not built (or
    ``BRACKETRY_NO_CKERNEL=1``; :func:`..extensions.optional_extension`)."""
    return optional_extension(f"{__package__}._pngcodec")


def png_decoder() -> Callable[[str, Any], Any] | None:
    """The compiled ``decode(path, out)`` (:func:`png_codec`), or None."""
    codec = png_codec()
    return None if codec is None else codec.decode  # type: ignore[no-any-return]


def read_png(path: Path, out: np.ndarray | None = None) -> np.ndarray | None:
    """A PNG's samples as ``cv2.imread(path, cv2.IMREAD_UNCHANGED)`` returns them (None when it cannot read it).

    ``out``: a C-contiguous array to decode into; used (and returned) when the image has its shape and dtype,
    else left untouched and a new array is returned. Raises OSError when the file cannot be read."""
    return _read_png(path, out)[0]


def _read_png(path: Path, out: np.ndarray | None) -> tuple[np.ndarray | None, int | None]:
    """(:func:`read_png`, the bitwise OR of every sample when the extension decoded it, else None)."""
    fits = _fits(out)
    decode = png_decoder()
    got = decode(str(path), out if fits else None) if decode is not None else None
    if got is not None:
        h, w, depth, or_samples, buf = got
        if buf is out:
            return out, or_samples
        return np.frombuffer(buf, np.uint16 if depth == 16 else np.uint8).reshape(h, w), or_samples
    img = cv2.imread(str(path), cv2.IMREAD_UNCHANGED)
    if img is not None and out is not None and img.shape == out.shape and img.dtype == out.dtype:
        out[...] = img
        return out, None
    return img, None


def read_png12(path: Path, out: np.ndarray | None = None) -> np.ndarray:
    """Read one 16-bit gray PNG holding 12-bit codes -> np.ndarray uint16 HxW.

    ``out``: a uint16 HxW C-contiguous array (e.g. a slot of a frame buffer) to decode into: returned filled when
    the image has its shape; an image of another shape comes back as a new array and ``out`` is left as it was.

    Raises DatasetError (one clear line) when the file is missing, corrupt, not single-channel 16-bit, or holds
    values above 4095 (e.g. codes shifted to the high bits).
    """
    if not path.is_file():
        raise DatasetError(f"missing image file: {path}")
    try:
        img, or_samples = _read_png(path, out)
    except OSError as exc:
        raise DatasetError(f"cannot read {path}: {exc.strerror or exc}") from exc
    return _checked12(img, or_samples, str(path))


def _checked12(img: np.ndarray | None, or_samples: int | None, source: str) -> np.ndarray:
    """``img`` when it is a uint16 HxW image of 12-bit codes, else DatasetError naming ``source``."""
    if img is None:
        raise DatasetError(f"corrupt or unreadable PNG: {source}")
    if img.ndim != 2 or img.dtype != np.uint16:
        raise DatasetError(f"expected a single-channel 16-bit PNG, got {img.dtype} shape {img.shape}: {source}")
    # a sample above 4095 has a bit above the 12th set: the OR of the samples is above 4095 exactly then
    if (or_samples if or_samples is not None else int(img.max(initial=0))) > MAX_CODE_12BIT:
        raise DatasetError(f"values above 4095 (not 12-bit LSB-aligned codes): {source}")
    return img


def read_png12_bytes(data: bytes, source: str, out: np.ndarray | None = None) -> np.ndarray:
    """:func:`read_png12` of a whole PNG file held in memory (e.g. a zip member); ``source`` names it in errors.

    Decoded by the ``_pngcodec`` extension's ``decode_bytes`` where it was built (and the PNG is one it decodes),
    else by OpenCV's ``imdecode``. Returns np.ndarray uint16 HxW (``out`` when it has the image's shape)."""
    codec = png_codec()
    decode = getattr(codec, "decode_bytes", None)  # None: not built, or built from an older _pngcodec.c
    got = decode(data, out if _fits(out) else None) if decode is not None else None
    if got is not None:
        h, w, depth, or_samples, buf = got
        img = out if buf is out else np.frombuffer(buf, np.uint16 if depth == 16 else np.uint8).reshape(h, w)
        return _checked12(img, or_samples, source)
    img = cv2.imdecode(np.frombuffer(data, np.uint8), cv2.IMREAD_UNCHANGED) if data else None
    if img is not None and out is not None and img.shape == out.shape and img.dtype == out.dtype:
        out[...] = img
        img = out
    return _checked12(img, None, source)


def read_png12_member(fd: int, offset: int, size: int, inflated: int, crc32: int, source: str,
                      out: np.ndarray | None = None) -> np.ndarray | None:
    """:func:`read_png12` of a PNG held in a zip member: its ``size`` bytes of data at ``offset`` of the open file
    ``fd``, stored (``inflated`` -1) or deflated (``inflated``: the PNG's size, ``crc32``: its CRC-32), read (and
    inflated, and checked against the CRC) by the ``_pngcodec`` extension's ``decode_member`` without a copy in
    Python. None when the extension cannot (not built; the archive ends early; the data or its CRC is wrong; a PNG
    it does not decode): the caller then reads the member another way (and reports what is wrong)."""
    decode = getattr(png_codec(), "decode_member", None)
    got = decode(fd, offset, size, inflated, crc32, out if _fits(out) else None) if decode is not None else None
    if got is None:
        return None
    h, w, depth, or_samples, buf = got
    img = out if buf is out else np.frombuffer(buf, np.uint16 if depth == 16 else np.uint8).reshape(h, w)
    return _checked12(img, or_samples, source)


def _fits(out: np.ndarray | None) -> bool:
    """True when ``out`` can be decoded into (2-D, uint8/uint16, C-contiguous, writeable)."""
    return out is not None and out.ndim == 2 and out.dtype in (np.uint8, np.uint16) and out.flags.c_contiguous \
        and out.flags.writeable


class PngLoader:
    """Loads one bracket PNG (a :data:`~.model.FrameLoader`): called, :func:`read_png12` of ``path``;
    :meth:`into` decodes it into a given array (:meth:`~.model.Frame.load_into`)."""

    __slots__ = ("path",)

    def __init__(self, path: Path) -> None:
        self.path = path

    def __call__(self) -> np.ndarray:
        return read_png12(self.path)

    def into(self, out: np.ndarray) -> np.ndarray:
        return read_png12(self.path, out)

    def __repr__(self) -> str:
        return f"PngLoader({str(self.path)!r})"


def write_png16(path: Path, image: np.ndarray) -> None:
    """Write a uint16 HxW array as a 16-bit gray PNG (fast compression level 1)."""
    if image.dtype != np.uint16 or image.ndim != 2:
        raise ValueError(f"write_png16 needs uint16 HxW, got {image.dtype} {image.shape}")
    path.parent.mkdir(parents=True, exist_ok=True)
    if not cv2.imwrite(str(path), image, [cv2.IMWRITE_PNG_COMPRESSION, 1]):
        raise DatasetError(f"cannot write PNG: {path}")
