"""Motion-blur emulation: the blur a target exposure longer than its source bracket would have.

A frame triggered at t and exposed T integrates the moving image over [t, t + T]; the source bracket of exposure
S < T (same trigger) holds only [t, t + S]. With the image velocity v (pixels per second) of every pixel, the
target is the mean of copies of the source moved along the path:

    I_T(x) ~ mean_k I_S(x - v u_k),   u_k = k (T - S) / (n - 1), k = 0 .. n - 1,  n = ceil(T / S)

(linear signal, before the exposure factor). Each copy already holds S of motion, so copies at most S apart leave no
gap: for T a whole multiple of S the kernel is exactly the true box of length v T (the S-box convolved with a comb of
pitch v S), otherwise boxes overlapping a little, with the true support and centre. Where the copies would be less
than ``STEP_PX`` apart along the path (S much shorter than T, or slow motion), fewer copies at most ``STEP_PX``
apart: the same image to the bilinear resampling's precision.

Moving a Bayer mosaic by a fraction of a pixel: each colour plane alone is sampled every 2 pixels, so a plane moved on
its own grid (bilinear) loses the detail between its samples, which the other planes hold. The copies are made from
the mosaic's luminance at full resolution instead: every pixel divided by its plane's local colour ratio (the plane's
low-pass, ``RATIO_SIGMA_PX``, over the mean of the four planes' low-passes taken at the same points: pattern-agnostic,
1 on a gray scene), moved on the full-resolution grid (bilinear), and multiplied by its plane's ratio moved with it
(colour-ratio interpolation, as demosaicing does). Measured by ``bracketry accuracy motion`` (emulator/DATASET.md:
moving each plane on its own grid removed 24-26 % of the error the blur leaves, this 35-38 %).

Velocity from optical flow between the source and the bracket nearest to it in time (the next or previous frame of
the bracket cycle, ~46 ms away): dense DIS flow (OpenCV) on the half-resolution gray log-irradiance of both
(linear / exposure, so the brackets match photometrically; the longer bracket's saturated pixels take the shorter
one's value), divided by the time between their mid-exposure stamps. Optical flow rather than pose and depth: it needs
nothing but the brackets, so it runs on real recordings as on synthetic ones, and catches moving objects; a pose-
and-depth flow would need a depth map the datasets do not have. Flow below ``STILL_PX`` between the two brackets
(noise on a static scene, a fraction of a pixel) counts as no motion: a static scene is emulated unchanged.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import cv2
import numpy as np

from .align import bayer_gray_half

#: optical flow magnitude (half-resolution pixels between the two brackets) below which a pixel is still
STILL_PX = 0.35
#: the largest number of shifted copies averaged (one per ``STEP_PX`` of the longest blur path)
MAX_SAMPLES = 48
#: spacing of the shifted copies along the blur path (half-resolution pixels)
STEP_PX = 0.5
#: Gaussian smoothing of the flow field (half-resolution pixels)
FLOW_SMOOTH_PX = 2.0
#: Gaussian sigma of the low-pass of each colour plane whose ratio to the planes' mean is the local colour ratio
#: (half-resolution pixels)
RATIO_SIGMA_PX = 1.0


#: the lowest linear level (DN, half-resolution gray) of both brackets where the flow is trusted
MIN_FLOW_LEVEL = 64.0
#: the least local contrast (Sobel magnitude of the 8-bit log image, smoothed) where the flow is trusted
MIN_TEXTURE = 8.0
#: the flow is not trusted this close to the image border (half-resolution pixels)
BORDER_PX = 8
#: reach of the fill of untrusted pixels from trusted ones (half-resolution pixels, Gaussian sigma)
FILL_SIGMA_PX = 8.0


def _fill(flow: np.ndarray, sure: np.ndarray) -> np.ndarray:
    """``flow`` (float32 (h, w, 2)) where ``sure`` (bool (h, w)); elsewhere the Gaussian-weighted mean of the sure
    flow around (normalised convolution), 0 where none is near."""
    w = cv2.GaussianBlur(sure.astype(np.float32), (0, 0), FILL_SIGMA_PX)
    out = flow.copy()
    for c in range(2):
        num = cv2.GaussianBlur(np.where(sure, flow[..., c], 0.0).astype(np.float32), (0, 0), FILL_SIGMA_PX)
        filled = np.divide(num, w, out=np.zeros_like(num), where=w > 1e-3)
        out[..., c] = np.where(sure, flow[..., c], filled)
    return out


@dataclass(frozen=True)
class Velocity:
    """Image velocity of the source bracket's pixels: ``vx``, ``vy`` float32 (H/2, W/2) in half-resolution pixels
    per second (x right, y down), at the source's geometry."""

    vx: np.ndarray
    vy: np.ndarray

    def max_px(self, seconds: float) -> float:
        """The longest path (half-resolution pixels) of any pixel over ``seconds``."""
        return float(np.sqrt(self.vx * self.vx + self.vy * self.vy).max(initial=0.0)) * seconds

    @property
    def still(self) -> bool:
        return not (np.any(self.vx) or np.any(self.vy))


