"""Pure image functions of the field monitor: previews, histograms and exposure shares of raw camera frames.

Raw frames are ``(height, width)`` uint16 arrays of sensor codes (DN, LSB-aligned; 12-bit sensors: 0..4095), either
an RGGB Bayer mosaic or monochrome. A pixel is *under-exposed* at or below ``low_dn`` and *over-exposed* (saturated)
at or above ``high_dn``; in between it is *well exposed*. No I/O here: arrays in, arrays and numbers out.
"""

from __future__ import annotations

import math

import numpy as np

#: default white level of the rig's 12-bit sensors, DN
WHITE_DN = 4095
#: colours of the preview's exposure marks (RGB): over-exposed blue, under-exposed red (as the paper's figure 1)
OVER_RGB = (40, 90, 255)
UNDER_RGB = (255, 40, 40)


def exposure_limits_dn(white_dn: int = WHITE_DN) -> tuple[float, float]:
    """``(low_dn, high_dn)``: under-exposed at or below 2 % of ``white_dn``, over-exposed at or above 95 %.

    For 12-bit codes: (81.9, 3890.25). The well-exposed window spans log2(95/2) = 5.6 stops.
    """
    return 0.02 * white_dn, 0.95 * white_dn


def luminance(raw: np.ndarray, bayer: bool, step: int = 1) -> np.ndarray:
    """Half-resolution (Bayer) or full-resolution (mono) luminance, float32 DN, every ``step``-th cell.

    Bayer (RGGB): each 2x2 cell gives ``max(R, (G1 + G2) / 2, B)``, so a cell is saturated when any colour is.
    Shape: ``(ceil(h / (2 * step)), ceil(w / (2 * step)))`` for Bayer (``h``, ``w`` even), ``(ceil(h / step),
    ceil(w / step))`` for mono.
    """
    if not bayer:
        return raw[::step, ::step].astype(np.float32)
    r, g1, g2, b = _bayer_planes(raw, step)
    return np.maximum(np.maximum(r, 0.5 * (g1 + g2)), b)


def _bayer_planes(raw: np.ndarray, step: int) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    s = 2 * step
    h, w = raw.shape[0] // 2 * 2, raw.shape[1] // 2 * 2
    r = raw[0:h:s, 0:w:s].astype(np.float32)
    g1 = raw[0:h:s, 1:w:s].astype(np.float32)
    g2 = raw[1:h:s, 0:w:s].astype(np.float32)
    b = raw[1:h:s, 1:w:s].astype(np.float32)
    return r, g1, g2, b


def preview_step(shape: tuple[int, int], bayer: bool, max_width: int) -> int:
    """The subsampling step that makes a preview of ``shape`` (raw height, width) at most ``max_width`` wide."""
    width = shape[1] // 2 if bayer else shape[1]
    return max(1, math.ceil(width / max(1, max_width)))


def preview_rgb(raw: np.ndarray, *, bayer: bool, white_dn: int = WHITE_DN, max_width: int = 240) -> np.ndarray:
    """A small demosaiced preview with over-exposed pixels in blue and under-exposed pixels in red.

    Args:
        raw: ``(h, w)`` uint16 sensor codes (RGGB mosaic when ``bayer``).
        bayer: demosaic by 2x2 cells (one RGB pixel per cell); else grey.
        white_dn: the sensor's white level (DN).
        max_width: preview width limit, pixels (cells are subsampled, not averaged: cost ~ preview size).

    Returns:
        ``(ph, pw, 3)`` uint8 RGB, gamma 1/2.2 on ``white_dn``; pixels whose luminance (see :func:`luminance`) is at
        or above ``high_dn`` are :data:`OVER_RGB`, at or below ``low_dn`` :data:`UNDER_RGB`.
    """
    step = preview_step(raw.shape, bayer, max_width)
    if bayer:
        r, g1, g2, b = _bayer_planes(raw, step)
        rgb = np.stack([r, 0.5 * (g1 + g2), b], axis=-1)
        lum = np.maximum(np.maximum(rgb[..., 0], rgb[..., 1]), rgb[..., 2])
    else:
        lum = raw[::step, ::step].astype(np.float32)
        rgb = np.repeat(lum[..., None], 3, axis=-1)
    out = (255.0 * np.clip(rgb / float(white_dn), 0.0, 1.0) ** (1 / 2.2)).astype(np.uint8)
    low_dn, high_dn = exposure_limits_dn(white_dn)
    out[lum >= high_dn] = OVER_RGB
    out[lum <= low_dn] = UNDER_RGB
    return out


def histogram(lum: np.ndarray, *, white_dn: int = WHITE_DN, bins: int = 64) -> np.ndarray:
    """Counts of ``lum`` (DN) in ``bins`` equal bins over ``0..white_dn`` (values above go to the last bin).

    Returns ``(bins,)`` int64.
    """
    idx = np.clip((lum.ravel() * (bins / (white_dn + 1.0))).astype(np.int64), 0, bins - 1)
    return np.bincount(idx, minlength=bins).astype(np.int64)


def exposure_shares(lum: np.ndarray, *, white_dn: int = WHITE_DN) -> tuple[float, float]:
    """``(over, under)``: the fractions (0..1) of ``lum`` pixels over-exposed and under-exposed."""
    if lum.size == 0:
        return 0.0, 0.0
    low_dn, high_dn = exposure_limits_dn(white_dn)
    return float(np.mean(lum >= high_dn)), float(np.mean(lum <= low_dn))


def disk_time_left_s(samples: list[tuple[float, float]], free_mb: float, floor_mb: float = 0.0) -> float | None:
    """Seconds until ``free_mb`` reaches ``floor_mb`` at the rate of ``samples`` ((t_s, free_mb) oldest first).

    None when the samples span under 2 s or free space does not decrease (nothing is being written).
    """
    if len(samples) < 2 or samples[-1][0] - samples[0][0] < 2.0:
        return None
    rate_mb_s = (samples[0][1] - samples[-1][1]) / (samples[-1][0] - samples[0][0])
    if rate_mb_s <= 0:
        return None
    return max(0.0, (free_mb - floor_mb) / rate_mb_s)
