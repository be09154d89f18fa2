"""Pure functions of the exposure environment: working image, observations, rewards, the action -> exposure map.

Facts from Zhang et al. 2024 (arXiv 2408.17005, ShuyangUni/drl_exposure_ctrl, read for constants only):

- action: a in [-1, 1], next exposure t <- t * 2^(2a) (at most +-2 stops per frame);
- state: the last 4 images area-resized to 84x84 in [0, 1], oldest first (the first image repeated 4 times at an
  episode's start);
- statistics reward (unitless): r = -sqrt(|m_t - 0.5|) - 0.2 * sqrt(|m_t - m_{t-1}|), m the mean of the image
  normalised to [0, 1] (so r in [-1.28, 0]; 0 = mid-grey and no flicker);
- feature reward (unitless, "points"): r = 0.005 * N_orb + 0.005 * N_inliers: N_orb the ORB keypoints of the new
  8-bit image (OpenCV's default ORB, at most 500), N_inliers the RANSAC homography inliers of the brute-force
  cross-checked Hamming matches between the previous and the new image (all matches when 4 or fewer); so r in
  [0, 5];
- their simulator resized the brackets (256x192) before re-exposing them; we do the same at ``width`` (default 256)
  on the 2x2-binned mosaic (one grey value per RGGB cell), keeping the aspect ratio.

Every image here is a 2-D array: ``uint16`` working images of 12-bit codes (0..4095) or float images in [0, 1].
"""

from __future__ import annotations

from typing import Any, Literal

import cv2
import numpy as np

#: the DRL state: frames and their size (px)
N_FRAMES = 4
FRAME_SIZE = 84
#: full scale of the 12-bit codes, as the DRL method divides (``ae/drl.py``: /4096)
CODE_SCALE = 4096.0
#: statistics reward constants (their ``rwd_mean_target``, ``rwd_w_flk``)
MEAN_TARGET = 0.5
FLICKER_WEIGHT = 0.2
#: feature reward weights (their ``rwd_w_detect``, ``rwd_w_match``), per keypoint and per inlier
DETECT_WEIGHT = 0.005
MATCH_WEIGHT = 0.005
#: largest change of one action (stops): t <- t * 2^(STOPS_PER_ACTION * a)
STOPS_PER_ACTION = 2.0
#: the statistics observation: its entries
STATS_FIELDS = ("mean", "std", "p05", "p50", "p95", "dark_fraction", "bright_fraction", "log2_exposure_ms_over_8")

Reward = Literal["feat", "stat"]
REWARDS: tuple[str, ...] = ("feat", "stat")
OBSERVATIONS: tuple[str, ...] = ("frames", "stats")


def working_image(mosaic: np.ndarray, width: int = 256) -> np.ndarray:
    """The working image of a raw RGGB mosaic: 2x2 cells averaged (grey), then area-resized to ``width`` px wide
    (never enlarged; aspect ratio kept, height even).

    mosaic: uint16 (H, W) codes 0..4095, H and W even. Returns uint16 (h, w) codes 0..4095 (rounded).
    """
    if mosaic.ndim != 2:
        raise ValueError(f"expected a HxW mosaic, got shape {mosaic.shape}")
    h2, w2 = mosaic.shape[0] // 2, mosaic.shape[1] // 2
    cells = mosaic[: 2 * h2, : 2 * w2].astype(np.float32).reshape(h2, 2, w2, 2).mean(axis=(1, 3))
    if w2 > width:
        h = max(2, round(h2 * width / w2 / 2.0) * 2)
        cells = cv2.resize(cells, (width, h), interpolation=cv2.INTER_AREA)
    return np.clip(np.rint(cells), 0, 4095).astype(np.uint16)


def frame_of(image: np.ndarray) -> np.ndarray:
    """One DRL state frame: uint16 (h, w) codes -> float32 (84, 84) in [0, 1) (area resize, / 4096)."""
    small = cv2.resize(image.astype(np.float32), (FRAME_SIZE, FRAME_SIZE), interpolation=cv2.INTER_AREA)
    return small / np.float32(CODE_SCALE)


