"""Motion-blur emulation: the blur a target exposure longer than its source bracket would have.

A frame triggered at t and exposed T integrates the moving image over [t, t + T]; the source bracket of exposure
S < T (same trigger) holds only [t, t + S]. With the image velocity v (pixels per second) of every pixel, the
target is approximated by averaging the source over the shifts v u, u in [0, T - S]:

    I_T(x) ~ mean_u I_S(x - v u)        (linear signal, before the exposure factor)

whose kernel is the source's box of length v S convolved with a box of length v (T - S): the support v T and the
centre v T / 2 of the true box, a trapezoid instead of a box (10-90 % width within ~10 % of the true one once
T >= 2 S).

Velocity from optical flow between the source and the bracket nearest to it in time (the next or previous frame of
the bracket cycle, ~46 ms away): dense Farneback flow (OpenCV) on the half-resolution gray log-irradiance of both
(linear / exposure, so the brackets match photometrically; the longer bracket's saturated pixels take the shorter
one's value), divided by the time between their mid-exposure stamps. Optical flow rather than pose and depth: it needs
nothing but the brackets, so it runs on real recordings as on synthetic ones, and catches moving objects; a pose-
and-depth flow would need a depth map the datasets do not have. Flow below ``STILL_PX`` between the two brackets
(noise on a static scene, a fraction of a pixel) counts as no motion: a static scene is emulated unchanged.

Warping: the four Bayer planes are shifted separately (half-resolution flow, bilinear), keeping the RGGB phase.
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


def add_motion_blur(linear: np.ndarray, velocity: Velocity, extra_s: float) -> np.ndarray:
    """The linear mosaic ``linear`` (float HxW, H and W even) averaged over the shifts v u, u in [0, ``extra_s``]
    (module docstring); float32 HxW. Unchanged (a float32 copy) where nothing moves or ``extra_s`` <= 0."""
    out = linear.astype(np.float32, copy=True)
    if extra_s <= 0 or velocity.still:
        return out
    path_px = velocity.max_px(extra_s)
    if path_px < STEP_PX:
        return out
    n = min(MAX_SAMPLES, max(2, math.ceil(path_px / STEP_PX) + 1))
    h2, w2 = velocity.vx.shape
    gy, gx = np.mgrid[0:h2, 0:w2].astype(np.float32)
    planes = [(dy, dx) for dy in (0, 1) for dx in (0, 1)]
    acc = np.zeros((len(planes), h2, w2), dtype=np.float32)
    srcs = [np.ascontiguousarray(out[dy::2, dx::2]) for dy, dx in planes]
    for j in range(n):
        u = np.float32(extra_s * (j + 0.5) / n)
        mx = gx - velocity.vx * u
        my = gy - velocity.vy * u
        for k, plane in enumerate(srcs):
            acc[k] += cv2.remap(plane, mx, my, cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE)
    for k, (dy, dx) in enumerate(planes):
        out[dy::2, dx::2] = acc[k] / np.float32(n)
    return out
