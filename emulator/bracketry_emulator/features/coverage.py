"""Keypoint uniformity: fraction of the cells of an n x n image grid holding at least one keypoint (paper: 20x20)."""

from __future__ import annotations

import numpy as np


def grid_coverage(xy_px: np.ndarray, width_px: int, height_px: int, n: int = 20) -> float:
    """Fraction in [0, 1] of the ``n x n`` cells that contain at least one keypoint.

    Args:
        xy_px: float Nx2 keypoint positions (x, y) in pixels of the full-resolution image.
        width_px, height_px: image size in pixels.
        n: cells per side (the paper uses 20).
    """
    if n <= 0 or width_px <= 0 or height_px <= 0:
        raise ValueError("grid size and image size must be positive")
    pts = np.asarray(xy_px, dtype=np.float64).reshape(-1, 2)
    if len(pts) == 0:
        return 0.0
    cx = np.clip((pts[:, 0] * n / width_px).astype(np.int64), 0, n - 1)
    cy = np.clip((pts[:, 1] * n / height_px).astype(np.int64), 0, n - 1)
    return float(len(np.unique(cy * n + cx))) / float(n * n)
