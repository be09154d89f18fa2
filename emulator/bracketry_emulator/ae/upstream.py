"""``--parity upstream``: Shim, Kim and Zhang step for step as the benchmark authors' code runs them, quirks included.

Written from the description of norlab-ulaval/BorealHDR (branch TFR2024, ``class_auto_exposure_methods.py``); no
code of theirs is copied. Trace-identical to their ``emulator_threads.py`` (test vectors in
``tests/bracketry_emulator/ae/data/upstream_traces/``, with the command that made them). Classical (ae30/50/70) and
Fix are the same in both modes (:mod:`.classical` is already their rule); Wang and DRL are not in their public code
and have no upstream variant (the default implementations run in both modes).

Every method works on the full-resolution gray image ``cvtColor(mosaic, COLOR_BAYER_RG2GRAY)`` (uint16 12-bit
codes; see :func:`.base.bayer_gray`) and takes and returns exposures in us (the authors: ms).

Quirks reproduced (the default implementations fix them; see their docstrings):

- Shim: gradients are ``cv2.Sobel`` with an UNSIGNED 16-bit output on the [0, 1] float image, so every gradient is
  rounded to an integer and negative ones are clipped to 0 (on an 8 ms frame 98.8 % are 0, the rest 1 or 2): the
  metric only counts a few steep rising edges, and it grows when the image gets darker (gamma > 1 sharpens the
  rare edges that survive the rounding), so their Shim favours darker images. The magnitude is computed in float32
  (``np.sqrt`` of uint16) and the metric is a float32 sum, not normalised by the pixel count.
- Kim: image ``uint8(gray / 16)``; Sobel with an unsigned 16-bit output (negatives clipped) and ``gx**2 + gy**2``
  in uint16 (wraps modulo 65536); weights ``exp(+(H - mean H)^2 / (2 std^2)) / std`` (POSITIVE exponent: the
  rarest entropy values weigh most); GP with zero prior mean on raw metric values (no normalisation), which with
  amplitude bounds of [1e-5, 1e5] against metrics of 400-15,000 keeps the posterior close to its data. The authors'
  scikit-learn GP draws its 10 restarts from the unseeded global generator; ours draws them from a generator
  seeded at ``reset`` (same model, :mod:`.gp`), so a run is reproducible.
- Zhang (the public snapshot's version): Scharr gradients by ``scipy.signal.convolve2d`` (symmetric boundary,
  kernel (3, 10, 3)) in long double; dI/dt = 1 / (h(I) t) with h a smoothing ``UnivariateSpline`` of the first
  differences of their lifted ICRF (so h ~ dE/dI, not d ln E / dI); per-pixel term 2 (Ix Jx + Iy Jy) SORTED BY
  ITSELF (not ranked by gradient magnitude); soft-percentile weights (p = 0.8, k = 5) in float32, divided by their
  L2 norm (not their sum); t_next = t + 1e-6 M (ms), floored at 0.02 ms; outside a gray mean of
  (1120, 3040) DN the classical-50 step. The authors size the weights for 1920x1200 images only; here for any size.
  Computed ~25x faster than their code with the same values bit for bit: h per 12-bit code (a table), the float64
  gradients summed in scipy's order, the long-double terms sorted by a most-significant-digit radix sort whose
  buckets are sorted in the caches as the sum reaches them, and summed with their weights in numpy's pairwise order
  (the compiled ``_zhang_terms``, ``_zhang_terms.c``; numpy does the same where it was not built or with
  ``BRACKETRY_NO_CKERNEL=1``).
- Speed of Shim and Kim (same results): Shim's per-pixel values are per-code tables and its gradients, bucketed
  and summed by the compiled ``_upstream_kernels`` (``_upstream_kernels.c``), bit for bit; Kim's metric from
  per-8-bit-value sums (float64 rounding), its GP fit (:mod:`.gp`) bit for bit with direct LAPACK / L-BFGS-B calls.
"""

from __future__ import annotations

import math
from typing import Any

import cv2
import numpy as np

