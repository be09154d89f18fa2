"""The brackets' PNG reader: the compiled decoder equals OpenCV on real frames and on PNGs built with every row
filter; anything else, and every invalid file, goes to OpenCV (same image, same one-line error)."""

from __future__ import annotations

import struct
import zlib
from pathlib import Path

import cv2
import numpy as np
import pytest

from bracketry_emulator.dataset import DatasetError
from bracketry_emulator.dataset.imageio import png_decoder, read_png, read_png12
from bracketry_emulator.extensions import clear_extension_cache

SIGNATURE = b"\x89PNG\r\n\x1a\n"


def _chunk(tag: bytes, data: bytes) -> bytes:
    return struct.pack(">I", len(data)) + tag + data + struct.pack(">I", zlib.crc32(tag + data))


def _paeth(a: np.ndarray, b: np.ndarray, c: np.ndarray) -> np.ndarray:
    p = a + b - c
    pa, pb, pc = np.abs(p - a), np.abs(p - b), np.abs(p - c)
    return np.where((pa <= pb) & (pa <= pc), a, np.where(pb <= pc, b, c))


def filtered_png(image: np.ndarray, filters: list[int], idat_size: int = 5000, level: int = 6) -> bytes:
    """A gray PNG of ``image`` (uint8 or uint16 HxW) whose row y uses filter ``filters[y % len(filters)]`` (0 none,
    1 sub, 2 up, 3 average, 4 paeth, as the PNG specification defines them), its data split into IDAT chunks of
    ``idat_size`` bytes. Our own encoder, written from the specification, so that every filter is exercised."""
    h, w = image.shape
    bpp = image.dtype.itemsize
    raw = np.ascontiguousarray(image.astype(">u2") if bpp == 2 else image).view(np.uint8).reshape(h, w * bpp)
    x = raw.astype(np.int32)
    rows = []
    for y in range(h):
        kind = filters[y % len(filters)]
        cur = x[y]
        up = x[y - 1] if y > 0 else np.zeros_like(cur)
        left = np.concatenate([np.zeros(bpp, np.int32), cur[:-bpp]])
        upleft = np.concatenate([np.zeros(bpp, np.int32), up[:-bpp]])
        pred = {0: 0, 1: left, 2: up, 3: (left + up) // 2, 4: _paeth(left, up, upleft)}[kind]
        rows.append(bytes([kind]) + ((cur - pred) % 256).astype(np.uint8).tobytes())
    data = zlib.compress(b"".join(rows), level)
    ihdr = struct.pack(">IIBBBBB", w, h, 8 * bpp, 0, 0, 0, 0)
    idats = b"".join(_chunk(b"IDAT", data[i:i + idat_size]) for i in range(0, len(data), idat_size))
    text = _chunk(b"tEXt", b"Comment\x00made by the test")
    return SIGNATURE + _chunk(b"IHDR", ihdr) + text + idats + _chunk(b"IEND", b"")


def test_pngcodec_extension_is_built() -> None:
    assert png_decoder() is not None, "the _pngcodec extension was not built (setup.sh builds it; libdeflate-dev)"


@pytest.mark.parametrize("dtype", [np.uint16, np.uint8])
@pytest.mark.parametrize("shape", [(9, 1), (7, 7), (13, 37), (24, 160)])
def test_pngcodec_every_filter_equals_opencv(tmp_path: Path, dtype: type, shape: tuple[int, int]) -> None:
    rng = np.random.default_rng(sum(shape))
    top = np.iinfo(dtype).max
    # smooth + noise, then uniform noise, extremes: every filter's carries and Paeth's ties happen
    yy, xx = np.mgrid[0:shape[0], 0:shape[1]]
    image = ((yy * 977 + xx * 331) % (top + 1)).astype(np.int64) + rng.integers(-3, 4, shape)
    image = np.clip(image, 0, top).astype(dtype)
    image[shape[0] // 2:] = rng.integers(0, top + 1, (shape[0] - shape[0] // 2, shape[1]), dtype=dtype)  # Paeth ties
    image[0, 0], image[-1, -1] = top, 0
    for k, filters in enumerate(([0], [1], [2], [3], [4], [4, 3, 2, 1, 0], [3, 4, 1, 4, 2])):
        path = tmp_path / f"f{k}.png"
        path.write_bytes(filtered_png(image, filters, idat_size=97 if k % 2 else 100_000))
        ref = cv2.imread(str(path), cv2.IMREAD_UNCHANGED)
        assert np.array_equal(ref, image)
        got = png_decoder()(str(path), None)  # type: ignore[misc]
        assert got is not None and got[:3] == (shape[0], shape[1], 8 * np.dtype(dtype).itemsize)
        assert got[3] == int(np.bitwise_or.reduce(image.ravel()))
        assert np.array_equal(read_png(path), ref)
        out = np.full(shape, 7, dtype)
        assert read_png(path, out) is out and np.array_equal(out, ref)


@pytest.mark.realdata
def test_pngcodec_real_frames_equal_opencv_into_a_buffer(borealhdr_sequence: Path) -> None:
    frames = sorted((borealhdr_sequence / "camera_left").rglob("*.png"))[::7][:3]
    frames += sorted((borealhdr_sequence / "camera_right").rglob("*.png"))[::11][:2]
    buffer = np.zeros((2, 1200, 1920), np.uint16)
    for k, png in enumerate(frames):
        ref = cv2.imread(str(png), cv2.IMREAD_UNCHANGED)
        assert png_decoder()(str(png), None) is not None, f"{png}: not decoded by the extension"  # type: ignore[misc]
        slot = buffer[k % 2]
        assert read_png12(png, slot) is slot
        assert np.array_equal(slot, ref)
        assert np.array_equal(read_png12(png), ref)


def test_pngcodec_out_of_another_shape_is_untouched(tmp_path: Path) -> None:
    image = np.arange(12 * 20, dtype=np.uint16).reshape(12, 20)
    path = tmp_path / "a.png"
    path.write_bytes(filtered_png(image, [1]))
    out = np.full((20, 12), 9, np.uint16)
    got = read_png12(path, out)
    assert got is not out and np.array_equal(got, image) and (out == 9).all()
    out8 = np.full((12, 40), 9, np.uint8)  # as many bytes, another sample size
    assert read_png(path, out8) is not out8 and (out8 == 9).all()


def test_pngcodec_other_pngs_are_read_by_opencv(tmp_path: Path) -> None:
    rng = np.random.default_rng(1)
    color = rng.integers(0, 4096, (10, 14, 3), dtype=np.uint16)
    path = tmp_path / "rgb.png"
    assert cv2.imwrite(str(path), color)
    assert png_decoder()(str(path), None) is None  # type: ignore[misc]
    assert np.array_equal(read_png(path), cv2.imread(str(path), cv2.IMREAD_UNCHANGED))
    with pytest.raises(DatasetError, match="expected a single-channel 16-bit PNG"):
        read_png12(path)
    gray8 = tmp_path / "gray8.png"
    gray8.write_bytes(filtered_png(rng.integers(0, 256, (5, 6), dtype=np.uint8), [4]))
    with pytest.raises(DatasetError, match="expected a single-channel 16-bit PNG, got uint8 shape"):
        read_png12(gray8)
    high = tmp_path / "high.png"
    high.write_bytes(filtered_png(np.full((4, 4), 4096, np.uint16), [0]))
    with pytest.raises(DatasetError, match="values above 4095"):
        read_png12(high)


def _corruptions(good: bytes) -> dict[str, bytes]:
    idat = good.index(b"IDAT")
    crc_at = idat + 4 + struct.unpack(">I", good[idat - 4:idat])[0]
    data_at = good.index(b"IDAT") + 4
    flipped = bytearray(good)
    flipped[crc_at] ^= 1
    # a byte of the zlib data changed, its chunk CRC fixed: only the Adler-32 (or the deflate stream) is wrong
    adler = bytearray(good)
    n = struct.unpack(">I", good[idat - 4:idat])[0]
    adler[data_at + n - 1] ^= 0x10
    adler[crc_at:crc_at + 4] = struct.pack(">I", zlib.crc32(bytes(adler[idat:data_at + n])))
    interlaced = bytearray(good)
    interlaced[28] = 1
    interlaced[29:33] = struct.pack(">I", zlib.crc32(bytes(interlaced[12:29])))
    huge = bytearray(good)  # a header claiming 2^31 x 2^31 samples over the same few bytes of data
    huge[16:24] = struct.pack(">II", 0x7FFFFFFF, 0x7FFFFFFF)
    huge[29:33] = struct.pack(">I", zlib.crc32(bytes(huge[12:29])))
    return {"truncated": good[: len(good) * 2 // 3], "huge header": bytes(huge), "no IEND": good[:-12],
            "bad CRC": bytes(flipped), "bad Adler-32": bytes(adler), "interlace flag": bytes(interlaced),
            "not a PNG": b"GIF89a" + good[6:], "signature only": SIGNATURE}


def test_pngcodec_invalid_files_fall_back_and_fail_as_before(tmp_path: Path) -> None:
    image = (np.arange(30 * 40, dtype=np.uint16).reshape(30, 40) * 3) % 4096
    good = filtered_png(image, [1, 2, 3, 4, 0], idat_size=300)
    for name, data in _corruptions(good).items():
        path = tmp_path / f"{name.replace(' ', '_')}.png"
        path.write_bytes(data)
        assert png_decoder()(str(path), None) is None, name  # type: ignore[misc]
        ref = cv2.imread(str(path), cv2.IMREAD_UNCHANGED)
        got = read_png(path)
        assert (got is None and ref is None) or np.array_equal(got, ref), name
        if ref is None:
            with pytest.raises(DatasetError, match=f"corrupt or unreadable PNG: {path}"):
                read_png12(path)
    with pytest.raises(DatasetError, match="missing image file"):
        read_png12(tmp_path / "nope.png")


def test_pngcodec_no_ckernel_reads_with_opencv(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    image = np.arange(6 * 9, dtype=np.uint16).reshape(6, 9)
    path = tmp_path / "a.png"
    path.write_bytes(filtered_png(image, [4]))
    assert png_decoder() is not None  # looked up (and kept) before the variable is set
    monkeypatch.setenv("BRACKETRY_NO_CKERNEL", "1")
    clear_extension_cache()
    try:
        assert png_decoder() is None
        out = np.zeros_like(image)
        assert read_png12(path, out) is out and np.array_equal(out, image)
    finally:
        monkeypatch.delenv("BRACKETRY_NO_CKERNEL")
        clear_extension_cache()
    assert png_decoder() is not None
