"""The signed-rank p-value's fast permutation path (:func:`~bracketry_emulator.stats.paired.wilcoxon_p`) gives
scipy's own p-value, bit for bit, wherever scipy's ``auto`` would run its permutation test, and hands every other
case to scipy."""

from __future__ import annotations

import warnings

import numpy as np
import pytest
from scipy.stats import wilcoxon

from bracketry_emulator.stats.paired import PERMUTATION_MAX_N, wilcoxon_p


def _scipy_p(d: np.ndarray, method: str = "auto") -> float:
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        return float(wilcoxon(d, alternative="two-sided", method=method).pvalue)


@pytest.mark.parametrize("seed", range(4))
def test_ties_and_zeros_match_scipy(seed: int) -> None:
    rng = np.random.default_rng(seed)
    checked = 0
    for _ in range(12):
        n = int(rng.integers(2, 10))
        d = rng.integers(-3, 4, size=n).astype(float) * float(rng.choice([0.5, 1.0, 0.1]))
        if not np.any(d != 0):
            continue
        assert wilcoxon_p(d) == _scipy_p(d), d
        checked += 1
    assert checked >= 8


def test_the_demo_size_case_matches_scipy() -> None:
    # 11 trajectories, a tie at the failure time and a worst-rank difference (the demo's RTE column's shape)
    d = np.array([0.0, 9.8, 9.8, -1.2, 3.4, -0.7, 41.0, 2.2, -2.2, 0.5, 1.1])
    assert wilcoxon_p(d) == _scipy_p(d)


def test_other_cases_are_scipys() -> None:
    no_ties = np.array([1.0, -2.5, 3.0, 4.5, -5.0, 6.0])  # scipy's exact distribution
    assert wilcoxon_p(no_ties) == _scipy_p(no_ties)
    big = np.r_[np.arange(1.0, PERMUTATION_MAX_N + 2), 3.0]  # ties beyond the permutation size: normal approx.
    assert wilcoxon_p(big) == _scipy_p(big)
    ties = np.array([1.0, 1.0, -2.0, 3.0])
    assert wilcoxon_p(ties, "approx") == _scipy_p(ties, "approx")


def test_permutation_case_does_not_call_scipys_wilcoxon(monkeypatch: pytest.MonkeyPatch) -> None:
    from bracketry_emulator.stats import paired

    d = np.array([1.0, 1.0, -2.0, 3.0, 0.0])
    want = _scipy_p(d)

    def refuse(*_a: object, **_k: object) -> None:
        raise AssertionError("scipy's wilcoxon called on the permutation path")

    monkeypatch.setattr(paired, "wilcoxon", refuse)
    assert wilcoxon_p(d) == want


@pytest.mark.parametrize("seed", range(3))
def test_normal_approximation_is_scipys_bit_for_bit(seed: int) -> None:
    rng = np.random.default_rng(seed)
    for k in range(200):
        n = int(rng.integers(1, 30))
        d = rng.normal(size=n) if k % 3 == 0 else rng.integers(-5, 6, size=n) * float(rng.choice([0.5, 0.1, 3.7]))
        if not np.any(d != 0):
            continue
        assert wilcoxon_p(d, "approx") == _scipy_p(d, "approx"), d


def test_normal_approximation_does_not_call_scipys_wilcoxon(monkeypatch: pytest.MonkeyPatch) -> None:
    from bracketry_emulator.stats import paired

    d = np.array([1.0, 1.0, -2.0, 3.0, 0.0, 0.0, -4.5, 6.0])
    want = _scipy_p(d, "approx")
    monkeypatch.setattr(paired, "wilcoxon", lambda *_a, **_k: pytest.fail("scipy's wilcoxon called"))
    assert wilcoxon_p(d, "approx") == want
