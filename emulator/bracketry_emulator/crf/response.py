"""Camera response models on 12-bit codes.

A response maps *linear exposure* (irradiance x time, in linear DN-equivalent units 0..``linear_max``) to 12-bit
codes (the CRF ``f``) and back (the inverse CRF ``f^-1``, stored as a 4096-entry table ``icrf``).

Three implementations:
- :class:`TableResponse`: ``icrf`` per code, forward = piecewise-linear inverse of it (calibrated curves, TUM
  ``pcalib.txt`` with the TUM lifting);
- :class:`SrgbResponse`: the sRGB-encoded 12-bit codes of the BorealHDR data (code = floor(4095 * OETF(k / 4095))
  of the integer linear level k), ``icrf`` = mean linear level of each code, forward = round to the linear level
  then the exact camera encoding (so emulated codes stay in the camera's code set);
- :class:`UpstreamResponse`: the authors' lifting of ``pcalib.txt`` (knots linspace(0, 4095, 256), irradiance 16 x
  pcalib, ends forced to 0 and 4095) evaluated with the same arithmetic as ``scipy.interpolate.interp1d``
  (:class:`LinearInterp`), for ``--parity upstream`` bit-exactness.
"""

from __future__ import annotations

from abc import ABC, abstractmethod
from typing import Literal

import numpy as np

#: Number of 12-bit codes.
N_CODES = 4096
#: Saturated code of the BorealHDR data (4095 never occurs).
SATURATED_CODE = 4094

Rounding = Literal["round", "trunc"]


class Response(ABC):
    """A camera response on 12-bit codes.

    Attributes:
        name: short description ("srgb", "pcalib:<file>", "upstream:<file>", ...).
        icrf: np.ndarray float64 (4096,), code -> linear exposure (DN-equivalent, 0..linear_max), non-decreasing.
        linear_max: largest linear exposure the forward curve accepts (inputs are clipped to [0, linear_max]).
        saturated_code: the code a saturated pixel reads (4094 for the BorealHDR camera).
    """

    name: str
    icrf: np.ndarray
    linear_max: float
    saturated_code: int

    @abstractmethod
    def encode_float(self, linear: np.ndarray) -> np.ndarray:
        """Forward CRF without quantization: float64 array of linear exposure -> float64 codes (same shape)."""

    def encode(self, linear: np.ndarray, rounding: Rounding = "round") -> np.ndarray:
        """Forward CRF with quantization: linear exposure (clipped to [0, linear_max]) -> uint16 codes.

        ``round`` rounds to the nearest code and caps at ``saturated_code`` (what the camera can output);
        ``trunc`` truncates (the authors' ``astype(uint16)``) and does not cap.
        """
        x = np.clip(np.asarray(linear, dtype=np.float64), 0.0, self.linear_max)
        codes = self.encode_float(x)
        if rounding == "trunc":
            return codes.astype(np.uint16)
        return np.clip(np.rint(codes), 0, self.saturated_code).astype(np.uint16)

    def lut(self, factor: float, rounding: Rounding = "round") -> np.ndarray:
        """Emulation lookup table for one exposure ratio: uint16 (4096,), code -> f(factor * f^-1(code))."""
        return self.encode(np.clip(factor * self.icrf, 0.0, self.linear_max), rounding)


class TableResponse(Response):
    """Response given by its inverse on every code; the forward curve is the piecewise-linear inverse."""

    def __init__(self, icrf: np.ndarray, name: str = "table", saturated_code: int = SATURATED_CODE) -> None:
        icrf = np.asarray(icrf, dtype=np.float64)
        if icrf.shape != (N_CODES,):
            raise ValueError(f"icrf must have {N_CODES} entries, got {icrf.shape}")
        if np.any(np.diff(icrf) < 0):
            raise ValueError("icrf must be non-decreasing")
        # strictly increasing knots for the forward interpolation (flat runs get a tiny slope)
        eps = 1e-9 * max(float(icrf[-1]), 1.0)
        self._knots = icrf + eps * np.arange(N_CODES)
        self.icrf = icrf
        self.name = name
        self.linear_max = float(icrf[-1])
        self.saturated_code = saturated_code

    def encode_float(self, linear: np.ndarray) -> np.ndarray:
        return np.interp(linear, self._knots, np.arange(N_CODES, dtype=np.float64))


def srgb_oetf(x: np.ndarray) -> np.ndarray:
    """sRGB opto-electronic transfer: linear [0,1] -> encoded [0,1] (float64)."""
    x = np.asarray(x, dtype=np.float64)
    return np.where(x <= 0.0031308, 12.92 * x, 1.055 * np.power(np.maximum(x, 0.0031308), 1 / 2.4) - 0.055)


