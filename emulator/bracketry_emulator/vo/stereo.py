"""Left-right matching of ORB keypoints on a rectified stereo pair (ORB-SLAM2's ``ComputeStereoMatches`` recipe).

For each left keypoint: right candidates on rows ``|y_l - y_r| <= 2 * s^octave``, octave within +-1, disparity in
``(0, fx]``; the best Hamming distance must be <= 75 (ORB-SLAM's (TH_HIGH + TH_LOW) / 2). The match is then refined
to sub-pixel by an 11x11 SAD search of +-5 px along the row on the keypoint's pyramid level and a parabola fit
(rejected when the minimum is at the search edge or the fit moves it by more than one pixel), and matches whose SAD
exceeds 1.5 * 1.4 * median are dropped. Depth is ``Z = bf / disparity``.
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np

from bracketry_emulator.features.orb import Features, hamming_distance

TH_STEREO_HAMMING = 75
_W = 5  # SAD half window (11x11)
_L = 5  # SAD search half range (pixels at the keypoint's level)


@dataclass
class StereoMatches:
    """Per left keypoint: ``u_right_px`` (float, NaN when unmatched) and ``depth_m`` (NaN when unmatched)."""

    u_right_px: np.ndarray
    depth_m: np.ndarray

    @property
    def valid(self) -> np.ndarray:
        """bool N: the keypoint has a stereo depth."""
        return np.isfinite(self.depth_m)


def _candidate_pairs(left: Features, right: Features, max_disp_px: float) -> tuple[np.ndarray, np.ndarray]:
    """All (left index, right index) pairs that satisfy the row, octave and disparity constraints."""
    order = np.argsort(right.xy_px[:, 1], kind="stable")
    ry = right.xy_px[order, 1]
    radius = 2.0 * left.scale_factors[left.octave]
    lo = np.searchsorted(ry, left.xy_px[:, 1] - radius, side="left")
    hi = np.searchsorted(ry, left.xy_px[:, 1] + radius, side="right")
    counts = hi - lo
    li = np.repeat(np.arange(len(left)), counts)
    offsets = np.arange(counts.sum()) - np.repeat(np.cumsum(counts) - counts, counts)
    ri = order[np.repeat(lo, counts) + offsets]
    disp = left.xy_px[li, 0] - right.xy_px[ri, 0]
    ok = (disp > 0) & (disp <= max_disp_px) & (np.abs(left.octave[li] - right.octave[ri]) <= 1)
    return li[ok], ri[ok]


def _level_images(image: np.ndarray, levels: np.ndarray, scales: np.ndarray) -> dict[int, np.ndarray]:
    h, w = image.shape
    out: dict[int, np.ndarray] = {0: image}
    current = image
    for level in range(1, int(levels.max(initial=0)) + 1):
        current = cv2.resize(current, (round(w / scales[level]), round(h / scales[level])),
                             interpolation=cv2.INTER_LINEAR)
        out[level] = current
    return out


def _refine_subpixel(left_img: np.ndarray, right_img: np.ndarray, left: Features, li: np.ndarray,
                     ur0: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Sub-pixel right x (level-0 px, NaN when rejected) and the best SAD per match, by SAD on each octave."""
    ur = np.full(len(li), np.nan)
    sad_best = np.full(len(li), np.inf)
    if len(li) == 0:
        return ur, sad_best
    scales = left.scale_factors
    octaves = left.octave[li]
    lpyr = _level_images(left_img, octaves, scales)
    rpyr = _level_images(right_img, octaves, scales)
    win = np.arange(-_W, _W + 1)
    shifts = np.arange(-_L, _L + 1)
    for level in np.unique(octaves):
        sel = np.flatnonzero(octaves == level)
        s = scales[level]
        limg = lpyr[int(level)].astype(np.float32)
        rimg = rpyr[int(level)].astype(np.float32)
        h, w = limg.shape
        xl = np.rint(left.xy_px[li[sel], 0] / s).astype(int)
        yl = np.rint(left.xy_px[li[sel], 1] / s).astype(int)
        xr = np.rint(ur0[sel] / s).astype(int)
        ok = ((yl - _W >= 0) & (yl + _W < h) & (xl - _W >= 0) & (xl + _W < w)
              & (xr - _W - _L - 1 >= 0) & (xr + _W + _L + 1 < w))
        sel, xl, yl, xr = sel[ok], xl[ok], yl[ok], xr[ok]
        if len(sel) == 0:
            continue
        rows = yl[:, None, None] + win[None, :, None]
        patch_l = limg[rows, xl[:, None, None] + win[None, None, :]]
        patch_l = patch_l - patch_l[:, _W:_W + 1, _W:_W + 1]
        sads = np.empty((len(sel), len(shifts)), np.float32)
        for k, sh in enumerate(shifts):
            patch_r = rimg[rows, (xr + sh)[:, None, None] + win[None, None, :]]
            patch_r = patch_r - patch_r[:, _W:_W + 1, _W:_W + 1]
            sads[:, k] = np.abs(patch_l - patch_r).sum(axis=(1, 2))
        best = np.argmin(sads, axis=1)
        interior = (best > 0) & (best < len(shifts) - 1)
        idx = np.arange(len(sel))
        b = np.clip(best, 1, len(shifts) - 2)
        d1, d2, d3 = sads[idx, b - 1], sads[idx, b], sads[idx, b + 1]
        denom = 2.0 * (d1 + d3 - 2.0 * d2)
        with np.errstate(divide="ignore", invalid="ignore"):
            delta = np.where(denom != 0, (d1 - d3) / denom, 0.0)
        good = interior & (np.abs(delta) <= 1.0)
        ur[sel[good]] = (xr[good] + shifts[best[good]] + delta[good]) * s
        sad_best[sel[good]] = sads[idx[good], best[good]]
    return ur, sad_best


def match_stereo(left: Features, right: Features, left_img: np.ndarray, right_img: np.ndarray, fx_px: float,
                 bf_m_px: float) -> StereoMatches:
    """Match rectified left keypoints to right keypoints and give each a depth.

    Args:
        left, right: features of the rectified left and right uint8 images ``left_img``, ``right_img`` (HxW).
        fx_px: rectified focal length (pixels), the largest disparity searched.
        bf_m_px: baseline (m) x fx (px).
    Returns:
        :class:`StereoMatches` with one entry per left keypoint.
    """
    n = len(left)
    u_right = np.full(n, np.nan)
    depth = np.full(n, np.nan)
    if n == 0 or len(right) == 0:
        return StereoMatches(u_right, depth)
    li, ri = _candidate_pairs(left, right, fx_px)
    if len(li) == 0:
        return StereoMatches(u_right, depth)
    dist = hamming_distance(left.descriptors[li], right.descriptors[ri])
    order = np.lexsort((dist, li))
    li, ri, dist = li[order], ri[order], dist[order]
    first = np.r_[True, li[1:] != li[:-1]]
    li, ri, dist = li[first], ri[first], dist[first]
    keep = dist <= TH_STEREO_HAMMING
    li, ri = li[keep], ri[keep]
    ur, sad = _refine_subpixel(left_img, right_img, left, li, right.xy_px[ri, 0].astype(np.float64))
    ok = np.isfinite(ur)
    if ok.any():
        median = float(np.median(sad[ok]))
        ok &= sad <= 1.5 * 1.4 * median if median > 0 else ok
    disp = left.xy_px[li, 0] - ur
    ok &= disp > 0
    u_right[li[ok]] = ur[ok]
    depth[li[ok]] = bf_m_px / disp[ok]
    return StereoMatches(u_right, depth)
