"""A verdict's stability over bootstrap resamples of the trajectories (stats/stability.py): a difference every
trajectory shows is stable and shown; one that a single trajectory carries is not, and is printed as unstable; the
shares are the same on every run (seeded draws)."""

from __future__ import annotations

from bracketry_emulator.stats.mannwhitney import SYMBOL, WORSE
from bracketry_emulator.stats.paired import wilcoxon_to_reference
from bracketry_emulator.stats.stability import (
    UNSTABLE,
    name_seed,
    resample_indices,
    shown_symbol,
    verdict_stability,
)


def _test(sample: dict[str, dict[str, float]], ref: str):
    return wilcoxon_to_reference(sample, ref, higher_is_better=True, alpha=0.05, method="approx")


def _values() -> dict[str, dict[str, float]]:
    trajectories = [f"t{i}" for i in range(12)]
    ref = {t: 100.0 + 3 * i for i, t in enumerate(trajectories)}
    clear = {t: v - 20.0 - 0.5 * i for i, (t, v) in enumerate(ref.items())}  # worse on every trajectory
    # worse by a hair on 8, better by a hair on 4: the sign rests on which trajectories are drawn
    borderline = {t: v + (-0.5 - 0.1 * i if i % 3 else 0.4 + 0.1 * i) for i, (t, v) in enumerate(ref.items())}
    return {"ref": ref, "clear": clear, "borderline": borderline}


def test_a_difference_every_trajectory_shows_is_stable_and_one_resting_on_noise_is_not() -> None:
    values = _values()
    verdicts = {m: c.verdict for m, c in _test(values, "ref").items()}
    assert verdicts["clear"] == WORSE
    share = verdict_stability(values, "ref", verdicts, _test, seed=name_seed("wilcoxon", "matches"))
    assert share["clear"] >= 0.99
    assert shown_symbol(verdicts["clear"], share["clear"]) == SYMBOL[WORSE]
    if verdicts["borderline"] == WORSE:  # the full sample's verdict, whatever it is, is not shown as settled
        assert share["borderline"] < 0.9
        assert shown_symbol(verdicts["borderline"], share["borderline"]) == UNSTABLE
    else:
        assert share["borderline"] < 1.0
    again = verdict_stability(values, "ref", verdicts, _test, seed=name_seed("wilcoxon", "matches"))
    assert again == share


def test_symbols_and_seeded_draws() -> None:
    assert shown_symbol(WORSE, 0.95) == SYMBOL[WORSE]
    assert shown_symbol(WORSE, 0.5) == UNSTABLE
    assert shown_symbol("equal", 0.1) == UNSTABLE  # an equal that resamples call better or worse
    assert shown_symbol("equal", 0.9) == SYMBOL["equal"]
    assert shown_symbol("n/a", 0.0) == SYMBOL["n/a"]
    a, b = resample_indices(5, 3, 7), resample_indices(5, 3, 7)
    assert a.shape == (3, 5) and (a == b).all() and a.min() >= 0 and a.max() < 5
    assert resample_indices(0, 4, 1).shape == (4, 0)
    assert name_seed("a", "b") == name_seed("a", "b") != name_seed("a", "c")
