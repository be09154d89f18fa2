"""Paired statistics: every method runs on the same trajectories, so compare them trajectory by trajectory.

Next to the paper's Mann-Whitney U (independent samples, :mod:`~bracketry_emulator.stats.mannwhitney`):

* **Wilcoxon signed-rank** of each method against the reference on the trajectories where both have a value
  (two-sided, Bonferroni over the compared methods like the Mann-Whitney table), with the matched-pairs rank-biserial
  correlation as effect size: ``r = (W+ - W-) / (W+ + W-)`` in [-1, 1], positive when the method's values are
  larger (1: larger on every trajectory). The verdict reads the sign of ``r`` with the metric's direction.
* **Friedman** across all methods on the trajectories where every method has a value (blocks = trajectories), with
  Kendall's ``W = chi2 / (n (k - 1))`` in [0, 1] as effect size (1: every trajectory ranks the methods the same way)
  and the methods' mean ranks (1 = smallest value).

Inputs are ``{method: {trajectory: value}}``; NaN values are dropped (a pair or a block with one is left out).
An infinite value is a run worse than any measured one (worst-rank imputation: a run that never tracked has no RTE,
and its localisation is worse than that of any run that has one; see :func:`worst_rank`): in the signed-rank test a
pair with one infinite value is a difference larger than every finite one, in its direction; two equal infinite
values are a tie. Friedman takes the trajectories where every method has a finite value.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.special import ndtr
from scipy.stats import friedmanchisquare, permutation_test, rankdata, wilcoxon

from bracketry_emulator.stats.mannwhitney import BETTER, EQUAL, NA, WORSE


@dataclass
class PairedComparison:
    """One method vs the reference on one metric, paired by trajectory."""

    method: str
    n_pairs: int
    median_difference: float
    p_two_sided: float
    effect_r: float
    alpha_corrected: float
    verdict: str


@dataclass
class FriedmanResult:
    """All methods on one metric: blocks (trajectories) used, chi-square, p, Kendall's W, mean ranks."""

    n_blocks: int
    methods: list[str]
    statistic: float
    p_value: float
    kendall_w: float
    mean_ranks: dict[str, float]


def _pairs(a: dict[str, float], b: dict[str, float]) -> tuple[np.ndarray, np.ndarray]:
    keys = [t for t in a if t in b and not np.isnan(a[t]) and not np.isnan(b[t])]
    return np.array([a[t] for t in keys], float), np.array([b[t] for t in keys], float)


def worst_rank(higher_is_better: bool) -> float:
    """The value standing for a run worse than any measured one: +inf for a metric where lower is better, -inf
    where higher is better (worst-rank imputation of a value missing because the run failed)."""
    return float(-np.inf if higher_is_better else np.inf)


def _differences(x: np.ndarray, y: np.ndarray) -> np.ndarray:
    """``x - y`` with infinite differences as finite ones larger in size than every finite difference (their ranks
    are what the signed-rank test uses) and equal infinite values as a zero difference."""
    with np.errstate(invalid="ignore"):
        d = x - y
    d[np.isnan(d)] = 0.0  # inf - inf: both runs worse than any measured one, a tie
    big = np.isinf(d)
    if big.any():
        top = float(np.max(np.abs(d[~big]), initial=0.0))
        d[big] = np.sign(d[big]) * (2.0 * top + 1.0)
    return d


def rank_biserial(x: np.ndarray, y: np.ndarray) -> float:
    """Matched-pairs rank-biserial correlation of ``x - y`` (zero differences dropped); NaN without differences."""
    d = np.asarray(x, float) - np.asarray(y, float)
    d = d[d != 0]
    if len(d) == 0:
        return float("nan")
    r = rankdata(np.abs(d))
    w_plus, w_minus = float(r[d > 0].sum()), float(r[d < 0].sum())
    return (w_plus - w_minus) / (w_plus + w_minus)


#: scipy's ``wilcoxon(method="auto")`` runs its sign-flip permutation test with ties or zeros up to this many
#: differences (2 ** 13 sign patterns fit its default 9999 resamples: the test enumerates them all)
PERMUTATION_MAX_N = 13


def wilcoxon_p(diff: np.ndarray, method: str = "auto") -> float:
    """Two-sided p-value of scipy's Wilcoxon signed-rank test of ``diff`` (float64 (n,), zeros dropped as
    ``zero_method="wilcox"`` does) with its p-value ``method``.

    Where scipy's ``auto`` takes its exact sign-flip permutation test (ties or zeros, n <= 13), the same
    ``permutation_test`` runs here with the statistic vectorised over the 2 ** n sign patterns (scipy's own calls
    it once per pattern, about a second for n = 11): the sum of the positive differences' ranks, whose ranks of
    ``|diff|`` no sign flip changes; half-integer sums, exact in float64, so the null distribution, the comparisons
    and the p-value are scipy's. ``approx`` (the bootstrap's many calls, :mod:`.stability`) is scipy's normal
    approximation computed here in scipy's order of operations (no continuity correction, ties corrected), the
    same float64 p-value without its per-call overhead. Every other case is scipy's ``wilcoxon`` itself."""
    d = np.asarray(diff, np.float64)
    nonzero = d != 0
    magnitude = np.abs(d[nonzero])
    values, counts = np.unique(magnitude, return_counts=True)
    if method == "approx" and len(magnitude) and np.isfinite(magnitude).all():
        return _normal_p(d[nonzero], magnitude, values, counts)
    ties = len(values) < len(magnitude)
    if method != "auto" or len(d) > PERMUTATION_MAX_N or not (ties or not nonzero.all()):
        return float(wilcoxon(d, alternative="two-sided", method=method).pvalue)
    ranks = rankdata(magnitude)

    def r_plus(x: np.ndarray, axis: int = -1) -> np.ndarray:
        return np.sum((np.moveaxis(x, axis, -1)[..., nonzero] > 0) * ranks, axis=-1)

    return float(permutation_test((d,), r_plus, permutation_type="samples", vectorized=True,
                                  alternative="two-sided", axis=-1).pvalue)


