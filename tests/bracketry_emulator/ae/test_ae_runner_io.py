"""AE runner I/O: the stored PNG writer (any reader returns exactly the written codes) and on-demand decoding."""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np
import pytest

from bracketry_emulator.emulation.writer import encode_png_stored, write_png_stored


@pytest.mark.parametrize("dtype,high", [(np.uint16, 4096), (np.uint16, 65536), (np.uint8, 256)])
def test_stored_png_round_trip(tmp_path: Path, dtype: type, high: int) -> None:
    img = np.random.default_rng(3).integers(0, high, (37, 53)).astype(dtype)
    path = tmp_path / "x.png"
    write_png_stored(path, img)
    back = cv2.imread(str(path), cv2.IMREAD_UNCHANGED)
    assert back.dtype == img.dtype and np.array_equal(back, img)


def test_stored_png_rejects_other_arrays() -> None:
    with pytest.raises(ValueError):
        encode_png_stored(np.zeros((4, 4, 3), np.uint8))
    with pytest.raises(ValueError):
        encode_png_stored(np.zeros((4, 4), np.float32))


@pytest.mark.parametrize("selection", ["highernosat", "upstream"])
def test_needed_brackets_select_like_all_brackets(selection: str) -> None:
    """Decoding on demand: the selection on the needed subset equals the selection on every bracket."""
    from bracketry_emulator.ae.emulation_cache import needed_brackets
    from bracketry_emulator.emulation.selection import select_highernosat, select_upstream

    exps = (1000, 2000, 4000, 8000, 16000, 32000)
    rng = np.random.default_rng(5)
    targets = [*exps, 20.0, 500.0, 999.0, 1000.5, 4000.0, 6321.7, 31999.0, 32000.5, 64000.0,
               *rng.uniform(20, 64000, 200)]
    for k in range(40):
        sat = {e: float(v) for e, v in zip(exps, np.sort(rng.uniform(0, 0.05, 6)) if k % 2 else rng.uniform(0, 0.05, 6),
                                           strict=True)}
        for t in targets:
            sub = needed_brackets(exps, float(t), selection)
            assert set(sub) <= set(exps) and 1 <= len(sub) <= 2
            if selection == "highernosat":
                full = select_highernosat(exps, t, sat)
                part = select_highernosat(sub, t, sat) if len(sub) > 1 else sub[0]
            else:
                full = select_upstream(exps, t, sat)
                part = select_upstream(sub, t, sat) if len(sub) > 1 else sub[0]
            assert part == full, (t, sub)
    assert needed_brackets(exps, 5000.0, "fusion") == exps


def test_shared_gray_equals_the_direct_conversions() -> None:
    from bracketry_emulator.ae.base import SharedGray, bayer_gray, gray_for, work_gray, work_gray_for

    img = np.random.default_rng(7).integers(0, 4096, (120, 192)).astype(np.uint16)
    meta = {"shared_gray": SharedGray(img)}
    assert np.array_equal(gray_for(img, meta), bayer_gray(img))
    assert np.array_equal(work_gray_for(img, 48, meta), work_gray(img, 48))
    assert work_gray_for(img, 48, meta) is work_gray_for(img, 48, meta)  # computed once
    assert not gray_for(img, meta).flags.writeable
    other = img.copy()  # a memo of another array is never used
    assert gray_for(other, meta) is not gray_for(img, meta) and gray_for(other, meta).flags.writeable


@pytest.mark.parametrize("compression", ["stored", "fast", "small", "opencv"])
def test_every_png_compression_is_lossless(tmp_path: Path, compression: str) -> None:
    from bracketry_emulator.emulation.writer import write_png

    rng = np.random.default_rng(11)
    img = (rng.normal(1500, 300, (48, 64)).clip(0, 4095)).astype(np.uint16)
    path = tmp_path / f"{compression}.png"
    write_png(path, img, compression)
    back = cv2.imread(str(path), cv2.IMREAD_UNCHANGED)
    assert back.dtype == np.uint16 and np.array_equal(back, img)
    if compression != "stored":
        assert path.stat().st_size < img.nbytes  # compressed


def test_png_compression_is_checked() -> None:
    from bracketry_base.errors import BracketryError
    from bracketry_emulator.ae import LoopConfig

    with pytest.raises(BracketryError, match="--png-compression"):
        LoopConfig(png_compression="zip").validate()
