"""Paired statistics (Wilcoxon signed-rank vs the reference, Friedman across methods) on constructed data."""

from __future__ import annotations

import math

import numpy as np
import pytest

from bracketry_emulator.stats import BETTER, EQUAL, NA, WORSE, friedman, rank_biserial, wilcoxon_to_reference

TRAJ = [f"t{i}" for i in range(12)]


def _values() -> dict[str, dict[str, float]]:
    rng = np.random.default_rng(5)
    ref = {t: float(v) for t, v in zip(TRAJ, rng.uniform(1.0, 3.0, len(TRAJ)))}
    return {
        "ae50": ref,
        "up": {t: v + 0.5 + 0.01 * i for i, (t, v) in enumerate(ref.items())},   # larger on every trajectory
        "down": {t: v - 0.2 for t, v in ref.items()},                            # smaller on every trajectory
        "same": dict(ref),
        "mixed": {t: v + (0.3 if i % 2 else -0.3) for i, (t, v) in enumerate(ref.items())},
        "empty": {t: float("nan") for t in TRAJ},
    }


def test_bench_wilcoxon_known_outcomes() -> None:
    out = wilcoxon_to_reference(_values(), "ae50", higher_is_better=False, alpha=0.05)
    # all 12 differences positive: exact two-sided p = 2 / 2**12, rank-biserial r = 1
    assert out["up"].p_two_sided == pytest.approx(2 / 2**12) and out["up"].effect_r == pytest.approx(1.0)
    assert out["up"].verdict == WORSE  # larger is worse for a lower-is-better metric (e.g. RTE)
    assert out["down"].effect_r == pytest.approx(-1.0) and out["down"].verdict == BETTER
    assert out["down"].median_difference == pytest.approx(-0.2) and out["down"].n_pairs == 12
    assert out["same"].verdict == EQUAL and out["same"].p_two_sided == 1.0
    assert out["mixed"].verdict == EQUAL and abs(out["mixed"].effect_r) < 0.5 and out["mixed"].p_two_sided > 0.3
    assert out["empty"].verdict == NA and out["empty"].n_pairs == 0
    assert out["up"].alpha_corrected == pytest.approx(0.05 / 5)  # Bonferroni over the compared methods
    higher = wilcoxon_to_reference(_values(), "ae50", higher_is_better=True, n_tests=2)
    assert higher["up"].verdict == BETTER and higher["up"].alpha_corrected == pytest.approx(0.025)


def test_bench_wilcoxon_pairs_by_trajectory_and_drops_nan() -> None:
    v = {"ref": {"a": 1.0, "b": 2.0, "c": 3.0, "d": float("nan")}, "m": {"b": 2.5, "c": 3.5, "d": 9.0, "e": 1.0}}
    out = wilcoxon_to_reference(v, "ref", higher_is_better=True)
    assert out["m"].n_pairs == 2 and out["m"].median_difference == pytest.approx(0.5)


def test_bench_rank_biserial() -> None:
    # d = 1, 2, -2: ranks of |d| 1, 2.5, 2.5 -> W+ = 3.5, W- = 2.5
    assert rank_biserial(np.array([2.0, 3.0, 1.0]), np.array([1.0, 1.0, 3.0])) == pytest.approx((3.5 - 2.5) / 6)
    assert math.isnan(rank_biserial(np.ones(3), np.ones(3)))


def test_bench_friedman_known_outcomes() -> None:
    n = 10
    perfect = {"a": {f"t{i}": 1.0 + i for i in range(n)}, "b": {f"t{i}": 2.0 + i for i in range(n)},
               "c": {f"t{i}": 3.0 + i for i in range(n)}}
    res = friedman(perfect)
    # every block ranks a < b < c: chi2 = n (k - 1) = 20, p = exp(-chi2 / 2) for 2 degrees of freedom, W = 1
    assert res.statistic == pytest.approx(2.0 * n) and res.p_value == pytest.approx(math.exp(-n))
    assert res.kendall_w == pytest.approx(1.0) and res.mean_ranks == {"a": 1.0, "b": 2.0, "c": 3.0}
    assert res.n_blocks == n
    tied = friedman({m: {f"t{i}": 1.0 for i in range(n)} for m in "abc"})
    assert tied.p_value == 1.0 and tied.kendall_w == 0.0
    perfect["c"]["t3"] = float("nan")  # the block with a missing value is left out
    assert friedman(perfect).n_blocks == n - 1
    assert math.isnan(friedman({"a": perfect["a"], "b": perfect["b"]}).p_value)  # needs 3 methods


def test_a_run_that_never_tracked_ranks_worst_in_the_paired_test() -> None:
    """RTE is missing where a method never tracked: left out, the four trajectories it failed on would hide its
    failures; ranked worst (worst-rank imputation), they count against it. Equal infinite values are a tie."""
    from bracketry_emulator.report.tables import per_trajectory_values

    ref = {f"t{k}": 2.0 + 0.1 * k for k in range(12)}
    rows = [{"trajectory": t, "method": "ae50", "rte_pct": v, "success": True, "reference": "groundtruth"}
            for t, v in ref.items()]
    bad = {t: v + (0.3 if k % 3 else -0.2) for k, (t, v) in enumerate(ref.items())}  # 8 worse, 4 better: unclear
    for k, (t, v) in enumerate(bad.items()):
        failed = k % 3 == 0  # the four trajectories it looked better on: it never tracked them
        rows.append({"trajectory": t, "method": "bad", "rte_pct": float("nan") if failed else v,
                     "success": not failed, "reference": "groundtruth"})
    dropped = wilcoxon_to_reference(per_trajectory_values(rows, ["ae50", "bad"], "rte_pct"), "ae50", False)
    ranked = wilcoxon_to_reference(per_trajectory_values(rows, ["ae50", "bad"], "rte_pct", impute_failures=True),
                                   "ae50", False)
    assert dropped["bad"].n_pairs == 8 and ranked["bad"].n_pairs == 12
    assert ranked["bad"].verdict == WORSE and ranked["bad"].effect_r == 1.0
    assert ranked["bad"].p_two_sided < dropped["bad"].p_two_sided
    # a run whose RTE is missing for another reason (no reference, a SLAM error) is still left out
    for r in rows:
        if r["method"] == "bad" and not r["success"]:
            r["error"] = "ORB-SLAM3 crashed"
    assert wilcoxon_to_reference(per_trajectory_values(rows, ["ae50", "bad"], "rte_pct", impute_failures=True),
                                 "ae50", False)["bad"].n_pairs == 8
    # both never tracked: a tie, not a difference
    both = wilcoxon_to_reference({"a": {"x": math.inf, "y": 1.0, "z": 2.0}, "b": {"x": math.inf, "y": 1.0, "z": 2.0}},
                                 "b", False)
    assert both["a"].verdict == EQUAL
