"""Synthetic scenes for the AE tests: a textured irradiance map rendered as a 12-bit sRGB-coded RGGB mosaic."""

from __future__ import annotations

import cv2
import numpy as np

from bracketry_emulator.crf import SrgbResponse

RESPONSE = SrgbResponse()


def irradiance(height: int = 240, width: int = 320, seed: int = 0, dynamic_range: float = 8.0) -> np.ndarray:
    """Linear irradiance (DN per us at full response), float64 HxW: smooth blobs, edges and fine texture.

    Scaled so that a mid-grey patch reaches half the linear range at about 8 ms.
    """
    rng = np.random.default_rng(seed)
    base = cv2.GaussianBlur(rng.random((height, width)), (0, 0), 12)
    base = (base - base.min()) / (np.ptp(base) + 1e-12)
    yy, xx = np.mgrid[0:height, 0:width]
    checker = ((xx // 16 + yy // 16) % 2).astype(np.float64)
    fine = cv2.GaussianBlur(rng.random((height, width)), (0, 0), 1.0)
    level = dynamic_range ** (base - 0.5)          # log-uniform brightness over `dynamic_range`
    tex = 0.6 + 0.3 * checker + 0.2 * fine
    return 2047.0 / 8000.0 * level * tex


def render(irr: np.ndarray, exposure_us: float) -> np.ndarray:
    """The mosaic (uint16 HxW codes 0..4094) the camera gives at ``exposure_us`` (same value on every channel)."""
    return RESPONSE.encode(irr * exposure_us)


def closed_loop(method, irr: np.ndarray, init_us: float, steps: int, bounds_us=(20.0, 200_000.0)) -> list[float]:
    """Run ``method`` on the static scene for ``steps`` steps; returns the exposures used (us)."""
    from bracketry_emulator.crf import SrgbResponse

    method.reset(init_us)
    t = init_us
    out = [t]
    meta = {"response": RESPONSE if isinstance(RESPONSE, SrgbResponse) else None, "side": "left"}
    for k in range(steps):
        meta["step"] = k
        t = float(np.clip(method.next_exposure_us(render(irr, t), t, meta), *bounds_us))
        out.append(t)
    return out