def stats_observation(image: np.ndarray, exposure_us: float) -> np.ndarray:
    """The statistics observation (:data:`STATS_FIELDS`): float32 (8,) of a uint16 (h, w) working image taken at
    ``exposure_us``: mean, std and 5/50/95th percentiles of codes / 4096, fractions of codes below 2 % and above
    98 % of full scale, and log2(exposure in ms) / 8."""
    x = image.astype(np.float32) / np.float32(CODE_SCALE)
    p05, p50, p95 = np.percentile(x, (5.0, 50.0, 95.0))
    return np.array([x.mean(), x.std(), p05, p50, p95, float((x < 0.02).mean()), float((x > 0.98).mean()),
                     np.log2(max(exposure_us, 1e-3) / 1000.0) / 8.0], dtype=np.float32)


def next_exposure_us(exposure_us: float, action: float, min_us: float, max_us: float) -> float:
    """The DRL action map: ``exposure_us * 2^(2a)`` with a clipped to [-1, 1], clamped to [min_us, max_us]."""
    a = float(np.clip(action, -1.0, 1.0))
    return float(np.clip(exposure_us * 2.0 ** (STOPS_PER_ACTION * a), min_us, max_us))


def discrete_actions(n: int) -> np.ndarray:
    """The continuous actions of the discrete variant: ``n`` (odd, >= 3) evenly spaced values of [-1, 1]
    (n = 9: steps of 0.5 stop, middle = keep the exposure). float64 (n,)."""
    if n < 3 or n % 2 == 0:
        raise ValueError(f"the discrete action count must be odd and >= 3, got {n}")
    return np.linspace(-1.0, 1.0, n)


def stat_reward(prev: np.ndarray, new: np.ndarray) -> float:
    """Statistics reward (unitless, in [-1.28, 0]) of two float images in [0, 1] (previous, new): see the module
    docstring."""
    m1, m0 = float(new.mean()), float(prev.mean())
    return -float(np.sqrt(abs(m1 - MEAN_TARGET))) - FLICKER_WEIGHT * float(np.sqrt(abs(m1 - m0)))


class FeatureReward:
    """Feature reward (unitless, in [0, 5]) of two float images in [0, 1] (previous, new): see the module
    docstring. Holds one ORB detector and one matcher (OpenCV defaults, as theirs); deterministic."""

    def __init__(self) -> None:
        self.orb = cv2.ORB_create()  # type: ignore[attr-defined]
        self.matcher = cv2.BFMatcher(cv2.NORM_HAMMING, crossCheck=True)
        self._last: tuple[np.ndarray, Any, Any] | None = None  # the last image's detections (the next one's prev)

    def _detect(self, img: np.ndarray) -> tuple[Any, Any]:
        if self._last is not None and self._last[0].shape == img.shape and np.array_equal(self._last[0], img):
            return self._last[1], self._last[2]
        kp, des = self.orb.detectAndCompute(img, None)
        self._last = (img, kp, des)
        return kp, des

    def counts(self, prev: np.ndarray, new: np.ndarray) -> tuple[int, int]:
        """(ORB keypoints of ``new``, homography inliers of the matches between ``new`` and ``prev``)."""
        img1 = (new * 255.0).astype(np.uint8)
        img0 = (prev * 255.0).astype(np.uint8)
        kp0, des0 = self._detect(img0)
        kp1, des1 = self._detect(img1)
        if not kp1 or not kp0 or des1 is None or des0 is None:
            return len(kp1), 0
        matches = self.matcher.match(des1, des0)
        if len(matches) <= 4:
            return len(kp1), len(matches)
        pts1 = np.array([kp1[m.queryIdx].pt for m in matches], dtype=np.float32)
        pts0 = np.array([kp0[m.trainIdx].pt for m in matches], dtype=np.float32)
        _, mask = cv2.findHomography(pts1, pts0, cv2.RANSAC)
        return len(kp1), 0 if mask is None else int(mask.sum())

    def __call__(self, prev: np.ndarray, new: np.ndarray) -> float:
        n_detect, n_match = self.counts(prev, new)
        return DETECT_WEIGHT * n_detect + MATCH_WEIGHT * n_match
