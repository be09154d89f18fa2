"""The authors' Shim metric, Kim's GP fit and Zhang's weights as formulated before the fast paths of ae/upstream.py
and ae/gp.py: one ``upstream_shim_metric`` per gamma on the normalised image, the GP's negative log marginal
likelihood with ``scipy.linalg.cho_factor``/``cho_solve`` minimised by ``scipy.optimize.minimize`` (L-BFGS-B, 11
starts), Zhang's soft-percentile weights on full-size temporaries. The
references that tests/bracketry_emulator/ae/test_ae_upstream_fast_paths.py and benchmarks/bench_upstream_methods.py
compare the fast paths with (bit for bit)."""

from __future__ import annotations

import math

import numpy as np
import scipy.optimize
from scipy.linalg import cho_factor, cho_solve

from bracketry_emulator.ae import gp as GP
from bracketry_emulator.ae import upstream as U


def shim_scores_formula(gray: np.ndarray) -> list[np.float32]:
    """Shim's 7 gamma scores of a uint16 HxW gray image, per pixel as the authors compute them."""
    lo, hi = np.min(gray), np.max(gray)
    img01 = (gray - lo) / (hi - lo)
    return [U.upstream_shim_metric(img01**g) for g in U.SHIM_GAMMAS_UPSTREAM]


def neg_lml_formula(log_theta: np.ndarray, x: np.ndarray, y: np.ndarray, noise: float) -> tuple[float, np.ndarray]:
    """(negative log marginal likelihood, its gradient in log amplitude and log length) of the GP on (x, y)."""
    c, length = np.exp(log_theta)
    d2 = (x[:, None] - x[None, :]) ** 2
    r = np.exp(-0.5 * d2 / length**2)
    k = c * r + noise * np.eye(len(x))
    try:
        cf = cho_factor(k, lower=True)
    except np.linalg.LinAlgError:
        return 1e25, np.zeros(2)
    alpha = cho_solve(cf, y)
    lml = -0.5 * float(y @ alpha) - float(np.sum(np.log(np.diag(cf[0])))) - 0.5 * len(x) * np.log(2 * np.pi)
    inner = np.outer(alpha, alpha) - cho_solve(cf, np.eye(len(x)))
    grad = np.array([0.5 * np.sum(inner * (c * r)), 0.5 * np.sum(inner * (c * r * d2 / length**2))])
    return -lml, -grad


def fit_formula(x: np.ndarray, y: np.ndarray, noise: float, rng: np.random.Generator) -> np.ndarray:
    """The fitted log hyper-parameters: the best of 11 L-BFGS-B starts (zeros, then 10 drawn from ``rng``)."""
    lo, hi = GP.LOG_BOUNDS
    starts = [np.zeros(2)] + [rng.uniform(lo, hi, 2) for _ in range(10)]
    best = None
    for s in starts:
        res = scipy.optimize.minimize(neg_lml_formula, s, args=(x, y, noise), jac=True, method="L-BFGS-B",
                                      bounds=[GP.LOG_BOUNDS, GP.LOG_BOUNDS])
        if best is None or res.fun < best[0]:
            best = (float(res.fun), np.asarray(res.x))
    assert best is not None
    return best[1]


def zhang_raw_weights_formula(n: int, p: float = 0.8, k: int = 5) -> np.ndarray:
    """Zhang's soft-percentile weights before their normalisation (float32 (n,)) as the authors write them."""
    t = math.floor(p * n)
    w = np.zeros(n, dtype=np.float32)
    first = np.arange(0, t)
    w[first] = np.sin((np.pi / (2 * t)) * first) ** k
    w[np.arange(t, n)] = np.sin((np.pi / 2) - (np.pi / (2 * (n - t))) * np.arange(0, n - t)) ** k
    return w


def zhang_weights_formula(n: int, p: float = 0.8, k: int = 5) -> np.ndarray:
    """Zhang's soft-percentile weights (float32 (n,), divided by their L2 norm) as the authors write them.

    The norm is a float32 ``sdot`` of OpenBLAS, whose kernel (and so its summation order) depends on the CPU: for
    1920x1200 it differs by up to ~1.6e-5 relative between CPUs (see ``test_ae_upstream_parity.py``)."""
    w = zhang_raw_weights_formula(n, p, k)
    return w / np.linalg.norm(w)
