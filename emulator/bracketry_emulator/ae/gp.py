"""A small Gaussian-process regressor (1-D input), deterministic: constant * RBF kernel plus a fixed noise term.

Equivalent in model to scikit-learn's ``GaussianProcessRegressor(kernel=ConstantKernel(1.0) * RBF(1.0),
alpha=noise_var, n_restarts_optimizer=n_restarts)`` that the benchmark authors use for Kim (zero prior mean, no
target normalisation, hyper-parameters by maximum log marginal likelihood with L-BFGS-B in log space, bounds
[1e-5, 1e5] for both), but the restarts are drawn from a seeded generator so runs are reproducible.

Speed (Kim fits one GP per step on at most 5 points, from 11 starts), with the same results bit for bit as the
formulation with ``scipy.linalg.cho_factor``/``cho_solve`` and ``scipy.optimize.minimize(method="L-BFGS-B")``: the
objective makes the same numpy operations and calls LAPACK's ``potrf``/``potrs`` with the arguments those functions
pass, without their wrappers' checks, with what depends on the data only computed once per fit and each value
remembered (restarts and line searches revisit points); scipy's L-BFGS-B routine (``setulb``, the one ``minimize``
calls) is driven directly, as ``minimize`` drives it, without its per-call and per-evaluation wrappers: ~5x faster
per fit (with single-threaded BLAS, as ``bracketry emulate`` runs). The direct drive is checked once per process
against ``minimize`` on a fixed problem; where they differ (another scipy's private routine) ``minimize`` is used.
An objective on Python floats or in C was not kept: its last-bit differences moved L-BFGS-B's stopping point (it stops
at a relative decrease of 2.2e-9) by up to 5e-4 in log l. scipy is imported on the first fit only.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import numpy as np

LOG_BOUNDS = (float(np.log(1e-5)), float(np.log(1e5)))

#: L-BFGS-B settings: scipy.optimize.minimize's defaults (memory 10, ftol 2.22e-9, gtol 1e-5, 20 line-search steps)
_MAXCOR = 10
_FTOL = 2.2204460492503131e-09
_GTOL = 1e-5
_MAXLS = 20
_MAXITER = 15000


class _Objective:
    """The negative log marginal likelihood of data (x, y) and its gradient in (log c, log l), as the formulation
    with scipy's ``cho_factor``/``cho_solve`` computes it: the same numpy operations in the same order and LAPACK's
    ``potrf``/``potrs`` called with the arguments those functions pass, so the same values bit for bit, without
    their wrappers' checks (non-finite data is refused once, as they refuse it), with what depends on the data only
    computed once per fit, and each value remembered (restarts and line searches revisit points)."""

    def __init__(self, x: np.ndarray, y: np.ndarray, noise_var: float) -> None:
        from scipy.linalg import get_lapack_funcs

        if not (np.isfinite(x).all() and np.isfinite(y).all()):
            raise ValueError("array must not contain infs or NaNs")  # as cho_factor / cho_solve
        n = len(x)
        self.y = y
        self.d2 = (x[:, None] - x[None, :]) ** 2
        self.minus_half_d2 = -0.5 * self.d2
        self.noise_eye = noise_var * np.eye(n)
        self.eye = np.eye(n)
        self.half_n_log_2pi = 0.5 * n * np.log(2 * np.pi)
        self.potrf, self.potrs = get_lapack_funcs(("potrf", "potrs"), (self.noise_eye,))
        self.seen: dict[bytes, tuple[float, np.ndarray]] = {}

    def __call__(self, log_theta: np.ndarray) -> tuple[float, np.ndarray]:
        key = log_theta.tobytes()
        hit = self.seen.get(key)
        if hit is None:
            hit = self.seen[key] = self._evaluate(log_theta)
        return hit[0], hit[1].copy()

    def _evaluate(self, log_theta: np.ndarray) -> tuple[float, np.ndarray]:
        # the formulation's operations, each computed once: r = exp(-0.5 d2 / l^2), K = c r + noise I,
        # L = cholesky(K), alpha = K^-1 y, lml = -y.alpha / 2 - sum(log diag L) - n log(2 pi) / 2,
        # d lml / d log(c, l) = sum((alpha alpha^T - K^-1) * (c r, c r d2 / l^2)) / 2
        add = np.add.reduce  # = np.sum
        c, length = np.exp(log_theta).tolist()  # Python floats: the same float64 products
        l2 = length**2
        r = np.exp(self.minus_half_d2 / l2)
        cr = c * r
        low, info = self.potrf(cr + self.noise_eye, 1, 0)  # lower, clean=False
        if info > 0:  # not positive definite
            return 1e25, np.zeros(2)
        alpha, _ = self.potrs(low, self.y, 1)
        lml = -0.5 * float(self.y @ alpha) - float(add(np.log(low.diagonal()), axis=None)) - self.half_n_log_2pi
        kinv, _ = self.potrs(low, self.eye, 1)
        inner = np.multiply.outer(alpha, alpha) - kinv  # = np.outer(alpha, alpha) - kinv
        g_c = 0.5 * float(add(inner * cr, axis=None))
        g_l = 0.5 * float(add(inner * (cr * self.d2 / l2), axis=None))
        return -lml, np.array([-g_c, -g_l])


class _Minimizer:
    """L-BFGS-B with jac=True and box bounds as ``scipy.optimize.minimize(method="L-BFGS-B")`` runs it (its
    defaults), the routine driven directly. Falls back to ``minimize`` itself when the direct drive does not
    reproduce it on a fixed problem (checked once)."""

    _checked: bool | None = None  # None: not checked yet

    def __init__(self) -> None:
        import scipy.optimize

        self._minimize = scipy.optimize.minimize
        self._setulb: Any = None
        try:
            from scipy.optimize import _lbfgsb

            self._setulb = _lbfgsb.setulb
        except ImportError:
            self._setulb = None
        if _Minimizer._checked is None:
            _Minimizer._checked = self._self_check()

    def _self_check(self) -> bool:
        if self._setulb is None:
            return False
        fun = _Objective(np.array([0.5, 3.0, 7.5, 12.0]), np.array([900.0, 1500.0, 2100.0, 1700.0]), 0.2)
        bounds = [LOG_BOUNDS, LOG_BOUNDS]
        for start in ([0.0, 0.0], [4.0, -3.0], [-2.0, 1.5]):
            try:
                mine = self._direct(fun, np.array(start), LOG_BOUNDS)
            except Exception:  # another scipy's private routine: use minimize
                return False
            ref = self._minimize(fun, np.array(start), jac=True, method="L-BFGS-B", bounds=bounds)
            if not (np.array_equal(mine[0], ref.x) and mine[1] == float(ref.fun) and mine[2] == ref.nfev):
                return False
        return True

    def _direct(self, fun: Callable[[np.ndarray], tuple[float, np.ndarray]], x0: np.ndarray,
                bounds: tuple[float, float]) -> tuple[np.ndarray, float, int]:
        n = x0.size
        m = _MAXCOR
        x = np.clip(np.asarray(x0, dtype=np.float64), bounds[0], bounds[1])
        low = np.full(n, bounds[0])
        up = np.full(n, bounds[1])
        nbd = np.full(n, 2, dtype=np.int32)
        f: Any = np.array(0.0)
        g = np.zeros(n)
        wa = np.zeros(2 * m * n + 5 * n + 11 * m * m + 8 * m)
        iwa = np.zeros(3 * n, dtype=np.int32)
        task = np.zeros(2, dtype=np.int32)
        ln_task = np.zeros(2, dtype=np.int32)
        lsave = np.zeros(4, dtype=np.int32)
        isave = np.zeros(44, dtype=np.int32)
        dsave = np.zeros(29)
        factr = _FTOL / np.finfo(float).eps
        nfev = 0
        nit = 0
        last_x: bytes | None = None
        last: tuple[float, np.ndarray] = (0.0, g)
        while True:
            self._setulb(m, x, low, up, nbd, f, g, factr, _GTOL, wa, iwa, task, lsave, isave, dsave, _MAXLS,
                         ln_task)
            if task[0] == 3:  # f and g wanted at x
                if last_x is None or x.tobytes() != last_x:
                    last = fun(x.copy())
                    last_x = x.tobytes()
                    nfev += 1
                f, g = last
            elif task[0] == 1:  # a new iterate
                nit += 1
                if nit >= _MAXITER:
                    break
            else:
                break
        return x, float(f), nfev

    def minimize(self, fun: Callable[[np.ndarray], tuple[float, np.ndarray]], x0: np.ndarray,
                 bounds: tuple[float, float]) -> tuple[np.ndarray, float]:
        """(argmin x, min f) from ``x0`` within ``bounds`` (the same for every coordinate)."""
        if _Minimizer._checked:
            x, f, _ = self._direct(fun, x0, bounds)
            return x, f
        res = self._minimize(fun, x0, jac=True, method="L-BFGS-B", bounds=[bounds] * x0.size)
        return np.asarray(res.x), float(res.fun)


_MINIMIZER: _Minimizer | None = None


def _minimizer() -> _Minimizer:
    global _MINIMIZER
    if _MINIMIZER is None:
        _MINIMIZER = _Minimizer()
    return _MINIMIZER


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

    def fit(self, x: np.ndarray, y: np.ndarray) -> GaussianProcess1D:
        """Fit hyper-parameters (max log marginal likelihood, seeded restarts) and the posterior."""
        x = np.asarray(x, dtype=np.float64).ravel()
        y = np.asarray(y, dtype=np.float64).ravel()
        starts = [np.zeros(2)] + [self.rng.uniform(LOG_BOUNDS[0], LOG_BOUNDS[1], 2) for _ in range(self.n_restarts)]
        opt = _minimizer()
        fun = _Objective(x, y, self.noise_var)
        best: tuple[float, np.ndarray] | None = None
        for s in starts:
            theta, f = opt.minimize(fun, s, LOG_BOUNDS)
            if best is None or f < best[0]:
                best = (f, theta)
        assert best is not None
        self.log_theta = best[1]
        from scipy.linalg import cho_factor, cho_solve  # loaded with scipy.optimize by the fit

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
        from scipy.linalg import cho_solve

        ks = self._kernel(xq, self._x, self.log_theta)
        mean = ks @ self._alpha
        v = cho_solve(self._chol, ks.T)
        var = np.exp(self.log_theta[0]) - np.sum(ks * v.T, axis=1)
        return mean, np.sqrt(np.maximum(var, 0.0))
