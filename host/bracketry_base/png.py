"""The lossless PNG writer of both packages: the rig's export and the emulator's writers (one encoder, one set of
choices).

``compression`` (every choice a lossless gray PNG that any reader, OpenCV and the authors' tools included, decodes to
exactly the same codes; time and size of each on this project's machine: emulator/DATASET.md):

- ``stored``: deflate without compression (zlib level 0): the fastest, the largest (2 bytes a pixel; the noisy
  12-bit raw mosaic compresses poorly anyway);
- ``fast``: deflate with Huffman coding only (zlib level 1, ``Z_HUFFMAN_ONLY``);
- ``small``: deflate with string matching (zlib level 1): the smallest of the four, the slowest;
- ``opencv``: ``cv2.imwrite``'s defaults, as the authors' script writes its images.

Here everything is numpy and zlib (OpenCV for ``opencv`` only), so the rig needs nothing of the emulator. The
emulator builds ``stored`` PNGs in one pass with its compiled ``_pngcodec`` (the same bytes:
``bracketry_emulator.emulation.writer.encode_png``), from :func:`png_head` and :func:`stored_blocks`. numpy is
imported where it is used, so the CLIs read :data:`PNG_COMPRESSIONS` while declaring their options without it.
"""

from __future__ import annotations

import functools
import os
import struct
import zlib
from pathlib import Path
from typing import TYPE_CHECKING

from bracketry_base.errors import BracketryError

if TYPE_CHECKING:
    import numpy as np

#: lossless PNG encodings of written images; the default of the emulator's closed loop first
PNG_COMPRESSIONS: tuple[str, ...] = ("stored", "fast", "small", "opencv")

_PNG_SIGNATURE = b"\x89PNG\r\n\x1a\n"

#: our encoder's choices: (zlib level, zlib strategy)
_DEFLATE = {"stored": (0, zlib.Z_DEFAULT_STRATEGY), "fast": (1, zlib.Z_HUFFMAN_ONLY),
            "small": (1, zlib.Z_DEFAULT_STRATEGY)}


def _png_chunk(tag: bytes, data: bytes) -> bytes:
    return struct.pack(">I", len(data)) + tag + data + struct.pack(">I", zlib.crc32(data, zlib.crc32(tag)))


@functools.lru_cache(maxsize=8)
def stored_blocks(raw_bytes: int) -> bytes:
    """The sizes (native uint16 each) of the stored deflate blocks that ``zlib.compress(raw, 0)`` makes of
    ``raw_bytes`` bytes: the layout depends on zlib (its version) and the length only, never on the bytes, so a
    compiled encoder reproduces zlib's stream exactly (learnt once per length from zeros)."""
    import numpy as np

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


def check_image(image: np.ndarray, compression: str) -> None:
    """Raise ValueError unless ``image`` is uint8 or uint16 HxW and ``compression`` one this module deflates."""
    import numpy as np

    if image.ndim != 2 or image.dtype not in (np.uint8, np.uint16):
        raise ValueError(f"encode_png needs uint8 or uint16 HxW, got {image.dtype} {image.shape}")
    if compression not in _DEFLATE:
        raise ValueError(f"unknown PNG compression {compression!r} (use {', '.join(_DEFLATE)})")


def png_head(image: np.ndarray) -> bytes:
    """The PNG signature and IHDR chunk of ``image`` (gray, 8 or 16 bits as its dtype, no filter, no interlace)."""
    h, w = image.shape
    ihdr = struct.pack(">IIBBBBB", w, h, 8 * image.dtype.itemsize, 0, 0, 0, 0)
    return _PNG_SIGNATURE + _png_chunk(b"IHDR", ihdr)


def encode_png(image: np.ndarray, compression: str = "stored") -> bytes:
    """A lossless gray PNG of ``image`` (uint16 HxW -> 16-bit, uint8 HxW -> 8-bit), no row filter, deflated as
    ``compression`` says (``stored``, ``fast`` or ``small``, see the module docstring). Any PNG reader returns
    exactly ``image``. Raises ValueError for another dtype, shape or compression."""
    import numpy as np

    check_image(image, compression)
    level, strategy = _DEFLATE[compression]
    h, w = image.shape
    nbytes = image.dtype.itemsize
    raw = np.empty((h, 1 + nbytes * w), np.uint8)
    raw[:, 0] = 0  # filter type None
    raw[:, 1:].view(">u2" if nbytes == 2 else np.uint8)[...] = image  # PNG samples are big-endian
    if level == 0:
        data = zlib.compress(raw.data, 0)
    else:
        z = zlib.compressobj(level, zlib.DEFLATED, 15, 9, strategy)
        data = z.compress(raw.data) + z.flush()
    return b"".join((png_head(image), _png_chunk(b"IDAT", data), _png_chunk(b"IEND", b"")))


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
        import cv2  # the host and emulator extras both install OpenCV

        if not cv2.imwrite(str(path), image):
            raise BracketryError(f"cannot write {path}")
        return
    write_file(path, encode_png(image, compression))
