"""The bracket advisor: the scene's dynamic range, how much of it a bracket table covers, and a table for this light.

Inputs are the latest bracket frames of one camera as luminance arrays (see
:func:`bracketry_rig.monitor.core.luminance`) of one shape, each with its exposure. The scene's *radiance* is estimated
per pixel in DN per microsecond of exposure from the longest bracket that exposes it well (best signal to noise); a
pixel under-exposed in every bracket only has an upper bound (``low_dn / longest``), one over-exposed in every bracket a
lower bound (``high_dn / shortest``). A pixel is *covered* by a table when at least one of its exposures puts it in the
well-exposed window ``(low_dn, high_dn)`` of :func:`bracketry_rig.monitor.core.exposure_limits_dn`. Pure numpy, no I/O.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from bracketry_rig.monitor.core import WHITE_DN, exposure_limits_dn

#: radiance state of a pixel: measured, below every bracket (upper bound), above every bracket (lower bound)
MEASURED, BELOW, ABOVE = 0, -1, 1


def radiance_map(exposures_us: Sequence[float], lums: Sequence[np.ndarray], *,
                 white_dn: int = WHITE_DN) -> tuple[np.ndarray, np.ndarray]:
    """Per-pixel scene radiance from bracket frames.

    Args:
        exposures_us: exposure of each frame, microseconds.
        lums: luminance of each frame, float DN, all of one shape ``(h, w)``.
        white_dn: white level, DN.

    Returns:
        ``(radiance, state)``: ``(h, w)`` float64 radiance in DN/us (a bound where not measured) and ``(h, w)`` int8
        :data:`MEASURED` / :data:`BELOW` / :data:`ABOVE`.
    """
    if not exposures_us or len(exposures_us) != len(lums):
        raise ValueError("need one luminance array per exposure (at least one)")
    low_dn, high_dn = exposure_limits_dn(white_dn)
    order = np.argsort(np.asarray(exposures_us, dtype=np.float64))
    shape = lums[0].shape
    rad = np.full(shape, np.nan)
    for i in order:  # shortest first: a longer well-exposed bracket overwrites
        lum = np.asarray(lums[i], dtype=np.float64)
        if lum.shape != shape:
            raise ValueError(f"luminance shapes differ: {lum.shape} vs {shape}")
        good = (lum > low_dn) & (lum < high_dn)
        rad[good] = lum[good] / float(exposures_us[i])
    state = np.zeros(shape, np.int8)
    unmeasured = np.isnan(rad)
    e_short, e_long = float(exposures_us[order[0]]), float(exposures_us[order[-1]])
    over_short = np.asarray(lums[order[0]], dtype=np.float64) >= high_dn
    above = unmeasured & over_short
    below = unmeasured & ~over_short
    state[above], state[below] = ABOVE, BELOW
    rad[above] = high_dn / e_short
    rad[below] = max(low_dn, 1.0) / e_long
    return rad, state


def dynamic_range_stops(radiance: np.ndarray, *, tail_pct: float = 0.5) -> float:
    """The scene's dynamic range in stops: log2 of the ratio of the (100 - tail) and tail percentiles of radiance.

    Where pixels are clipped in every bracket the bounds enter, so the result is then a lower bound.
    """
    lo, hi = np.percentile(radiance, [tail_pct, 100.0 - tail_pct])
    return float(math.log2(max(hi, 1e-12) / max(lo, 1e-12)))


def coverage(lums: Sequence[np.ndarray], *, white_dn: int = WHITE_DN) -> float:
    """Fraction (0..1) of pixels well exposed in at least one of the bracket frames ``lums`` (one shape)."""
    low_dn, high_dn = exposure_limits_dn(white_dn)
    good = np.zeros(lums[0].shape, bool)
    for lum in lums:
        good |= (lum > low_dn) & (lum < high_dn)
    return float(good.mean())


def predicted_coverage(radiance: np.ndarray, state: np.ndarray, brackets_us: Sequence[float], *,
                       white_dn: int = WHITE_DN) -> float:
    """Fraction (0..1) of pixels a table ``brackets_us`` would expose well, from measured radiance only
    (pixels known only by a bound count as not covered)."""
    low_dn, high_dn = exposure_limits_dn(white_dn)
    good = np.zeros(radiance.shape, bool)
    for e in brackets_us:
        dn = radiance * float(e)
        good |= (dn > low_dn) & (dn < high_dn)
    return float((good & (state == MEASURED)).mean())


@dataclass(frozen=True)
class Advice:
    """What the advisor found for one camera or the rig.

    ``dynamic_range_stops``: the scene's range (a lower bound when ``clipped_share`` > 0); ``coverage``: share of
    pixels the current table exposes well; ``suggested_us``: a table (ascending, microseconds);
    ``suggested_coverage``: its predicted coverage; ``clipped_share``: pixels clipped in every current bracket.
    """

    dynamic_range_stops: float
    coverage: float
    suggested_us: tuple[int, ...]
    suggested_coverage: float
    clipped_share: float


def suggest_brackets(radiance: np.ndarray, state: np.ndarray, n_brackets: int, *, min_us: float, max_us: float,
                     white_dn: int = WHITE_DN, tail_pct: float = 0.5) -> tuple[int, ...]:
    """A table of ``n_brackets`` exposures (ascending, integer microseconds within ``min_us..max_us``) whose
    well-exposed windows cover the radiance between the ``tail_pct`` and ``100 - tail_pct`` percentiles.

    The longest bracket puts the dark end one stop above ``low_dn``, the shortest puts the bright end 1/3 stop below
    ``high_dn``; the ones between are spaced geometrically. When more than ``tail_pct`` % of the pixels are below
    (above) every current bracket the dark (bright) end is unknown and is taken 2 stops beyond its bound, so a few
    rounds of suggest-apply reach a scene far outside the current table. A scene narrower than the table keeps
    factor-2 steps around its middle.
    """
    if n_brackets < 1:
        raise ValueError("n_brackets must be >= 1")
    if not 0 < min_us <= max_us:
        raise ValueError(f"need 0 < min_us <= max_us, got {min_us}, {max_us}")
    low_dn, high_dn = exposure_limits_dn(white_dn)
    r_lo, r_hi = (float(v) for v in np.percentile(radiance, [tail_pct, 100.0 - tail_pct]))
    if float(np.mean(state == BELOW)) * 100.0 > tail_pct:
        r_lo /= 4.0
    if float(np.mean(state == ABOVE)) * 100.0 > tail_pct:
        r_hi *= 4.0
    r_lo, r_hi = max(r_lo, 1e-12), max(r_hi, 1e-12)
    e_long = 2.0 * low_dn / r_lo
    e_short = high_dn / (2 ** (1 / 3)) / r_hi
    if n_brackets == 1:
        table = [math.sqrt(e_short * e_long)]
    elif e_long / e_short < 2.0 ** (n_brackets - 1):
        mid = math.sqrt(e_short * e_long)
        table = [mid * 2.0 ** (i - (n_brackets - 1) / 2) for i in range(n_brackets)]
    else:
        # consecutive windows overlap by at least a stop: a range too wide for n brackets loses its two ends
        ratio = min((e_long / e_short) ** (1.0 / (n_brackets - 1)), high_dn / low_dn / 2.0)
        mid = math.sqrt(e_short * e_long)
        table = [mid * ratio ** (i - (n_brackets - 1) / 2) for i in range(n_brackets)]
    # shift a table that leaves the limits into them, then clip what still does not fit
    if table[-1] > max_us:
        table = [e * max_us / table[-1] for e in table]
    if table[0] < min_us:
        table = [e * min_us / table[0] for e in table]
    return tuple(round(min(max(e, min_us), max_us)) for e in table)


def advise(exposures_us: Sequence[float], lums: Sequence[np.ndarray], *, min_us: float, max_us: float,
           white_dn: int = WHITE_DN) -> Advice:
    """Dynamic range, coverage of the current table and a suggested table with as many brackets as the current.

    ``lums`` may come from several cameras concatenated along axis 0 (one shape per exposure).
    """
    rad, state = radiance_map(exposures_us, lums, white_dn=white_dn)
    table = suggest_brackets(rad, state, len(exposures_us), min_us=min_us, max_us=max_us, white_dn=white_dn)
    return Advice(dynamic_range_stops=round(dynamic_range_stops(rad), 2),
                  coverage=round(coverage(lums, white_dn=white_dn), 4), suggested_us=table,
                  suggested_coverage=round(predicted_coverage(rad, state, table, white_dn=white_dn), 4),
                  clipped_share=round(float(np.mean(state != MEASURED)), 4))
