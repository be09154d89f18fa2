"""Statistics: Mann-Whitney U against the reference with Bonferroni, on constructed distributions."""

from __future__ import annotations

import numpy as np
import pytest

from bracketry_emulator.stats import BETTER, EQUAL, NA, WORSE, compare_to_reference, verdict_table


def _values() -> dict[str, list[float]]:
    rng = np.random.default_rng(0)
    base = rng.normal(20.0, 2.0, 40)
    return {
        "ae50": list(base),
        "good": list(base - 6.0 + rng.normal(0, 0.5, 40)),  # clearly lower RTE
        "bad": list(base + 6.0 + rng.normal(0, 0.5, 40)),  # clearly higher RTE
        "same": list(rng.permutation(base) + rng.normal(0, 0.05, 40)),
    }


def test_bench_better_worse_equal_lower_is_better() -> None:
    out = compare_to_reference(_values(), "ae50", higher_is_better=False)
    assert set(out) == {"good", "bad", "same"}
    assert out["good"].verdict == BETTER and out["bad"].verdict == WORSE and out["same"].verdict == EQUAL
    assert out["good"].alpha_corrected == pytest.approx(0.05 / 3)  # Bonferroni over the 3 compared methods
    assert np.isnan(out["same"].p_one_sided)  # the one-sided test only runs when the two-sided one rejects


def test_bench_direction_flips_when_higher_is_better() -> None:
    out = compare_to_reference(_values(), "ae50", higher_is_better=True)
    assert out["good"].verdict == WORSE and out["bad"].verdict == BETTER


def test_bench_bonferroni_changes_the_verdict() -> None:
    # a shift that is significant at alpha = 0.05 but not at 0.05 / 20
    ref = np.arange(30.0)
    shifted = ref + 6.5  # two-sided p ~ 0.010
    single = compare_to_reference({"ref": list(ref), "m": list(shifted)}, "ref", higher_is_better=True)["m"]
    assert 0.05 / 20 < single.p_two_sided < 0.05 and single.verdict == BETTER
    many = {"ref": list(ref), "m": list(shifted)} | {f"x{i}": list(ref) for i in range(19)}
    corrected = compare_to_reference(many, "ref", higher_is_better=True)["m"]
    assert corrected.p_two_sided == pytest.approx(single.p_two_sided)
    assert corrected.alpha_corrected == pytest.approx(0.05 / 20) and corrected.verdict == EQUAL


def test_bench_nan_dropped_and_na() -> None:
    vals = {"ae50": [1.0, 2.0, 3.0, float("nan")], "never": [float("nan")] * 3}
    out = compare_to_reference(vals, "ae50", higher_is_better=True)
    assert out["never"].verdict == NA
    table = verdict_table({"rte_pct": _values()}, "ae50")
    assert table["rte_pct"]["good"].verdict == BETTER
    with pytest.raises(KeyError):
        compare_to_reference(vals, "missing", higher_is_better=True)
