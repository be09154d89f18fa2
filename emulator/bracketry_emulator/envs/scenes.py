"""Constructed scenes: a :class:`~.trajectories.Trajectory` made in memory from a known radiance (tests, examples).

The scene is a seeded texture of blobs and edges moving sideways by ``shift_px`` per sequence; the brackets are
encoded through the emulator's camera response, so the emulator re-exposes them as it does real brackets.
"""

from __future__ import annotations

import cv2
import numpy as np

from ..crf import load_response
from .trajectories import Trajectory


def textured_radiance(height: int, width: int, seed: int = 0) -> np.ndarray:
    """A seeded texture: float64 (height, width) relative radiance in [0.05, 1] (blobs and sharp-edged
    rectangles, rich in ORB corners)."""
    rng = np.random.default_rng(seed)
    base = cv2.GaussianBlur(rng.random((height, width)), (0, 0), 3.0)
    base = (base - base.min()) / max(float(np.ptp(base)), 1e-9)
    for _ in range(max(4, height * width // 600)):
        y, x = int(rng.integers(height)), int(rng.integers(width))
        h, w = int(rng.integers(3, 12)), int(rng.integers(3, 12))
        base[y: y + h, x: x + w] = rng.random()
    return 0.05 + 0.95 * base


def constructed_trajectory(steps: int = 24, height: int = 160, width: int = 256, *, brackets_ms: tuple[float, ...]
                           = (1, 2, 4, 8, 16, 32), good_exposure_us: float = 4000.0, shift_px: int = 2,
                           seed: int = 0, name: str = "constructed") -> Trajectory:
    """A ``steps``-sequence trajectory of a moving texture whose mean code is near half scale at
    ``good_exposure_us`` (us; sRGB response). Returns a Trajectory of uint16 (steps, B, height, width) codes."""
    response = load_response("srgb")
    tex = textured_radiance(height, width + shift_px * steps, seed)
    exps = tuple(round(b * 1000) for b in brackets_ms)
    # radiance (code-linear units per us) so that the texture's mean maps to a linear level of 0.21 (sRGB ~ 0.5)
    linear_max = float(response.icrf[response.saturated_code])
    scale = 0.21 * linear_max / (float(tex.mean()) * good_exposure_us)
    out = np.empty((steps, len(exps), height, width), dtype=np.uint16)
    for n in range(steps):
        view = tex[:, n * shift_px: n * shift_px + width] * scale
        for b, e in enumerate(exps):
            out[n, b] = response.encode(view * e)
    stamps = np.arange(steps, dtype=np.int64) * 50_000_000
    return Trajectory(name, exps, out, stamps, "left")