def image_velocity(source_linear: np.ndarray, source_us: float, source_t_ns: int, source_valid: np.ndarray,
                   other_linear: np.ndarray, other_us: float, other_t_ns: int, other_valid: np.ndarray) -> Velocity:
    """Velocity of the source's pixels from dense optical flow to another bracket of the same camera.

    ``*_linear``: float HxW linear mosaics (DN at unity gain); ``*_us``: their exposures; ``*_t_ns``: their
    mid-exposure stamps (ns, different); ``*_valid``: bool HxW, False at the saturated code."""
    dt_s = (other_t_ns - source_t_ns) * 1e-9
    if dt_s == 0:
        raise ValueError("the two brackets have the same timestamp: no motion can be measured")
    sv = bayer_gray_half(source_valid.astype(np.float32)) == 1.0
    ov = bayer_gray_half(other_valid.astype(np.float32)) == 1.0
    src = bayer_gray_half(source_linear) / np.float32(source_us)
    oth = bayer_gray_half(other_linear) / np.float32(other_us)
    # a pixel saturated in one bracket takes the other's irradiance there (the flow is smooth over such patches)
    src = np.where(sv, src, np.where(ov, oth, src))
    oth = np.where(ov, oth, src)
    a = np.log(np.maximum(src, 1e-4)).astype(np.float32)
    b = np.log(np.maximum(oth, 1e-4)).astype(np.float32)
    lo, hi = np.percentile(np.concatenate([a.ravel(), b.ravel()]), [0.5, 99.5])
    scale = 255.0 / max(float(hi - lo), 1e-6)
    a8 = np.clip((a - lo) * scale, 0, 255).astype(np.uint8)
    b8 = np.clip((b - lo) * scale, 0, 255).astype(np.uint8)
    # DIS (OpenCV's dense inverse search, preset medium): follows the tens of pixels a bracket period can hold, where
    # Farneback's pyramid lost them (a textured scene moving 11 half-resolution pixels: Farneback's median 0.25)
    dis = cv2.DISOpticalFlow.create(cv2.DISOPTICAL_FLOW_PRESET_MEDIUM)
    flow = np.asarray(dis.calc(a8, b8, np.zeros((*a8.shape, 2), np.float32)))
    # where either bracket is too dark to follow (noise) or saturated (or within 3 px of it: the edge of a saturated
    # patch moves with its size, not with the scene), flat or at the border, the flow of the confident pixels around
    near_sat = cv2.dilate((~(sv & ov)).astype(np.uint8), np.ones((7, 7), np.uint8)) > 0
    sure = ~near_sat & (src * np.float32(source_us) >= MIN_FLOW_LEVEL) & (oth * np.float32(other_us) >= MIN_FLOW_LEVEL)
    gx = cv2.Sobel(a8, cv2.CV_32F, 1, 0, ksize=3)
    gy = cv2.Sobel(a8, cv2.CV_32F, 0, 1, ksize=3)
    texture = cv2.GaussianBlur(np.sqrt(gx * gx + gy * gy), (0, 0), 2.0)
    sure &= texture >= MIN_TEXTURE  # a flat patch has no motion to see
    m = BORDER_PX
    sure[:m, :] = sure[-m:, :] = False
    sure[:, :m] = sure[:, -m:] = False
    flow = _fill(flow, sure)
    flow = np.dstack([cv2.medianBlur(np.ascontiguousarray(flow[..., c]), 5) for c in range(2)])  # lone outliers
    flow = cv2.GaussianBlur(flow, (0, 0), FLOW_SMOOTH_PX) if FLOW_SMOOTH_PX > 0 else flow
    mag = np.sqrt(flow[..., 0] ** 2 + flow[..., 1] ** 2)
    still = mag < STILL_PX
    vx = np.where(still, 0.0, flow[..., 0] / dt_s).astype(np.float32)
    vy = np.where(still, 0.0, flow[..., 1] / dt_s).astype(np.float32)
    return Velocity(vx, vy)


def copy_shifts_s(extra_s: float, source_s: float | None, path_px: float) -> np.ndarray:
    """Times u_k (s, float64 (n,), 0 .. ``extra_s`` evenly) by which the copies of the source move along the path
    (module docstring): copies at most one source exposure ``source_s`` apart in time (n = ceil(T / S), T = S +
    ``extra_s``) or at most :data:`STEP_PX` apart along the longest path ``path_px``, whichever needs fewer; 2 to
    :data:`MAX_SAMPLES`. Without ``source_s``: by the path alone."""
    n = math.ceil(path_px / STEP_PX) + 1
    if source_s is not None and source_s > 0:
        n = min(n, math.ceil((extra_s + source_s) / source_s - 1e-9))
    return np.linspace(0.0, extra_s, min(max(2, n), MAX_SAMPLES))


