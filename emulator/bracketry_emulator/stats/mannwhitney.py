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
        p2 = float(mannwhitneyu(x, ref, alternative="two-sided").pvalue)
        p1 = float("nan")
        if p2 >= alpha_c:
            verdict = EQUAL
        else:
            p1 = float(mannwhitneyu(x, ref, alternative="greater" if higher_is_better else "less").pvalue)
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