from ..extensions import optional_extension
from .base import check_input, gray_for
from .classical import classical_step_ms
from .gp import GaussianProcess1D

SHIM_GAMMAS_UPSTREAM = np.array([1 / 1.9, 1 / 1.5, 1 / 1.2, 1.0, 1.2, 1.5, 1.9])


def upstream_shim_metric(img01: np.ndarray, delta: float = 0.06, lam: float = 1e3) -> np.float32:
    """The authors' Shim gradient information of a [0, 1] float64 image (HxW): CV_16U Sobel, float32 sum."""
    n = np.log10(lam * (1 - delta) + 1)
    gx = cv2.Sobel(img01, ddepth=cv2.CV_16U, dx=1, dy=0, ksize=3)
    gy = cv2.Sobel(img01, ddepth=cv2.CV_16U, dx=0, dy=1, ksize=3)
    mag = np.sqrt(gx**2 + gy**2)  # uint16 squares, float32 root
    with np.errstate(divide="ignore", invalid="ignore"):
        m = (mag - np.min(mag)) / (np.max(mag) - np.min(mag))
    out = np.zeros_like(m)
    sel = m >= delta
    out[sel] = (1 / n) * np.log10(lam * (m[sel] - delta) + 1)
    return np.sum(out)


def _shim_values(m2_min: int, m2_max: int, delta: float, lam: float) -> np.ndarray:
    """float32 (256,): the authors' per-pixel Shim term for every bucket ``gx * 6 + gy`` (gx, gy in 0..4) of an
    image whose gx^2 + gy^2 spans [m2_min, m2_max], by their operations (float32 magnitude, min-max normalisation,
    float64 log, float32 store)."""
    n = np.log10(lam * (1 - delta) + 1)
    b = np.arange(256)
    mag = np.sqrt(((b // 6) ** 2 + (b % 6) ** 2).astype(np.uint16))  # uint16 squares, float32 root
    lo, hi = np.sqrt(np.array([m2_min, m2_max], dtype=np.uint16))
    with np.errstate(divide="ignore", invalid="ignore"):
        m = (mag - lo) / (hi - lo)
    out = np.zeros_like(m)
    sel = m >= delta
    out[sel] = (1 / n) * np.log10(lam * (m[sel] - delta) + 1)
    return out


#: the sparse path of :func:`upstream_shim_scores` runs when at most this fraction of the pixels are candidates
SHIM_SPARSE_MAX_FRACTION = 0.25

#: a difference of table values below this cannot make a Shim gradient round above 0 (1/8: the four weights of a
#: gradient add to 4 and it must exceed 0.5; the margin covers the rounding of the differences and sums)
_SHIM_MIN_STEP = 0.125 - 1e-6


def _shim_partner_codes(tables: list[np.ndarray]) -> np.ndarray:
    """int32 (codes,): for each code b the smallest code a whose value can exceed b's by :data:`_SHIM_MIN_STEP`
    in any of the tables (float64 (codes,) each; len(tables[0]) when none can), from their running maxima (so a
    table that is not exactly monotone is still bounded)."""
    partner = np.full(len(tables[0]), len(tables[0]), dtype=np.int64)
    for table in tables:
        rising = np.maximum.accumulate(table)
        partner = np.minimum(partner, np.searchsorted(rising, table + _SHIM_MIN_STEP, side="left"))
    return partner.astype(np.int32)


def upstream_shim_scores(gray: np.ndarray, gammas: np.ndarray = SHIM_GAMMAS_UPSTREAM, delta: float = 0.06,
                         lam: float = 1e3) -> list[np.float32]:
    """:func:`upstream_shim_metric` of ``((gray - min) / (max - min)) ** gamma`` for each gamma (a gray image,
    HxW), bit for bit.

    The image holds integer codes, so every per-pixel value before the gradients (normalisation, power) is a
    function of the code: a table per gamma. The compiled kernel (``_upstream_kernels.c``) computes the authors'
    CV_16U Sobel gradients of the gathered table with OpenCV's float64 operations in OpenCV's order (so the same
    rounded integers, 0..4), stores each pixel's (gx, gy) pair as one byte, and sums the per-pair float32 terms in
    numpy's pairwise order; ~6x faster. Most gradients round to 0: a pixel can have a non-zero one only if a
    difference of table values around it reaches 1/8, which the codes tell for every gamma at once
    (:func:`_shim_partner_codes`); where at most :data:`SHIM_SPARSE_MAX_FRACTION` of the pixels can (3-10 % on the
    frames here), only those are computed, with the same operations (~2.5x faster again). Where the kernel was not
    built (or ``BRACKETRY_NO_CKERNEL=1``), for non-integer or flat images and in the unexpected case of a gradient
    above 4, the authors' formula runs as written.
    """
    lo, hi = np.min(gray), np.max(gray)
    kernels = _upstream_kernels()
    fast = (kernels is not None and gray.dtype == np.uint16 and gray.ndim == 2 and min(gray.shape) >= 2
            and hi > lo)
    img01: np.ndarray | None = None
    scores: list[np.float32] = []
    count = -1  # candidates of the sparse path (-1: every pixel, shim_buckets)
    if fast:
        codes = np.maximum(np.arange(int(hi) + 1, dtype=gray.dtype), lo)
        t01 = (codes - lo) / (hi - lo)  # = (gray - lo) / (hi - lo) per code
        tables = [np.ascontiguousarray(t01**gamma) for gamma in gammas]
        g = np.ascontiguousarray(gray)
        idx = np.empty(g.size, dtype=np.int32)
        count = kernels.shim_candidates(g, _shim_partner_codes(tables), g.shape[0], g.shape[1], idx)
        if count > SHIM_SPARSE_MAX_FRACTION * g.size:
            count = -1
        buckets = np.zeros(g.shape, dtype=np.uint8) if count >= 0 else np.empty(g.shape, dtype=np.uint8)
    for k, gamma in enumerate(gammas):
        if fast:
            if count >= 0:
                status, m2_min, m2_max = kernels.shim_sparse(g, tables[k], g.shape[0], g.shape[1], idx, count,
                                                             buckets)
            else:
                status, m2_min, m2_max = kernels.shim_buckets(g, tables[k], g.shape[0], g.shape[1], buckets)
            if status == 0:
                scores.append(np.float32(kernels.shim_sum(buckets, _shim_values(m2_min, m2_max, delta, lam))))
                continue
        if img01 is None:
            img01 = (gray - lo) / (hi - lo)
        scores.append(upstream_shim_metric(img01**gamma, delta, lam))
    return scores


class UpstreamShimAE:
    """Shim as the authors' code runs it (see the module docstring; id ``shim`` with ``--parity upstream``)."""

    #: relative cost of one step, for balancing worker processes (see registry.MethodTraits): ~ms of CPU per
    #: 1920x1200 step here (~19 with the sparse gradients on the frames here, ~42 where every pixel is computed)
    step_cost = 20

    def __init__(self, delta: float = 0.06, lam: float = 1e3, kp: float = 0.2, name: str = "shim") -> None:
        self.delta, self.lam, self.kp = delta, lam, kp
        self.name = name
        self.last_gamma: float | None = None

    def reset(self, init_exposure_us: float) -> None:
        self.last_gamma = None

    def next_exposure_us(self, image: np.ndarray, exposure_us: float, meta: dict[str, Any]) -> float:
        check_input(image, exposure_us)
        scores = upstream_shim_scores(gray_for(image, meta), SHIM_GAMMAS_UPSTREAM, self.delta, self.lam)
        coeffs = np.polyfit(SHIM_GAMMAS_UPSTREAM, scores, deg=5)
        grid = np.linspace(np.min(SHIM_GAMMAS_UPSTREAM), np.max(SHIM_GAMMAS_UPSTREAM), 100)
        gamma = float(grid[np.argmax(np.poly1d(coeffs)(grid))])
        self.last_gamma = gamma
        a = 0.5 if gamma >= 1 else 1.0
        return (1 + a * self.kp * (1 - gamma)) * (exposure_us / 1000.0) * 1000.0


def upstream_kim_metric(gray12: np.ndarray, alpha: float = 16.0, tau: float = 4.0, mask_below: float = 0.6
                        ) -> float:
    """The authors' Kim metric of a 12-bit gray image (uint16 HxW), quirks included (module docstring).

    Every per-pixel quantity but the gradient is a function of the pixel's 8-bit value v, and the gradient enters
    only through ``w(v) g``, so the metric is ``sum over v of w(v) G(v) + rest(v) N(v)`` with N(v) the pixel count
    and G(v) the sum of the authors' wrapped uint16 ``gx^2 + gy^2`` over the pixels of value v (exact integers, one
    pass of the compiled ``_upstream_kernels``); the reductions (mean, std, weight sum) are taken over the 256
    values weighted by N. The same value as the per-pixel formula up to float64 rounding (relative ~1e-15; the
    authors' own sums round differently), ~8x faster. Where the kernel was not built, for non-12-bit input or when
    a weight is not finite, :func:`upstream_kim_metric_exact` (per pixel, bit for bit the authors') runs instead.
    """
    kernels = _upstream_kernels()
    if kernels is not None and gray12.dtype == np.uint16 and gray12.ndim == 2 and min(gray12.shape) >= 2:
        counts = np.empty(256, dtype=np.int64)
        gsum = np.empty(256, dtype=np.int64)
        g = np.ascontiguousarray(gray12)
        if kernels.kim_code_sums(g, g.shape[0], g.shape[1], counts, gsum) == 0:
            value = _kim_metric_from_code_sums(counts, gsum, alpha, tau, mask_below)
            if value is not None:
                return value
    return upstream_kim_metric_exact(gray12, alpha, tau, mask_below)


def _kim_metric_from_code_sums(counts: np.ndarray, gsum: np.ndarray, alpha: float, tau: float, mask_below: float
                               ) -> float | None:
    """The authors' Kim metric from the pixel count and the summed squared gradient of each 8-bit value (int64
    (256,) each); None when a weight or the result is not finite (the per-pixel formula decides then)."""
    n = int(counts.sum())
    present = counts > 0
    p = counts / n
    c = counts[present].astype(np.float64)
    with np.errstate(divide="ignore", invalid="ignore", over="ignore"):
        h = -p[present] * np.log2(p[present])
        mean = float(np.sum(c * h)) / n
        sigma = np.sqrt(float(np.sum(c * (h - mean) ** 2)) / n)
        w = (1 / sigma) * np.exp(((h - mean) ** 2) / (2 * sigma**2))
        w = w / np.sum(c * w)
        h_min, h_max = np.min(h), np.max(h)
        hn = (h - h_min) / (h_max - h_min)
        act = (2 / (1 + np.exp(-alpha * hn + tau))) - 1
        mask = (hn < mask_below).astype(np.float64)
        rest = act * mask * w * (1 / n) * int(gsum.sum())
        value = float(np.sum(w * gsum[present]) + np.sum(rest * c))
    if not (sigma > 0 and np.all(np.isfinite(w)) and np.isfinite(value)):
        return None
    return value


def upstream_kim_metric_exact(gray12: np.ndarray, alpha: float = 16.0, tau: float = 4.0, mask_below: float = 0.6
                              ) -> float:
    """The authors' Kim metric bit for bit (their per-pixel reductions) of a gray image (uint16 HxW).

    Every per-pixel quantity but the gradient is a function of the pixel's 8-bit value, so it is computed once per
    value (a 256-entry table, the same operations on the same numbers) and gathered; the reductions (std, mean,
    sums) run on the gathered full-size arrays as the authors' do, so the result is theirs bit for bit, ~3x faster
    than their formula.
    """
    if gray12.size == 0 or int(gray12.max(initial=0)) > 4095:
        return _upstream_kim_metric_direct(gray12, alpha, tau, mask_below)
    img = (gray12 >> 4).astype(np.uint8)  # = uint8(gray / 16.0) for 12-bit codes
    flat = img.ravel()
    hist = np.bincount(flat, minlength=256)
    p = hist / hist.sum()
    present = hist > 0
    with np.errstate(divide="ignore", invalid="ignore"):
        h_of = -p * np.log2(p)
    h = h_of[flat]
    gx = cv2.Sobel(img, ddepth=cv2.CV_16U, dx=1, dy=0, ksize=3).ravel()
    gy = cv2.Sobel(img, ddepth=cv2.CV_16U, dx=0, dy=1, ksize=3).ravel()
    g = gx**2 + gy**2  # uint16: wraps
    sigma = np.std(h)
    with np.errstate(divide="ignore", over="ignore", invalid="ignore"):
        w_of = (1 / sigma) * np.exp(((h_of - np.mean(h)) ** 2) / (2 * sigma**2))
    w_of = w_of / np.sum(w_of[flat])
    h_min, h_max = np.min(h_of[present]), np.max(h_of[present])
    with np.errstate(divide="ignore", invalid="ignore", over="ignore"):
        hn_of = (h_of - h_min) / (h_max - h_min)
        act_of = (2 / (1 + np.exp(-alpha * hn_of + tau))) - 1
    mask_of = np.zeros_like(hn_of)
    mask_of[hn_of < mask_below] = 1
    n = g.shape[0]
    rest_of = act_of * mask_of * w_of * (1 / n) * np.sum(g)
    return float(np.sum((w_of[flat] * g) + rest_of[flat]))


def _upstream_kim_metric_direct(gray12: np.ndarray, alpha: float, tau: float, mask_below: float) -> float:
    """:func:`upstream_kim_metric` computed per pixel, as the authors write it (any input)."""
    img = (gray12 / 16.0).astype(np.uint8)
    flat = img.ravel()
    hist = np.bincount(flat, minlength=256)
    p = hist / hist.sum()
    h = -p[flat] * np.log2(p[flat])
    gx = cv2.Sobel(img, ddepth=cv2.CV_16U, dx=1, dy=0, ksize=3).ravel()
    gy = cv2.Sobel(img, ddepth=cv2.CV_16U, dx=0, dy=1, ksize=3).ravel()
    g = gx**2 + gy**2  # uint16: wraps
    sigma = np.std(h)
    w = (1 / sigma) * np.exp(((h - np.mean(h)) ** 2) / (2 * sigma**2))
    w = w / np.sum(w)
    hn = (h - np.min(h)) / (np.max(h) - np.min(h))
    act = (2 / (1 + np.exp(-alpha * hn + tau))) - 1
    mask = np.zeros_like(hn)
    mask[hn < mask_below] = 1
    n = g.shape[0]
    return float(np.sum((w * g) + act * mask * w * (1 / n) * np.sum(g)))


class UpstreamKimAE:
    """Kim as the authors' code runs it (module docstring; id ``kim`` with ``--parity upstream``).

    Control: newest-first window of at most 5 (exposure ms, metric) pairs, GP constant * RBF (noise 0.2, 10
    restarts), GP-MI on linspace(0.5, 35, 50) ms with eta from 1, converged when sigma(x) <= 5 (then the argmax of
    the GP mean on linspace(0.5, 35, 1000)). Output always in [0.5, 35] ms.
    """

    #: relative cost of one step, for balancing worker processes (see registry.MethodTraits): ~ms of CPU per
    #: 1920x1200 step here (metric ~8, GP fit ~3; scipy's import, ~0.3 s of CPU on the first step, is its start_up)
    step_cost = 15
    #: the GP fit imports scipy (see registry.MethodTraits): shared with the other methods that do on one worker
    start_up = "scipy"

    def __init__(self, seed: int = 0, name: str = "kim") -> None:
        self.seed = seed
        self.name = name
        self.candidates_ms = np.linspace(0.5, 35, 50)
        self.fine_ms = np.linspace(0.5, 35, 1000)
        self.reset(0.0)

    def reset(self, init_exposure_us: float) -> None:
        self._rng = np.random.default_rng(self.seed)
        self._t: list[float] = []
        self._m: list[float] = []
        self._eta = 1.0
        self.converged = False

    def next_exposure_us(self, image: np.ndarray, exposure_us: float, meta: dict[str, Any]) -> float:
        check_input(image, exposure_us)
        self._t.insert(0, exposure_us / 1000.0)
        self._m.insert(0, upstream_kim_metric(gray_for(image, meta)))
        gp = GaussianProcess1D(0.2, 10, self._rng).fit(np.array(self._t), np.array(self._m))
        mu, sd = gp.predict(self.candidates_ms)
        phi = math.sqrt(math.log(2 / 0.25)) * (np.sqrt(sd**2 + self._eta) - np.sqrt(self._eta))
        i = int(np.argmax(mu + phi))
        self._eta += float(sd[i] ** 2)
        if len(self._t) == 5:  # the window drops its oldest point after a step with 5 points
            self._t.pop()
            self._m.pop()
        self.converged = bool(sd[i] <= 5)
        if self.converged:
            fine, _ = gp.predict(self.fine_ms)
            return float(self.fine_ms[int(np.argmax(fine))]) * 1000.0
        return float(self.candidates_ms[i]) * 1000.0


def upstream_zhang_weights(n: int, p: float = 0.8, k: int = 5) -> np.ndarray:
    """The authors' soft-percentile weights (float32 (n,), divided by their L2 norm), bit for bit their formula
    ``w[i] = sin(pi / (2 t) * i) ** k`` for ranks i < t = floor(p n), ``sin(pi / 2 - pi / (2 (n - t)) * (i - t)) ** k``
    above: the same elementwise float64 operations (product, sine, power) on pieces of ``chunk`` ranks that stay in
    the caches, without the formula's full-size temporaries (~1.5x faster)."""
    t = math.floor(p * n)
    a = np.pi / (2 * t)  # ZeroDivisionError for n = 1, as the formula
    b = np.pi / (2 * (n - t))
    chunk = 1 << 15
    w = np.empty(n, dtype=np.float32)
    buf = np.empty(min(chunk, n), dtype=np.float64)
    for start, count, scale, offset in ((0, t, a, None), (t, n - t, b, np.pi / 2)):
        for c0 in range(0, count, chunk):
            x = buf[:min(chunk, count - c0)]
            np.multiply(scale, np.arange(c0, c0 + x.size), out=x)  # (pi / (2 t)) * rank, as float64
            if offset is not None:
                np.subtract(offset, x, out=x)
            np.sin(x, out=x)
            np.power(x, k, out=x)
            w[start + c0:start + c0 + x.size] = x
    return w / np.linalg.norm(w)


def scharr_symm(image: np.ndarray, kernel: np.ndarray) -> np.ndarray:
    """``scipy.signal.convolve2d(image, kernel, boundary="symm", mode="same")`` of a float64 HxW image and a 3x3
    kernel, bit for bit: scipy accumulates, per pixel, the products of the kernel taken row by row (zeros add
    nothing) in float64, in that order; this does the same over whole shifted views. -> float64 HxW."""
    h, w = image.shape
    padded = np.pad(image, 1, mode="symmetric")
    out = np.zeros((h, w), dtype=np.float64)
    tmp = np.empty((h, w), dtype=np.float64)
    for r in range(3):
        for c in range(3):
            k = float(kernel[r, c])
            if k != 0.0:
                np.multiply(padded[2 - r:2 - r + h, 2 - c:2 - c + w], k, out=tmp)
                out += tmp
    return out


def scharr_integer(gray: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The Scharr gradients (x, y) of an integer image of codes below 2^16, symmetric boundary, as float32 HxW:
    integers below 2^24 at every partial sum, so exact in any order (= ``convolve2d`` of the authors)."""
    img = gray.astype(np.float32)
    kx = np.array([[-3, 0, 3], [-10, 0, 10], [-3, 0, 3]], dtype=np.float32)  # correlation = flipped convolution
    gx = cv2.filter2D(img, cv2.CV_32F, kx, borderType=cv2.BORDER_REFLECT)
    gy = cv2.filter2D(img, cv2.CV_32F, np.ascontiguousarray(kx.T), borderType=cv2.BORDER_REFLECT)
    return gx, gy


def sort_longdouble(values: np.ndarray) -> np.ndarray:
    """``np.sort`` of a flat long-double array, faster: an argsort of the float64 roundings (vectorised), then the
    rare runs of equal roundings whose long doubles are out of order sorted on their own. The sorted values are
    unique, so the result is identical to ``np.sort(values)``."""
    hi = values.astype(np.float64)
    order = np.argsort(hi)
    out = values[order]
    bad = np.flatnonzero(out[1:] < out[:-1])
    if bad.size:
        hs = hi[order]
        done = -1
        for i in bad:
            if i < done:
                continue
            a = int(np.searchsorted(hs, hs[i], "left"))
            b = int(np.searchsorted(hs, hs[i], "right"))
            out[a:b] = np.sort(out[a:b])
            done = b
    return out


def _zhang_kernel() -> Any:
    """The compiled ``_zhang_terms`` extension (``_zhang_terms.c``, built with the package), or None when it was not
    built or ``BRACKETRY_NO_CKERNEL=1`` (then numpy computes the same values; :mod:`..extensions`)."""
    return optional_extension(f"{__package__}._zhang_terms")


def _upstream_kernels() -> Any:
    """The compiled ``_upstream_kernels`` extension (``_upstream_kernels.c``, built with the package), or None when it
    was not built or ``BRACKETRY_NO_CKERNEL=1`` (then numpy computes the same values; :mod:`..extensions`)."""
    return optional_extension(f"{__package__}._upstream_kernels")


class UpstreamZhangAE:
    """Zhang as the authors' public code runs it (module docstring; id ``zhang`` with ``--parity upstream``).

    The ICRF is the emulator's upstream response (``meta["response"]``, their lifting of pcalib_inside1, which is
    what their Zhang loads); another response is used through its per-code table.
    """

    #: relative cost of one step, for balancing worker processes (see registry.MethodTraits): ~ms of CPU per
    #: 1920x1200 step here (~42 on the gradient branch, ~1 on the classical one; scipy's import for the spline, ~0.3
    #: s of CPU on the first step, is its start_up)
    step_cost = 45
    #: the spline imports scipy (see registry.MethodTraits): shared with the other methods that do on one worker
    start_up = "scipy"

    _SCHARR_X = np.array([[3, 0, -3], [10, 0, -10], [3, 0, -3]], dtype=np.float64)
    _SCHARR_Y = np.array([[3, 10, 3], [0, 0, 0], [-3, -10, -3]], dtype=np.float64)

    def __init__(self, name: str = "zhang") -> None:
        self.name = name
        self._weights: dict[int, np.ndarray] = {}
        self._spline: dict[int, Any] = {}
        self._tables: dict[int, np.ndarray] = {}

    def reset(self, init_exposure_us: float) -> None:
        """Stateless between steps."""

    def _icrf_slope(self, meta: dict[str, Any]) -> Any:
        from scipy.interpolate import UnivariateSpline

        resp = meta.get("response")
        key = id(resp)
        spline = self._spline.get(key)
        if spline is None:
            fn = getattr(resp, "_icrf_fn", None)
            x = np.linspace(0, 4095, 4097)
            if fn is not None:
                e = np.asarray(fn(x), dtype=np.float64)
            else:
                icrf = np.asarray(resp.icrf if resp is not None else np.arange(4096.0), dtype=np.float64)
                e = np.interp(x, np.arange(len(icrf), dtype=np.float64), icrf)
            spline = self._spline[key] = UnivariateSpline(np.linspace(0, 4095, 4096), np.diff(e))
        return spline

    def _slope_table(self, meta: dict[str, Any]) -> np.ndarray:
        """float64 (4096,): the smoothing spline h at every 12-bit code (a spline evaluates each point on its own, so
        ``table[gray]`` is bit for bit ``spline(gray)``)."""
        key = id(meta.get("response"))
        table = self._tables.get(key)
        if table is None:
            table = self._tables[key] = np.asarray(self._icrf_slope(meta)(np.arange(4096.0)), dtype=np.float64)
        return table

    def _terms(self, gray: np.ndarray, t_ms: float, meta: dict[str, Any]) -> np.ndarray:
        """The per-pixel terms 2 (Ix Jx + Iy Jy) as long doubles (flat, unsorted), bit for bit the authors'."""
        if int(gray.max(initial=0)) <= 4095:
            j = (1.0 / (self._slope_table(meta) * t_ms))[gray]  # per code, the same operations as per pixel
        else:
            j = 1.0 / (self._icrf_slope(meta)(gray) * t_ms)
        ix, iy = scharr_integer(gray)
        jx, jy = scharr_symm(j, self._SCHARR_X), scharr_symm(j, self._SCHARR_Y)
        ld = np.longdouble
        prod = np.multiply(ix, jx, dtype=ld)
        prod += np.multiply(iy, jy, dtype=ld)
        prod *= 2
        return prod.ravel()

    def sorted_terms(self, gray: np.ndarray, t_ms: float, meta: dict[str, Any]) -> np.ndarray:
        """The terms sorted ascending (long double (H*W,)): the compiled kernel ``_zhang_terms`` when it was built
        (the same values, ~10x faster), else numpy (:meth:`_terms` and :func:`sort_longdouble`)."""
        kernel = _zhang_kernel()
        if kernel is None or gray.ndim != 2 or int(gray.max(initial=0)) > 4095:
            return sort_longdouble(self._terms(gray, t_ms, meta))
        g, jlut = self._kernel_inputs(gray, t_ms, meta)
        out = np.empty(g.size, dtype=np.longdouble)
        kernel.sorted_terms(g, jlut, g.shape[0], g.shape[1], out)
        return out

    def _kernel_inputs(self, gray: np.ndarray, t_ms: float, meta: dict[str, Any]) -> tuple[np.ndarray, np.ndarray]:
        jlut = np.zeros(65536, dtype=np.float64)
        jlut[:4096] = 1.0 / (self._slope_table(meta) * t_ms)
        return np.ascontiguousarray(gray, dtype=np.uint16), jlut

    def weighted_sum(self, gray: np.ndarray, t_ms: float, meta: dict[str, Any]) -> np.longdouble:
        """``np.sum(w * sorted_terms)`` with the soft-percentile weights w (float32) in long double, bit for bit:
        the compiled kernel sums the products in numpy's pairwise order without writing the terms out (where it was
        built), else numpy."""
        w = self._weights.get(gray.size)
        if w is None:
            w = self._weights[gray.size] = upstream_zhang_weights(gray.size)
        kernel = _zhang_kernel()
        if kernel is None or gray.ndim != 2 or int(gray.max(initial=0)) > 4095:
            return np.sum(w * self.sorted_terms(gray, t_ms, meta))
        g, jlut = self._kernel_inputs(gray, t_ms, meta)
        out = np.empty(1, dtype=np.longdouble)
        kernel.weighted_sum(g, jlut, g.shape[0], g.shape[1], w, out)
        return out[0]

    def next_exposure_us(self, image: np.ndarray, exposure_us: float, meta: dict[str, Any]) -> float:
        check_input(image, exposure_us)
        gray = gray_for(image, meta)
        t_ms = exposure_us / 1000.0
        mean = np.mean(gray)
        if mean <= (70 / 256) * 4096 or mean >= (190 / 256) * 4096:
            nxt = classical_step_ms(float(mean), t_ms, 50.0)
        else:
            nxt = float(t_ms + 1e-6 * self.weighted_sum(gray, t_ms, meta))
        return max(nxt, 0.02) * 1000.0
