"""Source-bracket selection rules.

- ``highernosat`` (the paper's HigherNoSat, alpha = 0.01): the bracketing pair bl < t < bh; take bh unless its
  over-saturated fraction exceeds alpha, else bl; a target equal to a bracket uses it; outside the bracket range,
  the nearest bracket. "Saturated" counts pixels at the saturated code (4094 on the BorealHDR camera), as the
  authors' first implementation (``higher_if_no_sat``) did; ``count="both"`` also counts code 0 (the paper's text).
- ``upstream`` (the authors' code, ``closer_least_sat``): idx = first bracket >= t (none -> the longest);
  if idx is not the first and sat[idx] > sat[idx-1] (sat = fraction of 0 and 4094), use idx-1.
"""

from __future__ import annotations

from bisect import bisect_left, bisect_right
from collections.abc import Mapping, Sequence
from typing import Literal

import numpy as np

from .kernel import code_counts

SatCount = Literal["over", "both"]


def saturation_fraction(image: np.ndarray, saturated_code: int, count: SatCount = "over") -> float:
    """Fraction of pixels at or above ``saturated_code`` (plus pixels at 0 when ``count == "both"``) of an image
    (any shape; a C-contiguous uint16 one is counted in one pass by the compiled ``_lut12`` where it was built)."""
    counts = code_counts()
    if (counts is not None and image.dtype == np.uint16 and image.flags.c_contiguous
            and 0 <= saturated_code <= 65535):
        at, zero = counts(image, int(saturated_code))
        n = at + zero if count == "both" else at
    else:
        n = int(np.count_nonzero(image >= saturated_code))
        if count == "both":
            n += int(np.count_nonzero(image == 0))
    return float(n) / float(image.size)


def select_highernosat(exposures_us: Sequence[int], target_us: float, over_sat: Mapping[int, float],
                       alpha: float = 0.01) -> int:
    """The paper's HigherNoSat; ``over_sat``: {exposure_us: saturated fraction} (only bh is looked at)."""
    exps = sorted(exposures_us)
    if target_us <= exps[0]:
        return exps[0]
    if target_us >= exps[-1]:
        return exps[-1]
    i = bisect_left(exps, target_us)
    if exps[i] == target_us:
        return exps[i]
    bh, bl = exps[i], exps[i - 1]
    return bh if over_sat[bh] <= alpha else bl


def select_upstream(exposures_us: Sequence[int], target_us: float, sat_both: Mapping[int, float]) -> int:
    """The authors' closer_least_sat; ``sat_both``: {exposure_us: fraction of pixels at 0 or 4094}."""
    exps = sorted(exposures_us)
    i = bisect_left(exps, target_us)
    if i >= len(exps):
        return exps[-1]
    if i > 0 and sat_both[exps[i]] > sat_both[exps[i - 1]]:
        return exps[i - 1]
    return exps[i]


def bounding_brackets(exposures_us: Sequence[int], target_us: float) -> tuple[int, int]:
    """(bl, bh) with bl <= target <= bh; both equal the nearest bracket outside the range or at an exact match."""
    exps = sorted(exposures_us)
    if target_us <= exps[0]:
        return exps[0], exps[0]
    if target_us >= exps[-1]:
        return exps[-1], exps[-1]
    i = bisect_right(exps, target_us)
    if exps[i - 1] == target_us:
        return exps[i - 1], exps[i - 1]
    return exps[i - 1], exps[i]
