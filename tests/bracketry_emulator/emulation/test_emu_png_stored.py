"""The ``stored`` PNG encoder: the compiled one writes exactly the bytes of the zlib route (and both decode to the
image), for one and many deflate blocks, 8 and 16 bits."""

from __future__ import annotations

import struct
import zlib

import cv2
import numpy as np
import pytest

from bracketry_emulator.dataset import imageio
from bracketry_emulator.emulation.writer import encode_png
from bracketry_emulator.extensions import extensions_disabled


def zlib_stored_png(image: np.ndarray) -> bytes:
    """The PNG as the specification and Python's zlib make it (the encoder before the compiled one)."""
    h, w = image.shape
    n = image.dtype.itemsize
    raw = b"".join(b"\x00" + row.astype(">u2" if n == 2 else np.uint8).tobytes() for row in image)

    def chunk(tag: bytes, data: bytes) -> bytes:
        return struct.pack(">I", len(data)) + tag + data + struct.pack(">I", zlib.crc32(tag + data))

    return (b"\x89PNG\r\n\x1a\n" + chunk(b"IHDR", struct.pack(">IIBBBBB", w, h, 8 * n, 0, 0, 0, 0))
            + chunk(b"IDAT", zlib.compress(raw, 0)) + chunk(b"IEND", b""))


def test_png_stored_codec_is_built() -> None:
    assert imageio.png_codec() is not None, "the _pngcodec extension was not built (setup.sh builds it)"


@pytest.mark.parametrize("dtype,shape", [(np.uint16, (1, 1)), (np.uint16, (37, 53)), (np.uint16, (300, 211)),
                                         (np.uint8, (290, 301)), (np.uint16, (1200, 1920))])
def test_png_stored_bytes_equal_the_zlib_route(dtype: type, shape: tuple[int, int],
                                               monkeypatch: pytest.MonkeyPatch) -> None:
    image = np.random.default_rng(shape[0]).integers(0, np.iinfo(dtype).max + 1, shape, dtype=dtype)
    expected = zlib_stored_png(image)
    assert encode_png(image, "stored") == expected
    assert encode_png(np.asfortranarray(image), "stored") == expected  # any memory layout
    back = cv2.imdecode(np.frombuffer(expected, np.uint8), cv2.IMREAD_UNCHANGED)
    assert np.array_equal(back, image)
    with extensions_disabled():  # as without the extension
        assert imageio.png_codec() is None
        assert encode_png(image, "stored") == expected