def colour_ratios(linear: np.ndarray) -> np.ndarray:
    """Local colour ratio of each plane of a 2x2 mosaic at its own pixels: float32 (4, H/2, W/2), planes in the order
    (0, 0), (0, 1), (1, 0), (1, 1). The plane's Gaussian low-pass (:data:`RATIO_SIGMA_PX`) over the mean of the four
    low-passes, each taken at the same points (the planes sit half a plane pixel apart: their low-passes moved
    there, bicubic; a plane's own low-pass against its neighbours' unmoved would read an edge as a colour)."""
    low = [cv2.GaussianBlur(np.ascontiguousarray(linear[dy::2, dx::2], dtype=np.float32), (0, 0), RATIO_SIGMA_PX)
           for dy, dx in _PLANES]
    h2, w2 = low[0].shape
    out = np.empty((len(_PLANES), h2, w2), np.float32)
    for k, (dy, dx) in enumerate(_PLANES):
        mean = np.zeros((h2, w2), np.float32)
        for j, (ey, ex) in enumerate(_PLANES):
            # plane j's value at plane k's pixels: (dx - ex) / 2 plane pixels to the right of plane j's own
            shift = np.array([[1.0, 0.0, (dx - ex) / 2], [0.0, 1.0, (dy - ey) / 2]], np.float32)
            mean += low[j] if (ey, ex) == (dy, dx) else cv2.warpAffine(
                low[j], shift, (w2, h2), flags=cv2.INTER_CUBIC | cv2.WARP_INVERSE_MAP,
                borderMode=cv2.BORDER_REPLICATE)
        out[k] = np.maximum(low[k], np.float32(1e-3)) / np.maximum(mean * np.float32(0.25), np.float32(1e-3))
    return out


_PLANES: tuple[tuple[int, int], ...] = ((0, 0), (0, 1), (1, 0), (1, 1))


def _mosaic_of(planes: np.ndarray) -> np.ndarray:
    """The (H, W) mosaic of four planes (H/2, W/2, 4) in the order of ``_PLANES``."""
    h2, w2, _ = planes.shape
    return planes.reshape(h2, w2, 2, 2).transpose(0, 2, 1, 3).reshape(2 * h2, 2 * w2)


def add_motion_blur(linear: np.ndarray, velocity: Velocity, extra_s: float,
                    source_s: float | None = None) -> np.ndarray:
    """The linear mosaic ``linear`` (float HxW, H and W even) of a source exposed ``source_s`` (s) as if exposed
    ``extra_s`` longer: the mean of its copies moved by v u_k (module docstring); float32 HxW. Unchanged (a float32
    copy) where nothing moves or ``extra_s`` <= 0."""
    out = linear.astype(np.float32, copy=True)
    if extra_s <= 0 or velocity.still:
        return out
    path_px = velocity.max_px(extra_s)
    if path_px < STEP_PX:
        return out
    shifts = copy_shifts_s(extra_s, source_s, path_px)
    f32 = np.float32
    ratio = colour_ratios(out)
    h2, w2 = velocity.vx.shape
    lum = out / _mosaic_of(ratio.transpose(1, 2, 0))  # the luminance at full resolution
    ratio_hw4 = np.ascontiguousarray(ratio.transpose(1, 2, 0))
    # the half- and full-resolution grids and the velocity of each pixel (of its 2x2 cell at full resolution) in
    # pixels per second of that grid
    hy, hx = np.mgrid[0:h2, 0:w2].astype(f32)
    fy, fx = np.mgrid[0:2 * h2, 0:2 * w2].astype(f32)
    hvx, hvy = velocity.vx.astype(f32), velocity.vy.astype(f32)
    fvx, fvy = (np.repeat(np.repeat(v * f32(2.0), 2, axis=0), 2, axis=1) for v in (hvx, hvy))
    acc = np.zeros_like(lum)
    acc_cells = acc.reshape(h2, 2, w2, 2)  # a view: [row, dy, column, dx]
    for u in shifts:
        moved = cv2.remap(lum, cv2.scaleAdd(fvx, -float(u), fx), cv2.scaleAdd(fvy, -float(u), fy), cv2.INTER_LINEAR,
                          borderMode=cv2.BORDER_REPLICATE)
        moved_ratio = cv2.remap(ratio_hw4, cv2.scaleAdd(hvx, -float(u), hx), cv2.scaleAdd(hvy, -float(u), hy),
                                cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE)
        acc_cells += moved.reshape(h2, 2, w2, 2) * moved_ratio.reshape(h2, w2, 2, 2).transpose(0, 2, 1, 3)
    acc *= f32(1.0 / len(shifts))
    return acc
