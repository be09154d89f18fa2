"""Deterministic value-noise fields sampled at world coordinates (consistent across textures and resolutions)."""

from __future__ import annotations

import cv2
import numpy as np


class ValueNoise:
    """Multi-octave value noise on the plane, tiling every ``lattice`` cells of the coarsest octave.

    Each octave is a random lattice (float32, values in [-1, 1]) interpolated with ``cv2.remap`` (bicubic for the
    coarsest octave, bilinear for the finer ones).
    """

    def __init__(self, rng: np.random.Generator, cell_m: float, octaves: int = 4, lattice: int = 256,
                 persistence: float = 0.5) -> None:
        self.cell_m = float(cell_m)
        self.octaves = int(octaves)
        self.persistence = float(persistence)
        self.lattices = [rng.uniform(-1.0, 1.0, (lattice, lattice)).astype(np.float32) for _ in range(octaves)]

    def __call__(self, x_m: np.ndarray, y_m: np.ndarray) -> np.ndarray:
        """Noise at world points (float arrays of equal 2-D shape, metres) -> float32 same shape, roughly [-1, 1]."""
        x = np.asarray(x_m, dtype=np.float32)
        y = np.asarray(y_m, dtype=np.float32)
        out = np.zeros(x.shape, dtype=np.float32)
        amp, total, cell = 1.0, 0.0, self.cell_m
        for lat in self.lattices:
            interp = cv2.INTER_CUBIC if cell == self.cell_m else cv2.INTER_LINEAR
            out += amp * cv2.remap(lat, x / cell, y / cell, interp, borderMode=cv2.BORDER_WRAP)
            total += amp
            amp *= self.persistence
            cell *= 0.5
        return out / np.float32(total)


    def grid(self, x0_m: float, y0_m: float, texel_m: float, n: int) -> np.ndarray:
        """Noise on a regular n x n grid of texel centres starting at world (x0_m, y0_m): float32 (n, n), rows = y.

        Same field as :meth:`__call__` (up to interpolation rounding), computed with ``cv2.warpAffine`` on the
        lattice window that covers the grid, which is much faster than a remap for large grids."""
        out = np.zeros((n, n), dtype=np.float32)
        amp, total, cell = 1.0, 0.0, self.cell_m
        for lat in self.lattices:
            size = lat.shape[0]
            kx = int(np.floor(x0_m / cell)) - 2
            ky = int(np.floor(y0_m / cell)) - 2
            span = int(np.ceil(n * texel_m / cell)) + 5
            window = np.take(np.take(lat, np.arange(ky, ky + span) % size, axis=0), np.arange(kx, kx + span) % size,
                             axis=1)
            scale = texel_m / cell
            M = np.array([[scale, 0.0, (x0_m + 0.5 * texel_m) / cell - kx],
                          [0.0, scale, (y0_m + 0.5 * texel_m) / cell - ky]])
            interp = cv2.INTER_CUBIC if cell == self.cell_m else cv2.INTER_LINEAR
            out += amp * cv2.warpAffine(window, M, (n, n), flags=interp | cv2.WARP_INVERSE_MAP,
                                        borderMode=cv2.BORDER_REPLICATE)
            total += amp
            amp *= self.persistence
            cell *= 0.5
        return out / np.float32(total)


def smoothstep(e0: float, e1: float, x: np.ndarray) -> np.ndarray:
    """Hermite step from 0 (x <= e0) to 1 (x >= e1), float32."""
    t = np.clip((np.asarray(x, dtype=np.float32) - e0) / (e1 - e0), 0.0, 1.0)
    return t * t * (3.0 - 2.0 * t)
