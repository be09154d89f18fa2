"""CRF helpers shared by the CRF-based methods (Zhang, Wang): the slope of the log inverse response, synthesis."""

from __future__ import annotations

import functools

import numpy as np

from ..crf import Response, load_response


@functools.lru_cache(maxsize=8)
def _slope_cached(response: Response, half_window: int) -> np.ndarray:
    icrf = np.maximum(np.asarray(response.icrf, dtype=np.float64), 1.0)
    g = np.log(icrf)
    codes = np.arange(len(g))
    lo = np.clip(codes - half_window, 0, len(g) - 1)
    hi = np.clip(codes + half_window, 0, len(g) - 1)
    slope = (g[hi] - g[lo]) / np.maximum(hi - lo, 1)
    return np.maximum(slope, 1e-6)


def log_icrf_slope(response: Response, half_window: int = 16) -> np.ndarray:
    """g'(I) = d ln f^-1(I) / dI per 12-bit code: float64 (4096,), central difference over +-``half_window`` codes
    (smooths the sRGB code set's coarse dark steps), floored at 1e-6. f^-1 is floored at 1 linear DN."""
    return _slope_cached(response, half_window)


def response_of(meta: dict) -> Response:
    """The camera response from the runner's meta, or the sRGB default (stand-alone use)."""
    resp = meta.get("response")
    if resp is None:
        resp = _default_response()
    return resp


@functools.lru_cache(maxsize=1)
def _default_response() -> Response:
    return load_response("srgb")


def synthesise(gray12: np.ndarray, factor: float, response: Response) -> np.ndarray:
    """Gray image (float, 12-bit code units, HxW) re-exposed by ``factor`` through the CRF -> float32 codes."""
    codes = np.clip(np.rint(gray12), 0, len(response.icrf) - 1).astype(np.intp)
    lut = response.lut(factor).astype(np.float32)
    return lut[codes]
