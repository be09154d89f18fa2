"""Wang 2022: CRF-synthesised heuristic search plus a photometric-sensitivity gradient refinement (id wang).

Paper: Y. Wang, H. Chen, S. Zhang, W. Lu, "Automated camera-exposure control for robust localization in varying
illumination environments", Autonomous Robots 46 (2022), doi 10.1007/s10514-022-10036-x (code
HITSZ-NRSL/ExposureControl). The benchmark authors re-implemented it (later revision of their code); we follow them.

On I = gray / 16 (8-bit scale):
- quality Q(I) = sum_x W(I(x)) |Sobel I(x)|^2 with the two-sigmoid weight
  W(i) = 1 / (1 + a e^{b (63.5 - i)}) - 0.001 for i <= 127, else 1 / (1 + a e^{b (i - 191.5)}) - 0.001,
  a = 0.25, b = 0.2 (Wang's code; the benchmark authors use a = 5, b = 1/5, available as parameters);
- search (n = 3 iterations): synthesise the ORIGINAL image through the CRF at gamma alpha and gamma beta
  (alpha = 0.5, beta = 2, gamma = 1 at start); when the better side beats ``accept_ratio`` x the current best
  quality (1.1, Wang's paper; no threshold is documented for the authors' code: ``accept_ratio=1.0`` moves on any
  improvement), move there (gamma *= that factor) and pull the other factor towards 1 ((1 + x) / 2); otherwise
  pull both;
- t_s = t (1 + k (gamma - 1)), k = 0.5 (the benchmark authors; Wang's paper uses 0.1);
- refinement at t_s on the synthesised image I_s: d = sum W 2 (grad I_s . grad (1 / (t_s g'(I_s)))) / sum W, with the
  per-pixel term replaced by +2 where I_s < 30 and -2 where I_s > 225; t_next = t_s + zeta d, zeta = 0.001 ms.

Deliberate deviations:
- Quirk FIXED: in the authors' code h (a degree-5 fit of log pcalib) is used directly as the derivative g'; we use the
  true slope of ln f^-1 of the emulator's response. The CRF synthesis also uses the emulator's response (the
  authors fit degree-5 polynomials to pcalib_forest2024).
- Quirk FIXED: in Wang's code the saturation branches (I > 225 -> -2 W, I < 30 -> +2 W) never fire because the
  intensity index is hard-coded to 100; we apply them (the paper's intent).
- Quirk FIXED: the -0.001 offset makes W negative for I <= 22 and I >= 233, where the refinement's saturation
  overrides apply: weighted by W, the +2 of a very dark pixel pushed towards a shorter exposure (and a sum of
  weights near 0 could flip or blow up d). The refinement averages with |W|; the quality Q keeps W as published.
- Speed: gray area-downscaled to ``work_width`` = 480 columns (7 syntheses per frame).
- The paper's frame-to-frame photometric compensation is not needed in the emulator and is left out.
- Correction (saturation guard): the search synthesises darker images from the clipped one, which cannot show the
  lost detail, and the refinement's -2 overrides move at most zeta = 0.001 ms per step, so on a mostly saturated
  scene Wang stops early (measured on a static scene 92 % saturated at 4 ms: 3.17 ms with 79 % still saturated).
  The refinement does not help: its +-2 overrides have no common scale with the gradient terms of the unsaturated
  pixels (hundreds), which push back up (measured: +0.5 ms per step at 3 ms). When more than
  ``base.SATURATION_GUARD`` = 10 % of the pixels are at the saturated code, the step is Wang's own search step
  down, gamma = alpha (0.5), t_next = t_s = 0.75 t, without the refinement. Neither Wang's paper nor the authors'
  code has it.
"""

from __future__ import annotations

from typing import Any

import cv2
import numpy as np

from .base import SATURATION_GUARD, check_input, saturated_fraction, work_gray_for
from .crfutil import log_icrf_slope, response_of, synthesise


def wang_weight(i8: np.ndarray, a: float = 0.25, b: float = 0.2) -> np.ndarray:
    """Wang's two-sigmoid photometric weight of 8-bit-scale intensities (float64, same shape)."""
    i = np.asarray(i8, dtype=np.float64)
    low = 1.0 / (1.0 + a * np.exp(b * (63.5 - i))) - 0.001
    high = 1.0 / (1.0 + a * np.exp(b * (i - 191.5))) - 0.001
    return np.where(i <= 127, low, high)


