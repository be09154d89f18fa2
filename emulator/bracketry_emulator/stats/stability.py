"""How far a verdict rests on the trajectories drawn: its share over bootstrap resamples of the trajectories.

A verdict (better / worse / equal than the reference, :mod:`.mannwhitney` or :mod:`.paired`) comes from one set of
trajectories. Resampled with replacement (:data:`N_RESAMPLES` times, the same draw for every method, so pairs stay
pairs), the test gives each resample a verdict; the **stability** of the verdict is the share of resamples that give
the same one. A verdict is shown (▲ / ▼ / ≡) only when its stability is at least :data:`STABLE_SHARE`; otherwise the
table prints :data:`UNSTABLE` (the verdict rests on noise: a p-value close to the threshold, or one or two
trajectories carrying it; an "equal" that many resamples call better or worse is no more settled than a "worse" that
many call equal, and two runs of one benchmark whose SLAM differs slightly flip between the two).

The draws come from a generator seeded by :data:`SEED` and the metric's and method's names: the same values give
the same shares on every run.
"""

from __future__ import annotations

import warnings
import zlib
from collections.abc import Callable, Mapping
from typing import Protocol

import numpy as np

from bracketry_emulator.stats.mannwhitney import BETTER, EQUAL, SYMBOL, WORSE

#: bootstrap resamples of the trajectories per verdict
N_RESAMPLES = 200
#: the share of resamples a better/worse verdict must keep to be shown as such
STABLE_SHARE = 0.9
#: the symbol of a better/worse verdict below :data:`STABLE_SHARE`
UNSTABLE = "?"
#: the resampling seed (with the metric's and method's names)
SEED = 44


class _HasVerdict(Protocol):
    verdict: str


#: a test: ({method: {trajectory: value}}, reference) -> {method: comparison with a ``verdict``}
Test = Callable[[dict[str, dict[str, float]], str], Mapping[str, _HasVerdict]]


def resample_indices(n: int, n_resamples: int, seed: int) -> np.ndarray:
    """int64 (n_resamples, n): indices into ``n`` items, drawn with replacement by a generator seeded ``seed``."""
    return np.random.default_rng(seed).integers(0, n, size=(n_resamples, n)) if n else np.zeros((n_resamples, 0), int)


def name_seed(*names: str, seed: int = SEED) -> int:
    """A seed from ``seed`` and names (stable across runs and Python processes, unlike ``hash``)."""
    return zlib.crc32("\0".join(names).encode(), seed)


def verdict_stability(values: dict[str, dict[str, float]], reference: str, verdicts: dict[str, str], test: Test,
                      seed: int, n_resamples: int = N_RESAMPLES) -> dict[str, float]:
    """{method: share of the ``n_resamples`` bootstrap resamples of the trajectories whose ``test`` verdict equals
    ``verdicts[method]``} for every method of ``verdicts``.

    ``values``: {method: {trajectory: value}} (the reference included); a resample draws trajectories (of the union
    of every method's) with replacement, and every method takes its values on the drawn ones (a drawn trajectory
    twice: its value twice, under two names). ``test``: the verdict of each method against ``reference`` on a
    resample (e.g. a Wilcoxon signed-rank with its alpha and direction bound).
    """
    trajectories = sorted({t for v in values.values() for t in v})
    draws = resample_indices(len(trajectories), n_resamples, seed)
    same = dict.fromkeys(verdicts, 0)
    with warnings.catch_warnings():  # a resample repeats trajectories: ties, which the tests warn about
        warnings.simplefilter("ignore")
        for draw in draws:
            sample = {m: {f"{j}:{trajectories[i]}": v[trajectories[i]] for j, i in enumerate(draw)
                          if trajectories[i] in v} for m, v in values.items()}
            got = test(sample, reference)
            for m, verdict in verdicts.items():
                same[m] += got[m].verdict == verdict
    return {m: same[m] / max(n_resamples, 1) for m in verdicts}


def shown_symbol(verdict: str, stability: float, stable_share: float = STABLE_SHARE) -> str:
    """The table's symbol of a verdict: ▲ / ▼ / ≡ when its ``stability`` is at least ``stable_share``, else
    :data:`UNSTABLE`; n/a as it is."""
    if verdict in (BETTER, WORSE, EQUAL) and not stability >= stable_share:
        return UNSTABLE
    return SYMBOL[verdict]
