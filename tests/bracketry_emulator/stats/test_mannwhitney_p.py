"""The Mann-Whitney p-value's own normal approximation (:func:`~bracketry_emulator.stats.mannwhitney.mannwhitney_p`)
gives scipy's p-value bit for bit, and the exact cases are scipy's."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.stats import mannwhitneyu

from bracketry_emulator.stats.mannwhitney import EXACT_MAX_N, mannwhitney_p


@pytest.mark.parametrize("seed", range(3))
def test_matches_scipy_bit_for_bit(seed: int) -> None:
    rng = np.random.default_rng(seed)
    for k in range(300):
        n1, n2 = int(rng.integers(1, 15)), int(rng.integers(1, 15))
        if k % 3 == 0:
            x, y = rng.normal(size=n1), rng.normal(size=n2)
        else:  # ties (the bootstrap's resamples repeat trajectories)
            x, y = rng.integers(0, 6, n1) * 0.7, rng.integers(0, 6, n2) * 0.7
        if np.ptp(np.r_[x, y]) == 0:
            continue
        for alternative in ("two-sided", "greater", "less"):
            assert mannwhitney_p(x, y, alternative) == float(mannwhitneyu(x, y, alternative=alternative).pvalue)


def test_the_approximation_does_not_call_scipy(monkeypatch: pytest.MonkeyPatch) -> None:
    from bracketry_emulator.stats import mannwhitney

    x = np.array([1.0, 2.0, 2.0, 3.5, 4.0, 4.0, 5.0, 7.0, 8.0, 9.0, 9.5])
    y = np.array([0.5, 2.0, 3.0, 3.0, 3.5, 6.0, 6.5, 7.5, 8.5, 10.0, 11.0])
    want = float(mannwhitneyu(x, y, alternative="less").pvalue)
    monkeypatch.setattr(mannwhitney, "mannwhitneyu", lambda *_a, **_k: pytest.fail("scipy's mannwhitneyu called"))
    assert mannwhitney_p(x, y, "less") == want


def test_small_samples_without_ties_are_scipys_exact_test() -> None:
    x, y = np.arange(1.0, EXACT_MAX_N + 1), np.arange(0.5, EXACT_MAX_N + 3)
    assert mannwhitney_p(x, y) == float(mannwhitneyu(x, y, method="exact").pvalue)
