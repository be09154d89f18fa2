"""Mann-Whitney U comparison of AE methods against a reference, with Bonferroni correction (paper §stats).

For each metric, each method's distribution (one value per trajectory: the per-trajectory mean of the metric) is
tested against the reference method's:

1. two-sided Mann-Whitney U at ``alpha / n_tests`` (Bonferroni, ``n_tests`` = number of methods compared, the
   reference excluded). Not rejected -> ``equal``.
2. otherwise one-sided (alternative: the method is better — larger values when higher is better, smaller when lower
   is better) at the same corrected threshold. Rejected -> ``better``; not rejected -> ``worse`` (step 1 already
   established that the distributions differ).

Values that are NaN (e.g. no RTE because a trajectory never tracked) are dropped; a method with no value left gets
verdict ``n/a``.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.special import ndtr
from scipy.stats import mannwhitneyu

BETTER, WORSE, EQUAL, NA = "better", "worse", "equal", "n/a"
SYMBOL = {BETTER: "▲", WORSE: "▼", EQUAL: "≡", NA: "–"}

#: metric key -> (label, higher is better)
METRICS: dict[str, tuple[str, bool]] = {
    "coverage_mean": ("Coverage", True),
    "matches_mean": ("# Matches", True),
    "rte_pct": ("RTE", False),
    "rre_deg_per_m": ("RRE", False),
    "time_before_failure_s": ("Failure Time", True),
}


@dataclass
class Comparison:
    """One method vs the reference on one metric."""

    method: str
    n: int
    n_ref: int
    median: float
    median_ref: float
    p_two_sided: float
    p_one_sided: float
    alpha_corrected: float
    verdict: str


def _clean(values) -> np.ndarray:
    a = np.asarray(list(values), dtype=np.float64)
    return a[np.isfinite(a)]


#: scipy's ``mannwhitneyu(method="auto")`` takes its exact distribution when a sample has at most this many values
#: and no value is tied; its normal approximation otherwise
EXACT_MAX_N = 8


def mannwhitney_p(x: np.ndarray, y: np.ndarray, alternative: str = "two-sided") -> float:
    """p-value of scipy's ``mannwhitneyu(x, y, alternative=alternative)`` (method ``auto``, continuity corrected) of
    two finite float64 samples (each (n,), n >= 1).

    Where scipy takes its normal approximation (both samples over :data:`EXACT_MAX_N` values, or ties) it is computed
    here in scipy's order of operations (average ranks, U, the tie term ``sum(c^3 - c)``, z, Phi(-z)): the same float64
    p-value without the per-call overhead of scipy's wrappers (~1 ms, and the report's bootstrap,
    :mod:`.stability`, calls it thousands of times). Otherwise (its exact distribution) it is scipy's own."""
    x, y = np.asarray(x, np.float64), np.asarray(y, np.float64)
    n1, n2 = len(x), len(y)
    xy = np.concatenate([x, y])
    _values, inverse, counts = np.unique(xy, return_inverse=True, return_counts=True)
    if (n1 <= EXACT_MAX_N or n2 <= EXACT_MAX_N) and not (counts > 1).any():
        return float(mannwhitneyu(x, y, alternative=alternative).pvalue)
    ranks = (np.cumsum(counts) - counts + 1.0 + (counts - 1.0) / 2)[inverse]
    r1 = np.sum(ranks[:n1])
    u1 = r1 - n1 * (n1 + 1) / 2
    u2 = n1 * n2 - u1
    u, f = (u1, 1) if alternative == "greater" else (u2, 1) if alternative == "less" else (max(u1, u2), 2)
    mu = n1 * n2 / 2
    n = n1 + n2
    c = counts.astype(np.float64)
    tie_term = np.sum(c**3 - c)
    sd = np.sqrt(n1 * n2 / 12 * ((n + 1) - tie_term / (n * (n - 1))))
    with np.errstate(divide="ignore", invalid="ignore"):
        z = (u - mu - 0.5) / sd
    return float(np.clip(ndtr(-z) * f, 0.0, 1.0))


def compare_to_reference(values: dict[str, list[float]], reference: str, higher_is_better: bool,
                         alpha: float = 0.05) -> dict[str, Comparison]:
    """Compare every method of ``values`` ({method: per-trajectory values}) to ``reference``.

    Returns {method: Comparison} for every method except the reference.
    """
    if reference not in values:
        raise KeyError(f"reference method {reference!r} has no values")
    ref = _clean(values[reference])
    others = [m for m in values if m != reference]
    alpha_c = alpha / max(len(others), 1)
    out = {}
    for m in others:
        x = _clean(values[m])
        if len(x) == 0 or len(ref) == 0:
            out[m] = Comparison(m, len(x), len(ref), float("nan"), float("nan"), float("nan"), float("nan"),
                                alpha_c, NA)
            continue
        med, med_ref = float(np.median(x)), float(np.median(ref))
        if np.array_equal(np.sort(x), np.sort(ref)) or (np.ptp(np.r_[x, ref]) == 0):
            out[m] = Comparison(m, len(x), len(ref), med, med_ref, 1.0, float("nan"), alpha_c, EQUAL)
            continue
        p2 = mannwhitney_p(x, ref, "two-sided")
        p1 = float("nan")
        if p2 >= alpha_c:
            verdict = EQUAL
        else:
            p1 = mannwhitney_p(x, ref, "greater" if higher_is_better else "less")
            verdict = BETTER if p1 < alpha_c else WORSE
        out[m] = Comparison(m, len(x), len(ref), med, med_ref, p2, p1, alpha_c, verdict)
    return out


def verdict_table(per_metric: dict[str, dict[str, list[float]]], reference: str, alpha: float = 0.05
                  ) -> dict[str, dict[str, Comparison]]:
    """{metric: {method: Comparison}} for every metric key of :data:`METRICS` present in ``per_metric``."""
    out = {}
    for key, (_label, higher) in METRICS.items():
        if key in per_metric and reference in per_metric[key]:
            out[key] = compare_to_reference(per_metric[key], reference, higher, alpha)
    return out
