"""Kim: entropy-weighted gradient metric maximised by Bayesian optimisation (id kim).

Papers: J. Kim, Y. Cho, A. Kim, "Exposure control using Bayesian optimization based on entropy weighted image
gradient", ICRA 2018; "Proactive camera attribute control using Bayesian optimization for illumination-resilient
visual navigation", T-RO 2020. Not open source for the benchmark authors, who implemented it from the paper; we follow
their implementation (constants below) except where noted.

Metric (on I = uint8(gray / 16)):
- per-pixel entropy term H_i = -p(v_i) log2 p(v_i), p = 256-bin histogram probability of the pixel's value;
- G = gx^2 + gy^2 (3x3 Sobel); weights w = exp(-(H - mean H)^2 / (2 std(H)^2)), normalised to sum 1;
- Hn = min-max normalised H; activation pi = 2 / (1 + exp(-alpha Hn + tau)) - 1 with alpha = 16, tau = 4;
  saturation mask S = [Hn < 0.6];
- metric = sum w G + sum pi S w * mean(G).

Control (the authors'): a sliding window of the newest 5 (exposure, metric) pairs; a GP (constant * RBF, noise 0.2,
10 restarts) on exposure in ms; 50 candidates linspace(0.5, 35, 50) ms; GP-MI acquisition
x = argmax(mu + sqrt(ln 8) (sqrt(sigma^2 + eta) - sqrt(eta))), eta starts at 1 and accumulates sigma^2(x); when
sigma(x) <= 5 the search has converged and the method returns the argmax of the GP mean on linspace(0.5, 35, 1000).

Deliberate deviations:
- Quirk FIXED: the authors' weights use exp(+(H - mean)^2 / (2 sigma^2)) (positive exponent), the opposite of the
  paper's Gaussian; we use the paper's sign.
- Quirk FIXED: their Sobel has an unsigned 16-bit output (negative gradients clipped to 0) and the square overflows
  in uint16; we use float gradients.
- Quirk FIXED: their GP (scikit-learn, unseeded restarts) is not deterministic; ours (:mod:`.gp`, same model) draws
  its restarts from a generator seeded by ``seed`` at ``reset``.
- Reproduced: the per-pixel entropy term from the global histogram (the paper uses a local-window entropy).
- Speed: gray area-downscaled to ``work_width`` = 480 columns (Kim's T-RO paper itself works on 94x60 images).
"""

from __future__ import annotations

from typing import Any

import cv2
import numpy as np

from .base import check_input, work_gray_for
from .gp import GaussianProcess1D


def kim_metric(gray8: np.ndarray, alpha: float = 16.0, tau: float = 4.0, mask_below: float = 0.6) -> float:
    """Entropy-weighted gradient metric of an 8-bit-scale gray image (HxW, values 0..255, any numeric dtype)."""
    img = np.asarray(gray8)
    codes = np.clip(img, 0, 255).astype(np.uint8)
    hist = np.bincount(codes.ravel(), minlength=256).astype(np.float64)
    p = hist / hist.sum()
    with np.errstate(divide="ignore", invalid="ignore"):
        ent_of_code = np.where(p > 0, -p * np.log2(p), 0.0)
    h = ent_of_code[codes]
    f = img.astype(np.float32)
    gx = cv2.Sobel(f, cv2.CV_32F, 1, 0, ksize=3).astype(np.float64)
    gy = cv2.Sobel(f, cv2.CV_32F, 0, 1, ksize=3).astype(np.float64)
    g = gx * gx + gy * gy
    mu, sigma = float(h.mean()), float(h.std())
    w = np.exp(-((h - mu) ** 2) / (2 * sigma**2)) if sigma > 0 else np.ones_like(h)
    w /= w.sum()
    hmin, hmax = float(h.min()), float(h.max())
    hn = (h - hmin) / (hmax - hmin) if hmax > hmin else np.zeros_like(h)
    act = 2.0 / (1.0 + np.exp(-alpha * hn + tau)) - 1.0
    mask = hn < mask_below
    return float(np.sum(w * g) + np.sum(act * mask * w) * float(g.mean()))


class KimAE:
    """Kim's entropy-weighted gradient + GP Bayesian optimisation (see the module docstring)."""

    #: relative cost of one step, for balancing worker processes (see registry.MethodTraits)
    step_cost = 40
    #: the GP fit imports scipy (see registry.MethodTraits): shared with the other methods that do on one worker
    start_up = "scipy"

    def __init__(self, window: int = 5, min_ms: float = 0.5, max_ms: float = 35.0, n_candidates: int = 50,
                 noise_var: float = 0.2, n_restarts: int = 10, sigma_converged: float = 5.0, seed: int = 0,
                 work_width: int = 480, name: str = "kim") -> None:
        self.window = window
        self.candidates_ms = np.linspace(min_ms, max_ms, n_candidates)
        self.fine_ms = np.linspace(min_ms, max_ms, 1000)
        self.noise_var = noise_var
        self.n_restarts = n_restarts
        self.sigma_converged = sigma_converged
        self.seed = seed
        self.work_width = work_width
        self.name = name
        self.reset(0.0)

    def reset(self, init_exposure_us: float) -> None:
        self._rng = np.random.default_rng(self.seed)
        self._points: list[tuple[float, float]] = []  # newest first: (t_ms, metric)
        self._eta = 1.0
        self.converged = False

    def metric(self, image: np.ndarray, meta: dict[str, Any] | None = None) -> float:
        """Kim's metric of an emulated mosaic (uint16 HxW 12-bit)."""
        return kim_metric(work_gray_for(image, self.work_width, meta) / 16.0)

    def next_exposure_us(self, image: np.ndarray, exposure_us: float, meta: dict[str, Any]) -> float:
        check_input(image, exposure_us)
        self._points.insert(0, (exposure_us / 1000.0, self.metric(image, meta)))
        del self._points[self.window:]
        x = np.array([p[0] for p in self._points])
        y = np.array([p[1] for p in self._points])
        gp = GaussianProcess1D(self.noise_var, self.n_restarts, self._rng).fit(x, y)
        mu, sd = gp.predict(self.candidates_ms)
        phi = np.sqrt(np.log(8.0)) * (np.sqrt(sd**2 + self._eta) - np.sqrt(self._eta))
        i = int(np.argmax(mu + phi))
        self._eta += float(sd[i] ** 2)
        if sd[i] <= self.sigma_converged:
            self.converged = True
            mu_fine, _ = gp.predict(self.fine_ms)
            return float(self.fine_ms[int(np.argmax(mu_fine))]) * 1000.0
        self.converged = False
        return float(self.candidates_ms[i]) * 1000.0
