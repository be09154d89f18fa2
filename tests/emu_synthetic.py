"""Small synthetic bracket stacks rendered in the tests from a known radiance map (no dependency on bracketry synth).

Camera model: linear level = irradiance (DN/us) x exposure (us) + Gaussian shot/read noise, rounded, clipped to
[0, 4095], then the sRGB 12-bit encoding of the BorealHDR camera (code = floor(4095 * OETF(k / 4095))).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from bracketry_emulator.crf import SrgbResponse
from bracketry_emulator.dataset import write_png16

BRACKETS_US = (1000, 2000, 4000, 8000, 16000, 32000)
SRGB = SrgbResponse()


def radiance_map(h: int = 64, w: int = 96, seed: int = 0) -> np.ndarray:
    """float64 HxW irradiance in linear DN per us spanning ~0.002 .. 8 (dark shade to bright snow)."""
    rng = np.random.default_rng(seed)
    y, x = np.mgrid[0:h, 0:w]
    base = np.exp(np.interp(x, [0, w - 1], [np.log(0.002), np.log(8.0)]))
    texture = 1.0 + 0.3 * np.sin(y / 3.0) * np.cos(x / 5.0) + 0.1 * rng.standard_normal((h, w))
    return np.clip(base * texture, 1e-4, None)


def render(irr: np.ndarray, exposure_us: float, rng: np.random.Generator | None = None, read_dn: float = 1.0,
           dn_per_e: float = 0.4) -> np.ndarray:
    """uint16 HxW sRGB-encoded codes of ``irr`` (DN/us) at ``exposure_us``; noise-free when ``rng`` is None."""
    lin = irr * exposure_us
    if rng is not None:
        lin = lin + rng.standard_normal(lin.shape) * np.sqrt(read_dn ** 2 + dn_per_e * lin)
    levels = np.clip(np.rint(lin), 0, 4095).astype(np.intp)
    return SRGB.code_of_level[levels]


def write_tree(root: Path, irr: np.ndarray, n_sequences: int = 2, sides: tuple[str, ...] = ("left", "right"),
               period_ns: int = 45_000_000, seed: int = 0, start_ns: int = 1_700_000_000_000_000_000) -> Path:
    """A BorealHDR tree of ``n_sequences`` complete cycles of a static scene; returns ``root``."""
    rng = np.random.default_rng(seed)
    t = start_ns
    for _ in range(n_sequences):
        for e in BRACKETS_US:
            for side in sides:
                write_png16(root / f"camera_{side}" / f"{e / 1000:.1f}" / f"{t}.png", render(irr, e, rng))
            t += period_ns
    return root
