"""A small Gaussian-process regressor (1-D input), deterministic: constant * RBF kernel plus a fixed noise term.

Equivalent in model to scikit-learn's ``GaussianProcessRegressor(kernel=ConstantKernel(1.0) * RBF(1.0),
alpha=noise_var, n_restarts_optimizer=n_restarts)`` that the benchmark authors use for Kim (zero prior mean, no
target normalisation, hyper-parameters by maximum log marginal likelihood with L-BFGS-B in log space, bounds
[1e-5, 1e5] for both), but the restarts are drawn from a seeded generator so runs are reproducible.
"""

from __future__ import annotations

import numpy as np
from scipy.linalg import cho_factor, cho_solve
from scipy.optimize import minimize

LOG_BOUNDS = (np.log(1e-5), np.log(1e5))


class GaussianProcess1D:
    """GP regression on scalars: ``fit(x, y)`` then ``predict(x) -> (mean, std)`` (float64 arrays)."""

    def __init__(self, noise_var: float = 0.2, n_restarts: int = 10, rng: np.random.Generator | None = None) -> None:
        self.noise_var = noise_var
        self.n_restarts = n_restarts
        self.rng = rng if rng is not None else np.random.default_rng(0)
        self.log_theta = np.zeros(2)  # log amplitude c, log length scale l
        self._x = np.zeros(0)
        self._alpha = np.zeros(0)
        self._chol: tuple[np.ndarray, bool] | None = None

    @staticmethod
    def _kernel(xa: np.ndarray, xb: np.ndarray, log_theta: np.ndarray) -> np.ndarray:
        c, length = np.exp(log_theta)
        d2 = (xa[:, None] - xb[None, :]) ** 2
        return c * np.exp(-0.5 * d2 / length**2)

    def _neg_lml(self, log_theta: np.ndarray, x: np.ndarray, y: np.ndarray) -> tuple[float, np.ndarray]:
        c, length = np.exp(log_theta)
        d2 = (x[:, None] - x[None, :]) ** 2
        r = np.exp(-0.5 * d2 / length**2)
        k = c * r + self.noise_var * np.eye(len(x))
        try:
            cf = cho_factor(k, lower=True)
        except np.linalg.LinAlgError:
            return 1e25, np.zeros(2)
        alpha = cho_solve(cf, y)
        lml = -0.5 * float(y @ alpha) - float(np.sum(np.log(np.diag(cf[0])))) - 0.5 * len(x) * np.log(2 * np.pi)
        inner = np.outer(alpha, alpha) - cho_solve(cf, np.eye(len(x)))
        dk_dlogc = c * r
        dk_dlogl = c * r * d2 / length**2
        grad = np.array([0.5 * np.sum(inner * dk_dlogc), 0.5 * np.sum(inner * dk_dlogl)])
        return -lml, -grad

    def fit(self, x: np.ndarray, y: np.ndarray) -> GaussianProcess1D:
        """Fit hyper-parameters (max log marginal likelihood, seeded restarts) and the posterior."""
        x = np.asarray(x, dtype=np.float64).ravel()
        y = np.asarray(y, dtype=np.float64).ravel()
        bounds = [LOG_BOUNDS, LOG_BOUNDS]
        starts = [np.zeros(2)] + [self.rng.uniform(LOG_BOUNDS[0], LOG_BOUNDS[1], 2) for _ in range(self.n_restarts)]
        best: tuple[float, np.ndarray] | None = None
        for s in starts:
            res = minimize(self._neg_lml, s, args=(x, y), jac=True, method="L-BFGS-B", bounds=bounds)
            if best is None or res.fun < best[0]:
                best = (float(res.fun), np.asarray(res.x))
        assert best is not None
        self.log_theta = best[1]
        k = self._kernel(x, x, self.log_theta) + self.noise_var * np.eye(len(x))
        self._chol = cho_factor(k, lower=True)
        self._alpha = cho_solve(self._chol, y)
        self._x = x
        return self

    def predict(self, xq: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Posterior mean and standard deviation at ``xq`` (float64, same length)."""
        xq = np.asarray(xq, dtype=np.float64).ravel()
        if self._chol is None:
            c = float(np.exp(self.log_theta[0]))
            return np.zeros_like(xq), np.full_like(xq, np.sqrt(c))
        ks = self._kernel(xq, self._x, self.log_theta)
        mean = ks @ self._alpha
        v = cho_solve(self._chol, ks.T)
        var = np.exp(self.log_theta[0]) - np.sum(ks * v.T, axis=1)
        return mean, np.sqrt(np.maximum(var, 0.0))
