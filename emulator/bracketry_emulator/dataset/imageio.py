"""Read and write 16-bit single-channel PNGs of 12-bit raw Bayer codes."""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np

from .model import DatasetError

#: Largest code of a 12-bit image.
MAX_CODE_12BIT = 4095


def read_png12(path: Path) -> np.ndarray:
    """Read one 16-bit gray PNG holding 12-bit codes -> np.ndarray uint16 HxW.

    Raises DatasetError (one clear line) when the file is missing, corrupt, not single-channel 16-bit, or holds
    values above 4095 (e.g. codes shifted to the high bits).
    """
    if not path.is_file():
        raise DatasetError(f"missing image file: {path}")
    img = cv2.imread(str(path), cv2.IMREAD_UNCHANGED)
    if img is None:
        raise DatasetError(f"corrupt or unreadable PNG: {path}")
    if img.ndim != 2 or img.dtype != np.uint16:
        raise DatasetError(f"expected a single-channel 16-bit PNG, got {img.dtype} shape {img.shape}: {path}")
    if int(img.max(initial=0)) > MAX_CODE_12BIT:
        raise DatasetError(f"values above 4095 (not 12-bit LSB-aligned codes): {path}")
    return img


def write_png16(path: Path, image: np.ndarray) -> None:
    """Write a uint16 HxW array as a 16-bit gray PNG (fast compression level 1)."""
    if image.dtype != np.uint16 or image.ndim != 2:
        raise ValueError(f"write_png16 needs uint16 HxW, got {image.dtype} {image.shape}")
    path.parent.mkdir(parents=True, exist_ok=True)
    if not cv2.imwrite(str(path), image, [cv2.IMWRITE_PNG_COMPRESSION, 1]):
        raise DatasetError(f"cannot write PNG: {path}")