def srgb_eotf(v: np.ndarray) -> np.ndarray:
    """Inverse of :func:`srgb_oetf`: encoded [0,1] -> linear [0,1] (float64)."""
    v = np.asarray(v, dtype=np.float64)
    return np.where(v <= 0.04045, v / 12.92, np.power((np.maximum(v, 0.04045) + 0.055) / 1.055, 2.4))


class SrgbResponse(Response):
    """The sRGB-encoded 12-bit codes of the BorealHDR camera (BslColorSpace sRgb, gamma 1, black level 0).

    ``code_of_level``: uint16 (4096,), code of each integer linear level k = floor(4095 * OETF(k / 4095)).
    ``icrf[c]``: mean of the levels k encoded as c (unbiased for the coarse dark codes 0, 12, 25, ...); codes that
    the camera never outputs get the continuous inverse.
    """

    def __init__(self) -> None:
        levels = np.arange(N_CODES, dtype=np.float64)
        self.code_of_level = np.floor(4095.0 * srgb_oetf(levels / 4095.0)).astype(np.uint16)
        icrf = 4095.0 * srgb_eotf(levels / 4095.0)
        sums = np.bincount(self.code_of_level, weights=levels, minlength=N_CODES)
        counts = np.bincount(self.code_of_level, minlength=N_CODES)
        used = counts > 0
        icrf[used] = sums[used] / counts[used]
        self.icrf = np.maximum.accumulate(icrf)
        self.used_codes = np.flatnonzero(used)
        self.name = "srgb"
        self.linear_max = 4095.0
        self.saturated_code = int(self.code_of_level.max())

    def encode_float(self, linear: np.ndarray) -> np.ndarray:
        return 4095.0 * srgb_oetf(linear / 4095.0)

    def encode(self, linear: np.ndarray, rounding: Rounding = "round") -> np.ndarray:
        """``round``: nearest integer linear level, then the camera's exact encoding (output in its code set);
        ``trunc``: floor of the continuous encoding (the authors' truncation applied to this curve)."""
        x = np.clip(np.asarray(linear, dtype=np.float64), 0.0, self.linear_max)
        if rounding == "trunc":
            return self.encode_float(x).astype(np.uint16)
        return np.take(self.code_of_level, np.rint(x).astype(np.intp))


class LinearInterp:
    """``scipy.interpolate.interp1d(x, y, kind="linear", fill_value=...)`` as the authors call it, with the same
    values without importing scipy (~0.3 s per process): interp1d sorts the knots by x (stable), evaluates float64
    data with ``np.interp`` and, its ``bounds_error`` being on for a fill value that is not "extrapolate", refuses
    points outside [x_0, x_-1] with a ValueError."""

    def __init__(self, x: np.ndarray, y: np.ndarray) -> None:
        order = np.argsort(x, kind="mergesort")
        self.x = np.asarray(x, dtype=np.float64)[order]
        self.y = np.asarray(y, dtype=np.float64)[order]

    def __call__(self, x_new: np.ndarray | float) -> np.ndarray:
        x = np.asarray(x_new)
        if not np.issubdtype(x.dtype, np.inexact):
            x = x.astype(np.float64)
        if np.any(x < self.x[0]) or np.any(x > self.x[-1]):
            raise ValueError(f"a value in x_new is outside the interpolation range [{self.x[0]}, {self.x[-1]}]")
        return np.interp(x, self.x, self.y)


class UpstreamResponse(Response):
    """The authors' 12-bit lifting of a TUM ``pcalib.txt`` with their interp1d arithmetic (``--parity upstream``).

    Knots x_i = linspace(0, 4095, 256) (codes), y_i = 16 * pcalib_i (irradiance) with y_0 = 0 and y_255 = 4095;
    ICRF = linear interpolation code -> irradiance, CRF = linear interpolation irradiance -> code.
    """

    def __init__(self, pcalib: np.ndarray, name: str = "upstream") -> None:
        pcalib = np.asarray(pcalib, dtype=np.float64)
        if pcalib.shape != (256,):
            raise ValueError(f"the upstream lifting needs 256 pcalib values, got {pcalib.shape}")
        x = np.linspace(0, 4095, 256)
        y = 16.0 * pcalib
        y[0] = 0.0
        y[-1] = 4095.0
        self._icrf_fn = LinearInterp(x, y)
        self._crf_fn = LinearInterp(y, x)
        self.icrf = np.asarray(self._icrf_fn(np.arange(N_CODES, dtype=np.float64)), dtype=np.float64)
        self.name = name
        self.linear_max = 4095.0
        self.saturated_code = SATURATED_CODE

    def encode_float(self, linear: np.ndarray) -> np.ndarray:
        return np.asarray(self._crf_fn(linear), dtype=np.float64)