def _normal_p(d: np.ndarray, magnitude: np.ndarray, values: np.ndarray, counts: np.ndarray) -> float:
    """scipy's two-sided normal-approximation p of the signed-rank test of the non-zero differences ``d`` (their
    ``magnitude`` = |d|, its sorted distinct ``values`` and their ``counts``): average ranks, the tie correction
    ``sum(c^3 - c)``, z = (W+ - n (n + 1) / 4) / se, p = 2 Phi(-|z|)."""
    first_rank = np.cumsum(counts) - counts + 1.0
    ranks = (first_rank + (counts - 1.0) / 2)[np.searchsorted(values, magnitude)]
    r_plus = np.float64(np.sum(ranks[d > 0]))
    count = np.float64(len(d))
    mn = count * (count + 1.) * 0.25
    se = count * (count + 1.) * (2. * count + 1.)
    c = counts.astype(np.float64)
    tie_correct = np.sum(c**3 - c)
    se = np.sqrt((se - tie_correct / 2) / 24)
    z = (r_plus - mn) / se
    return float(2 * ndtr(-np.abs(z)))


def wilcoxon_to_reference(values: dict[str, dict[str, float]], reference: str, higher_is_better: bool,
                          alpha: float = 0.05, n_tests: int | None = None, method: str = "auto"
                          ) -> dict[str, PairedComparison]:
    """Wilcoxon signed-rank of every method against ``reference`` (see the module text).

    ``n_tests``: the Bonferroni count (default: the number of compared methods). ``method``: scipy's p-value method
    (``auto``: exact without ties, a permutation test with ties on small samples, about a second a call;
    ``approx``: the normal approximation with the tie correction, for the many calls of a bootstrap,
    :mod:`.stability`).
    """
    if reference not in values:
        raise KeyError(f"reference method {reference!r} has no values")
    others = [m for m in values if m != reference]
    alpha_c = alpha / max(n_tests if n_tests is not None else len(others), 1)
    out = {}
    for m in others:
        x, y = _pairs(values[m], values[reference])
        if len(x) == 0:
            out[m] = PairedComparison(m, 0, float("nan"), float("nan"), float("nan"), alpha_c, NA)
            continue
        with np.errstate(invalid="ignore"):
            raw = x - y
        med = float(np.median(np.where(np.isnan(raw), 0.0, raw)))
        diff = _differences(x, y)
        if not np.any(diff != 0):
            out[m] = PairedComparison(m, len(x), med, 1.0, float("nan"), alpha_c, EQUAL)
            continue
        p = wilcoxon_p(diff, method)
        r = rank_biserial(diff, np.zeros_like(diff))
        if p >= alpha_c:
            verdict = EQUAL
        else:
            verdict = BETTER if (r > 0) == higher_is_better else WORSE
        out[m] = PairedComparison(m, len(x), med, p, r, alpha_c, verdict)
    return out


def friedman(values: dict[str, dict[str, float]], methods: list[str] | None = None) -> FriedmanResult:
    """Friedman test over ``methods`` (default: all of ``values``; at least 3) on their common trajectories."""
    ms = list(methods or values)
    nan = float("nan")
    if len(ms) < 3:
        return FriedmanResult(0, ms, nan, nan, nan, {m: nan for m in ms})
    blocks = [t for t in values[ms[0]] if all(t in values[m] and bool(np.isfinite(values[m][t])) for m in ms)]
    if len(blocks) < 2:
        return FriedmanResult(len(blocks), ms, nan, nan, nan, {m: nan for m in ms})
    data = np.array([[values[m][t] for m in ms] for t in blocks], float)  # (n blocks, k methods)
    ranks = np.vstack([rankdata(row) for row in data])
    mean_ranks = {m: float(v) for m, v in zip(ms, ranks.mean(axis=0))}
    if np.all(np.ptp(data, axis=1) == 0):  # every block a tie: no evidence of any difference
        return FriedmanResult(len(blocks), ms, 0.0, 1.0, 0.0, mean_ranks)
    res = friedmanchisquare(*data.T)
    chi2 = float(res.statistic)
    w = chi2 / (len(blocks) * (len(ms) - 1))
    return FriedmanResult(len(blocks), ms, chi2, float(res.pvalue), float(min(max(w, 0.0), 1.0)), mean_ranks)
