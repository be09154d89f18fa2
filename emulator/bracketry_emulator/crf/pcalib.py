"""TUM ``pcalib.txt`` files: load, save, and turn into a 12-bit response.

Format (TUM mono dataset / DSO): one text line of 256 floats, the inverse response G^-1 of each 8-bit value. We
also accept and write a 12-bit variant with 4096 values (G^-1 of every 12-bit code), which is what
``bracketry calibrate-crf`` produces by default.
"""

from __future__ import annotations

from pathlib import Path
from typing import Literal

import numpy as np

from bracketry_base.errors import BracketryError

from .response import N_CODES, Response, TableResponse, UpstreamResponse

Lifting = Literal["tum", "upstream"]


def load_pcalib(path: str | Path) -> np.ndarray:
    """Read a pcalib file -> float64 (256,) or (4096,) inverse-response values (non-decreasing).

    Raises BracketryError for a missing file, unparsable numbers, a wrong count, a decreasing curve, a negative
    start or a flat curve.
    """
    p = Path(path)
    if not p.is_file():
        raise BracketryError(f"pcalib file not found: {p}")
    try:
        values = np.array(p.read_text().split(), dtype=np.float64)
    except ValueError as exc:
        raise BracketryError(f"pcalib file holds non-numbers: {p}") from exc
    if values.size not in (256, N_CODES):
        raise BracketryError(f"pcalib file must hold 256 (TUM) or 4096 values, found {values.size}: {p}")
    if not np.all(np.isfinite(values)) or np.any(np.diff(values) < 0):
        raise BracketryError(f"pcalib curve must be finite and non-decreasing: {p}")
    if values[0] < 0 or values[-1] <= values[0]:
        raise BracketryError(f"pcalib curve must start at a value >= 0 and rise (first {values[0]:g}, last "
                             f"{values[-1]:g}): {p}")
    return values


def save_pcalib(path: str | Path, values: np.ndarray) -> None:
    """Write inverse-response values (256 or 4096 floats) as one text line."""
    v = np.asarray(values, dtype=np.float64).ravel()
    if v.size not in (256, N_CODES):
        raise ValueError(f"pcalib needs 256 or 4096 values, got {v.size}")
    Path(path).write_text(" ".join(f"{x:.9g}" for x in v) + "\n")


def response_from_pcalib(values: np.ndarray, lifting: Lifting = "tum", name: str = "pcalib") -> Response:
    """Build a 12-bit response from pcalib values.

    ``tum`` (default): 256 values are rescaled to [0, 4095] (TUM rescales G to [0, 255]) and interpolated linearly
    at the 12-bit codes placed on linspace(0, 4095, 256); 4096 values are used per code (rescaled the same way).
    ``upstream``: the authors' lifting, bit-exact with their emulator (256 values only).
    """
    v = np.asarray(values, dtype=np.float64)
    if lifting == "upstream":
        if v.size != 256:
            raise BracketryError("the upstream pcalib lifting needs a 256-value (TUM) file")
        return UpstreamResponse(v, name=f"upstream:{name}")
    span = float(v[-1] - v[0])
    if span <= 0:
        raise BracketryError("pcalib curve is flat")
    g = (v - v[0]) / span * 4095.0
    if v.size == 256:
        g = np.interp(np.arange(N_CODES, dtype=np.float64), np.linspace(0, 4095, 256), g)
    return TableResponse(g, name=f"pcalib:{name}")


def pcalib256_from_icrf(icrf: np.ndarray) -> np.ndarray:
    """Sample a 4096-entry inverse response at the 256 TUM knots (codes linspace(0, 4095, 256)), in [0, 255]."""
    icrf = np.asarray(icrf, dtype=np.float64)
    g = np.interp(np.linspace(0, 4095, 256), np.arange(N_CODES), icrf)
    return (g - g[0]) / max(float(g[-1] - g[0]), 1e-12) * 255.0
