"""Image error metrics in 12-bit DN."""

from __future__ import annotations

import itertools

import numpy as np


def rmse_dn(a: np.ndarray, b: np.ndarray, mask: np.ndarray | None = None) -> float:
    """Root-mean-square difference (DN) of two code images (any numeric dtype, same shape), over ``mask`` if given."""
    d = a.astype(np.float64).ravel() - b.astype(np.float64).ravel()
    if mask is not None:
        d = d[mask.ravel()]
    if d.size == 0:
        return float("nan")
    return float(np.sqrt(np.dot(d, d) / d.size))


def bias_dn(a: np.ndarray, b: np.ndarray, mask: np.ndarray | None = None) -> float:
    """Mean difference a - b (DN), over ``mask`` if given."""
    d = a.astype(np.float64).ravel() - b.astype(np.float64).ravel()
    if mask is not None:
        d = d[mask.ravel()]
    return float(d.mean()) if d.size else float("nan")


def noise_corrected(rmse: float, floor_dn: float) -> float:
    """RMSE with the camera-noise floor removed: sqrt(max(rmse^2 - floor^2, 0)).

    ``floor_dn`` is what two real frames at the same exposure differ by (:func:`noise_floor_dn`), i.e. the RMSE a
    perfect emulator producing a camera-like noisy frame would get against a noisy ground truth (the paper's
    correction, "the difference between 25 images from the same exposure time")."""
    return float(np.sqrt(max(rmse * rmse - floor_dn * floor_dn, 0.0)))


def noise_floor_dn(frames: list[np.ndarray]) -> float:
    """RMS difference (DN) between repeated frames of a static scene, averaged over consecutive pairs (in quadrature);
    about sqrt(2) x the temporal noise."""
    if len(frames) < 2:
        raise ValueError("the noise floor needs at least 2 frames")
    sq = [rmse_dn(a, b) ** 2 for a, b in itertools.pairwise(frames)]
    return float(np.sqrt(np.mean(sq)))
