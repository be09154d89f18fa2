"""Camera-response calibration from a static exposure stack: TUM-style alternating least squares at 4096 levels.

Model (Engel, Usenko, Cremers 2016): I_ix = f(t_i * E_x), unknowns G = f^-1 on every 12-bit code and E_x per pixel.
Alternate (``iterations`` times) on the pixels that are not saturated (code >= ``saturated_code`` is masked, with a
``leak_padding`` dilation as TUM does):

    E step:  E_x = sum_i t_i G[I_ix] / sum_i t_i^2
    G step:  G[c] = mean over (i, x) with I_ix = c of t_i E_x

Codes never observed are interpolated; G is made non-decreasing and scaled to [0, 4095] (scale is free: emulation
uses ratios only). Images of a Bayer mosaic are used as is (one response for all channels, as the camera applies).

Vignetting is not calibrated: emulation re-exposes each pixel from the same pixel of a
bracket, so a per-pixel attenuation V_x cancels (f(t' V_x E_x) from f(t V_x E_x) needs only f and t'/t), and a
static stack of a textured scene cannot separate V_x from E_x anyway (TUM calibrates it from a moving camera over a
planar target). The synthetic camera still applies vignetting, so the emulator is tested with it present.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass

import cv2
import numpy as np

from bracketry_base.errors import BracketryError

from .response import N_CODES, SATURATED_CODE


@dataclass(frozen=True)
class CrfCalibration:
    """Result of :func:`calibrate_response`.

    Attributes:
        icrf: float64 (4096,) inverse response, code -> linear exposure in [0, 4095], non-decreasing.
        observed: bool (4096,) codes seen unsaturated in the stack (others are interpolated).
        residual_rms: float64 (iterations,) RMS of G[I] - t E (linear DN) after each iteration.
        n_pixels: pixels used per image; exposures_us: the exposures used.
    """

    icrf: np.ndarray
    observed: np.ndarray
    residual_rms: np.ndarray
    n_pixels: int
    exposures_us: tuple[int, ...]


def _masks(images: np.ndarray, saturated_code: int, leak_padding: int, shape: tuple[int, int]) -> np.ndarray:
    """Valid mask per image (n, H*W): not saturated, dilated by ``leak_padding`` pixels around saturation."""
    sat = images.reshape(-1, *shape) >= saturated_code
    if leak_padding > 0:
        k = np.ones((2 * leak_padding + 1, 2 * leak_padding + 1), np.uint8)
        sat = np.stack([cv2.dilate(s.astype(np.uint8), k) > 0 for s in sat])
    return ~sat.reshape(images.shape)


def calibrate_response(stack: Mapping[int, Sequence[np.ndarray]] | Sequence[tuple[int, np.ndarray]],
                       iterations: int = 10, saturated_code: int = SATURATED_CODE, leak_padding: int = 2,
                       max_pixels: int = 300_000, seed: int = 0, init_gamma: float = 2.2) -> CrfCalibration:
    """Calibrate f^-1 from a static stack.

    Args:
        stack: {exposure_us: [uint16 HxW frames]} or [(exposure_us, frame), ...] of one static scene, >= 2 exposures.
        iterations: ALS iterations (TUM default 10).
        saturated_code: codes at or above it are masked.
        leak_padding: dilation radius of the saturation mask (pixels).
        max_pixels: pixels sampled per image (same positions in every image, fixed ``seed``).
    """
    pairs = ([(int(e), f) for e, frames in stack.items() for f in frames] if isinstance(stack, Mapping)
             else [(int(e), f) for e, f in stack])
    if len({e for e, _ in pairs}) < 2:
        raise BracketryError("response calibration needs frames at 2 or more exposure times")
    shape = pairs[0][1].shape
    if any(f.shape != shape or f.ndim != 2 for _, f in pairs):
        raise BracketryError("all frames of the stack must be single-channel images of the same size")
    t = np.array([e for e, _ in pairs], dtype=np.float64)
    imgs = np.stack([f.reshape(-1) for _, f in pairs])
    valid_full = _masks(imgs, saturated_code, leak_padding, shape)
    rng = np.random.default_rng(seed)
    n = imgs.shape[1]
    sel = np.sort(rng.choice(n, max_pixels, replace=False)) if n > max_pixels else np.arange(n)
    codes = imgs[:, sel].astype(np.intp)
    valid = valid_full[:, sel]
    g = 4095.0 * (np.arange(N_CODES, dtype=np.float64) / 4095.0) ** init_gamma  # start from a gamma curve
    tt = t[:, None]
    residuals = []
    observed = np.bincount(codes[valid], minlength=N_CODES) > 0
    if observed.sum() < 8:
        raise BracketryError("too few unsaturated codes in the stack to calibrate a response")
    obs_idx = np.flatnonzero(observed)
    for _ in range(iterations):
        gi = g[codes]
        num = np.sum(np.where(valid, tt * gi, 0.0), axis=0)
        den = np.sum(np.where(valid, tt * tt, 0.0), axis=0)
        e = np.divide(num, den, out=np.zeros_like(num), where=den > 0)
        target = tt * e[None, :]
        sums = np.bincount(codes[valid], weights=target[valid], minlength=N_CODES)
        counts = np.bincount(codes[valid], minlength=N_CODES)
        g_obs = sums[obs_idx] / counts[obs_idx]
        g = _fill(obs_idx, g_obs)
        scale = 4095.0 / max(g[-1], 1e-12)
        residuals.append(scale * float(np.sqrt(np.mean((g[codes][valid] - target[valid]) ** 2))))
        g *= scale
        if not np.isfinite(residuals[-1]):
            raise BracketryError("response calibration diverged")
    return CrfCalibration(g, observed, np.array(residuals), int(sel.size), tuple(sorted({int(x) for x in t})))


def _fill(obs_idx: np.ndarray, g_obs: np.ndarray) -> np.ndarray:
    """A non-decreasing 4096-entry curve through the observed (code, value) points; linear extrapolation above the
    last observed code (slope of the last 5% of observed codes), flat below the first."""
    g_obs = np.maximum.accumulate(np.maximum(g_obs, 0.0))
    codes = np.arange(N_CODES, dtype=np.float64)
    g = np.interp(codes, obs_idx.astype(np.float64), g_obs)
    last = int(obs_idx[-1])
    if last < N_CODES - 1:
        k = max(2, obs_idx.size // 20)
        x0, x1 = float(obs_idx[-k]), float(obs_idx[-1])
        slope = (g_obs[-1] - g_obs[-k]) / max(x1 - x0, 1.0)
        g[last + 1:] = g_obs[-1] + max(slope, 0.0) * (codes[last + 1:] - last)
    return np.maximum.accumulate(g)
