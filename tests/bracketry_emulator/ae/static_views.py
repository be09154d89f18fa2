"""Static views of five kinds for the AE direction tests (linear irradiance maps, float64 HxW, DN per us).

Kinds: sunlit snow beside a forest edge, the same with the sun and its glare in view, a frozen lake under a bright
sky, a dusk forest (dark trunks and canopy against the sky), a campus (sunlit and shaded blocks with windows). Every
shape, share and contrast is drawn from ``rng``; :func:`sample_view` is a view of the real sample; :func:`at_ae50`
scales a view so AE50 settles at a chosen exposure.
"""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path

import cv2
import numpy as np
from ae_scenes import RESPONSE, closed_loop, irradiance

from bracketry_emulator.ae import get_method

H, W = 200, 320


def _texture(rng: np.random.Generator, sigma_px: float) -> np.ndarray:
    t = cv2.GaussianBlur(rng.standard_normal((H, W)), (0, 0), sigma_px)
    return t / (t.std() + 1e-12)


def _patchy(rng: np.random.Generator, dynamic_range: float) -> np.ndarray:
    """The AE tests' textured irradiance (blobs, checker, fine texture), mean about 1."""
    return irradiance(H, W, seed=int(rng.integers(1 << 30)), dynamic_range=dynamic_range) / (2047.0 / 8000.0)


def snow(rng: np.random.Generator) -> np.ndarray:
    yy, xx = np.mgrid[0:H, 0:W]
    field = 1.0 + rng.uniform(0.01, 0.05) * (0.6 * _texture(rng, 1.5) + 0.4 * _texture(rng, 6.0))
    edge = W * rng.uniform(0.1, 0.4) + 20.0 * np.sin(yy / rng.uniform(10.0, 40.0))
    forest = _patchy(rng, 8.0) * rng.uniform(0.03, 0.1)
    inside = (xx < edge) if rng.random() < 0.5 else (xx > W - edge)
    return np.where(inside, forest, field)


def glare(rng: np.random.Generator) -> np.ndarray:
    yy, xx = np.mgrid[0:H, 0:W]
    r = np.hypot(yy - rng.uniform(0.0, 0.4 * H), xx - rng.uniform(0.0, W))
    sun = np.where(r < rng.uniform(3.0, 8.0), 3000.0, 0.0)
    return snow(rng) + sun + rng.uniform(2.0, 10.0) / (1.0 + (r / 15.0) ** 2)


def lake(rng: np.random.Generator) -> np.ndarray:
    yy = np.mgrid[0:H, 0:W][0]
    horizon = H * rng.uniform(0.25, 0.5)
    sky = rng.uniform(1.5, 4.0) * (1.0 + 0.2 * (1.0 - yy / horizon))
    ice = 1.0 + rng.uniform(0.005, 0.03) * _texture(rng, 2.0)
    shore = _patchy(rng, 4.0) * rng.uniform(0.05, 0.2)
    return np.where(yy < horizon - rng.uniform(6.0, 20.0), sky, np.where(yy < horizon, shore, ice))


def dusk_forest(rng: np.random.Generator) -> np.ndarray:
    yy, xx = np.mgrid[0:H, 0:W]
    out = np.where(yy > 0.7 * H, 0.05 * (1.0 + 0.3 * _texture(rng, 1.5)), 1.0 + 0.05 * _texture(rng, 8.0))
    for _ in range(int(rng.integers(8, 25))):
        x0, width = rng.uniform(0.0, W), rng.uniform(3.0, 25.0)
        bark = rng.uniform(0.01, 0.06) * (1.0 + 0.4 * _texture(rng, 1.0))
        out = np.where(np.abs(xx - x0) < width / 2, bark, out)
    canopy = (_texture(rng, 5.0) > rng.uniform(0.0, 1.0)) & (yy < 0.5 * H)
    return np.maximum(np.where(canopy, 0.03 * (1.0 + 0.4 * _texture(rng, 1.0)), out), 1e-4)


def campus(rng: np.random.Generator) -> np.ndarray:
    yy, xx = np.mgrid[0:H, 0:W]
    out = np.full((H, W), rng.uniform(2.0, 4.0))  # sky
    x = 0
    while x < W:
        width, top = int(rng.integers(40, 120)), int(rng.integers(20, 100))
        lit = rng.uniform(0.3, 1.0) if rng.random() < 0.5 else rng.uniform(0.02, 0.08)
        block = lit * (1.0 + 0.1 * _texture(rng, 1.0))
        windows = ((xx // 12) % 2 == 0) & ((yy // 16) % 2 == 0)
        block = np.where(windows, block * rng.uniform(0.2, 0.5), block)
        out = np.where((xx >= x) & (xx < x + width) & (yy > top), block, out)
        x += width
    return np.where(yy > 0.8 * H, 0.3 * (1.0 + 0.05 * _texture(rng, 1.0)), out)


KINDS: dict[str, Callable[[np.random.Generator], np.ndarray]] = {
    "snow": snow, "glare": glare, "lake": lake, "dusk_forest": dusk_forest, "campus": campus}


def at_ae50(irr: np.ndarray, target_us: float, rounds: int = 4) -> tuple[np.ndarray, float]:
    """``irr`` scaled so AE50 (12 steps from 4 ms) settles near ``target_us``; returns (scaled map, AE50's last
    exposure in us on it)."""
    irr = irr * (0.18 * 4095.0 / (float(np.median(irr)) * target_us))
    for _ in range(rounds):
        settled_us = closed_loop(get_method("ae50"), irr, 4000.0, 12)[-1]
        irr = irr * settled_us / target_us
    return irr, closed_loop(get_method("ae50"), irr, 4000.0, 12)[-1]


def sample_view(sequence: Path, index: int = 0) -> np.ndarray:
    """A static view of the real sample: its left brackets of sequence ``index`` (1..32 ms) merged to linear
    irradiance (each pixel from the longest bracket where it is neither clipped nor below code 60), area-resized to
    HxW."""
    merged: np.ndarray | None = None
    for ms in (1.0, 2.0, 4.0, 8.0, 16.0, 32.0):
        path = sorted((sequence / "camera_left" / f"{ms}").glob("*.png"))[index]
        codes = cv2.imread(str(path), cv2.IMREAD_UNCHANGED).astype(np.int64)
        rate = RESPONSE.icrf[np.clip(codes, 0, 4095)] / (ms * 1000.0)
        usable = (codes < 4000) & (codes > 60)
        merged = rate if merged is None else np.where(usable, rate, merged)
    assert merged is not None
    return cv2.resize(merged, (W, H), interpolation=cv2.INTER_AREA)