def wang_quality(i8: np.ndarray, a: float = 0.25, b: float = 0.2) -> float:
    """Q(I) = sum W(I) (Sobel_x^2 + Sobel_y^2) of an 8-bit-scale gray image (HxW, float)."""
    f = np.asarray(i8, dtype=np.float32)
    gx = cv2.Sobel(f, cv2.CV_32F, 1, 0, ksize=3).astype(np.float64)
    gy = cv2.Sobel(f, cv2.CV_32F, 0, 1, ksize=3).astype(np.float64)
    return float(np.sum(wang_weight(f, a, b) * (gx * gx + gy * gy)))


def wang_refinement(i8: np.ndarray, t_ms: float, slope_per_code8: np.ndarray, a: float = 0.25, b: float = 0.2,
                    low: float = 30.0, high: float = 225.0) -> float:
    """Refinement direction d (dimensionless) of an 8-bit-scale image at t_ms; ``slope_per_code8``: g' per 8-bit
    code, float64 (256,)."""
    f = np.asarray(i8, dtype=np.float32)
    codes = np.clip(np.rint(f), 0, 255).astype(np.intp)
    inv = (1.0 / (t_ms * slope_per_code8[codes])).astype(np.float32)
    gx, gy = cv2.Sobel(f, cv2.CV_32F, 1, 0, ksize=3), cv2.Sobel(f, cv2.CV_32F, 0, 1, ksize=3)
    jx, jy = cv2.Sobel(inv, cv2.CV_32F, 1, 0, ksize=3), cv2.Sobel(inv, cv2.CV_32F, 0, 1, ksize=3)
    term = 2.0 * (gx.astype(np.float64) * jx + gy.astype(np.float64) * jy)
    term = np.where(f < low, 2.0, np.where(f > high, -2.0, term))
    w = np.abs(wang_weight(f, a, b))  # |W|: see the module docstring (negative weights flip the overrides)
    sw = float(w.sum())
    return float(np.sum(w * term) / sw) if sw != 0 else 0.0


class WangAE:
    """Wang 2022 search + refinement AE (see the module docstring)."""

    #: relative cost of one step, for balancing worker processes (see registry.MethodTraits)
    step_cost = 20

    def __init__(self, alpha: float = 0.5, beta: float = 2.0, iterations: int = 3, accept_ratio: float = 1.1,
                 k: float = 0.5, zeta_ms: float = 0.001, a: float = 0.25, b: float = 0.2, work_width: int = 480,
                 name: str = "wang") -> None:
        self.alpha, self.beta, self.iterations, self.accept_ratio = alpha, beta, iterations, accept_ratio
        self.k, self.zeta_ms, self.a, self.b = k, zeta_ms, a, b
        self.work_width = work_width
        self.name = name
        self.last_gamma = 1.0

    def reset(self, init_exposure_us: float) -> None:
        self.last_gamma = 1.0

    def search_gamma(self, gray12: np.ndarray, response: Any) -> float:
        """The heuristic search's exposure ratio gamma for a 12-bit-scale gray image."""
        gamma, alpha, beta = 1.0, self.alpha, self.beta
        best = wang_quality(gray12 / 16.0, self.a, self.b)
        for _ in range(self.iterations):
            qa = wang_quality(synthesise(gray12, gamma * alpha, response) / 16.0, self.a, self.b)
            qb = wang_quality(synthesise(gray12, gamma * beta, response) / 16.0, self.a, self.b)
            if max(qa, qb) > self.accept_ratio * best:
                if qa >= qb:
                    gamma *= alpha
                    best = qa
                    beta = (1.0 + beta) / 2.0
                else:
                    gamma *= beta
                    best = qb
                    alpha = (1.0 + alpha) / 2.0
            else:
                alpha, beta = (1.0 + alpha) / 2.0, (1.0 + beta) / 2.0
        return gamma

    def next_exposure_us(self, image: np.ndarray, exposure_us: float, meta: dict[str, Any]) -> float:
        check_input(image, exposure_us)
        response = response_of(meta)
        gray12 = work_gray_for(image, self.work_width, meta)
        t_ms = exposure_us / 1000.0
        if saturated_fraction(image, meta) > SATURATION_GUARD:
            self.last_gamma = self.alpha
            return t_ms * (1.0 + self.k * (self.alpha - 1.0)) * 1000.0
        gamma = self.search_gamma(gray12, response)
        self.last_gamma = gamma
        ts_ms = t_ms * (1.0 + self.k * (gamma - 1.0))
        i_s = synthesise(gray12, ts_ms / t_ms, response) / 16.0
        slope12 = log_icrf_slope(response)
        slope8 = 16.0 * slope12[np.arange(256) * 16 + 8]
        d = wang_refinement(i_s, ts_ms, slope8, self.a, self.b)
        return max(ts_ms + self.zeta_ms * d, 1e-6) * 1000.0
