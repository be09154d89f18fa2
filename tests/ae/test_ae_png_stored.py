"""The stored PNG writer of AE runs: any reader returns exactly the written codes (16-bit and 8-bit)."""

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
