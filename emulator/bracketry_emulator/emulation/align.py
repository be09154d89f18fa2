"""Global motion between brackets: estimate on linearized gray images, warp Bayer mosaics channel by channel.

Brackets of one sequence are ~46 ms apart on a walking backpack (median 1-2 px, up to ~15 px), so fusing or
comparing them pixel by pixel mixes motion into photometry. Estimation runs on the half-resolution gray image of
the *linear* exposure divided by the exposure time (so brackets match photometrically), clipped to pixels valid in
both. Warping applies one full-resolution 3x3 transform to each of the four Bayer planes, keeping the RGGB phase.
"""

from __future__ import annotations

import contextlib
from typing import Literal

import cv2
import numpy as np

Motion = Literal["none", "translation", "homography"]
#: Resolution of the estimation relative to the half-resolution gray image (1.0: 960x600 for 1920x1200).
ALIGN_SCALE = 1.0


def bayer_gray_half(linear: np.ndarray) -> np.ndarray:
    """Mean of each 2x2 RGGB block: float32 (H/2, W/2) from a float HxW linear mosaic (H, W even)."""
    x = linear.astype(np.float32, copy=False)
    return 0.25 * (x[0::2, 0::2] + x[0::2, 1::2] + x[1::2, 0::2] + x[1::2, 1::2])


def _log_norm(img: np.ndarray) -> np.ndarray:
    return np.log1p(np.maximum(img, 0.0)).astype(np.float32)


def estimate_motion(moving: np.ndarray, reference: np.ndarray, motion: Motion = "homography",
                    valid: np.ndarray | None = None) -> np.ndarray:
    """Full-resolution 3x3 transform (float64) mapping reference pixel coordinates to moving coordinates.

    ``moving``, ``reference``: float HxW linear irradiance mosaics (linear / exposure time) of the same scene.
    ``valid``: optional bool (H/2, W/2) mask of usable half-resolution pixels. Falls back to the identity when the
    estimation does not converge.
    """
    eye = np.eye(3)
    if motion == "none":
        return eye
    mov = _log_norm(bayer_gray_half(moving))
    ref = _log_norm(bayer_gray_half(reference))
    # optionally below the half resolution for speed (global motion is smooth)
    scale = ALIGN_SCALE
    mov_s = cv2.resize(mov, None, fx=scale, fy=scale, interpolation=cv2.INTER_AREA)
    ref_s = cv2.resize(ref, None, fx=scale, fy=scale, interpolation=cv2.INTER_AREA)
    win = cv2.createHanningWindow(ref_s.shape[::-1], cv2.CV_32F)
    (dx, dy), _resp = cv2.phaseCorrelate(ref_s, mov_s, win)
    # coordinates: reference (x, y) -> moving (x + dx, y + dy) at this scale
    warp = np.array([[1, 0, dx], [0, 1, dy], [0, 0, 1]], dtype=np.float32)
    # refine with ECC (sub-pixel, and the full homography when asked), initialised by the phase correlation
    mask: np.ndarray = np.ones(ref_s.shape, dtype=np.uint8)
    if valid is not None:
        mask = cv2.resize(valid.astype(np.uint8), ref_s.shape[::-1], interpolation=cv2.INTER_NEAREST)
    criteria = (cv2.TERM_CRITERIA_EPS | cv2.TERM_CRITERIA_COUNT, 60, 1e-5)
    with contextlib.suppress(cv2.error):
        if motion == "homography":
            _cc, found = cv2.findTransformECC(ref_s, mov_s, warp, cv2.MOTION_HOMOGRAPHY, criteria, mask, 3)
            warp = np.asarray(found, dtype=np.float32)
        else:
            _cc, found = cv2.findTransformECC(ref_s, mov_s, np.ascontiguousarray(warp[:2]), cv2.MOTION_TRANSLATION,
                                              criteria, mask, 3)
            warp[:2] = np.asarray(found, dtype=np.float32)
    # small-image pixel j has its centre at full-resolution 2 (j + 0.5) / scale - 0.5 (half = 2x2 blocks)
    s = 2.0 / scale
    c = 1.0 / scale - 0.5
    to_full = np.array([[s, 0, c], [0, s, c], [0, 0, 1.0]])
    return to_full @ warp.astype(np.float64) @ np.linalg.inv(to_full)


def warp_mosaic(mosaic: np.ndarray, ref_to_moving: np.ndarray, border_value: float = np.nan) -> np.ndarray:
    """Resample a float HxW Bayer mosaic into the reference geometry, plane by plane (bilinear).

    ``ref_to_moving``: 3x3 full-resolution transform from :func:`estimate_motion`. Returns float32 HxW; pixels
    that come from outside the frame are ``border_value`` (NaN by default, i.e. invalid).
    """
    out = np.empty(mosaic.shape, dtype=np.float32)
    src = mosaic.astype(np.float32, copy=False)
    for dy in (0, 1):
        for dx in (0, 1):
            s_d = np.array([[2.0, 0, dx], [0, 2.0, dy], [0, 0, 1]])
            m = np.linalg.inv(s_d) @ ref_to_moving @ s_d  # plane coords (ref) -> plane coords (moving)
            plane = np.ascontiguousarray(src[dy::2, dx::2])
            out[dy::2, dx::2] = cv2.warpPerspective(plane, m, plane.shape[::-1],
                                                    flags=cv2.INTER_LINEAR | cv2.WARP_INVERSE_MAP,
                                                    borderMode=cv2.BORDER_CONSTANT, borderValue=border_value)
    return out
