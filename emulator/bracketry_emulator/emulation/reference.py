"""The authors' per-pixel emulation formula, re-implemented from its description for parity tests and benchmarks.

``radiance_emulation``: E = ICRF(I) with scipy interp1d on the lifted pcalib knots, E' = clip(f * E, 0, 4095),
I_out = uint16(CRF(E')) (truncation). Slow by design (two interp1d evaluations per pixel): it is the yardstick.
"""

from __future__ import annotations

import numpy as np


class UpstreamFormula:
    """The authors' ICRF/CRF pair built from 256 pcalib values (knots linspace(0, 4095, 256), 16 x pcalib, ends
    forced to 0 and 4095)."""

    def __init__(self, pcalib: np.ndarray) -> None:
        from scipy.interpolate import interp1d

        x = np.linspace(0, 4095, 256)
        y = 16.0 * np.asarray(pcalib, dtype=np.float64)
        y[0] = 0.0
        y[-1] = 4095.0
        self.icrf = interp1d(x, y, kind="linear", fill_value=(0, 4095))
        self.crf = interp1d(y, x, kind="linear", fill_value=(0, 4095))

    def radiance_emulation(self, image: np.ndarray, target_ms: float, source_ms: float) -> np.ndarray:
        """uint16 HxW emulated codes of ``image`` (uint16 HxW) from ``source_ms`` to ``target_ms``."""
        factor = target_ms / source_ms
        irradiance = np.clip(factor * self.icrf(image), 0, 4095)
        return np.asarray(self.crf(irradiance)).astype(np.uint16)


def upstream_saturation(image: np.ndarray) -> float:
    """The authors' saturation level: fraction of pixels equal to 0 or 4094."""
    return float(np.count_nonzero(image == 0) + np.count_nonzero(image == 4094)) / image.size


def closer_least_sat(brackets_ms: list[float], sat: list[float], target_ms: float) -> float:
    """The authors' selection (brackets ascending, ``sat`` as :func:`upstream_saturation`), returns the bracket."""
    idx: int | None = None
    for i, b in enumerate(brackets_ms):
        if b >= target_ms:
            idx = i
            break
    if idx is None:
        return brackets_ms[-1]
    if idx != 0 and sat[idx] > sat[idx - 1]:
        return brackets_ms[idx - 1]
    return brackets_ms[idx]
