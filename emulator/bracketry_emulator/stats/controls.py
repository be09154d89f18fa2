"""Control rows of a benchmark: what frames the AE methods' results without being an AE method.

- the **oracle** (non-causal: its step search reads the next step's images, :mod:`bracketry_emulator.ae.oracle`):
  the best exposure sequence found, per trajectory the best whole run among the step search's and every other row's
  (:mod:`bracketry_emulator.benchmark.oracle_rows`), an upper bound of the rows' successes;
- **constant exposures** ``constant-<ms>`` of a grid (:data:`CONTROL_CONSTANTS_MS`): the best of the grid is what a
  well-chosen fixed exposure achieves on this dataset, the worst a known-bad control the statistics should flag.

``--methods ...,controls`` (the keyword :data:`CONTROLS_KEYWORD`) adds the oracle and the grid's constants. The report
marks these rows and names the grid's best and worst constant (:func:`control_roles`), ranked by successful
trajectories, then median time before failure (longer first), then median RTE (smaller first).
"""

from __future__ import annotations

import math
import re
from collections.abc import Iterable

#: the keyword of ``--methods`` that adds the control rows
CONTROLS_KEYWORD = "controls"
#: methods that read the next step (not AE methods a camera could run)
NON_CAUSAL_METHODS: tuple[str, ...] = ("oracle",)
#: the constant exposures (ms) of the control grid: two stops apart, from far too short to far too long for daylight
#: brackets of 1..32 ms
CONTROL_CONSTANTS_MS: tuple[float, ...] = (0.0625, 0.25, 1.0, 4.0, 16.0, 64.0)

_CONSTANT = re.compile(r"^constant-(\d+(?:\.\d*)?|\.\d+)$")

NON_CAUSAL, CONSTANT, BEST_CONSTANT, WORST_CONSTANT = ("non-causal control", "control: constant",
                                                       "control: best constant", "control: worst constant")


def control_methods() -> list[str]:
    """The method ids :data:`CONTROLS_KEYWORD` stands for: the oracle, then the grid's constants."""
    return [*NON_CAUSAL_METHODS, *(f"constant-{ms:g}" for ms in CONTROL_CONSTANTS_MS)]


def constant_ms(method: str) -> float | None:
    """The exposure (ms) of a ``constant-<ms>`` method's name, else None."""
    m = _CONSTANT.match(method.lower())
    return float(m.group(1)) if m else None


def _median(values: Iterable[float]) -> float:
    vals = sorted(v for v in values if math.isfinite(v))
    if not vals:
        return math.nan
    n = len(vals)
    return vals[n // 2] if n % 2 else 0.5 * (vals[n // 2 - 1] + vals[n // 2])


def constant_rank_key(results: list[dict], method: str) -> tuple[float, float, float]:
    """Sort key of a constant (larger is better): (successful trajectories, median time before failure s, minus
    median RTE %); NaN medians rank last."""
    rs = [r for r in results if r["method"] == method]
    ok = float(sum(bool(r.get("success")) for r in rs))
    tbf = _median(float(r.get("time_before_failure_s", math.nan)) for r in rs)
    rte = _median(float(r.get("rte_pct", math.nan)) for r in rs)
    return ok, tbf if math.isfinite(tbf) else -math.inf, -rte if math.isfinite(rte) else -math.inf


def control_roles(results: list[dict], methods: list[str]) -> dict[str, str]:
    """{method: role} of the control rows among ``methods`` (others are left out): the non-causal ones, and every
    ``constant-<ms>``; with two constants or more, the best and the worst of them by :func:`constant_rank_key`
    (``results``: the benchmark's rows with method, success, time_before_failure_s, rte_pct)."""
    roles = {m: NON_CAUSAL for m in methods if m.lower() in NON_CAUSAL_METHODS}
    constants = [m for m in methods if constant_ms(m) is not None]
    roles.update({m: CONSTANT for m in constants})
    if len(constants) >= 2:
        ranked = sorted(constants, key=lambda m: (constant_rank_key(results, m), -float(constant_ms(m) or 0.0)))
        roles[ranked[-1]] = BEST_CONSTANT
        roles[ranked[0]] = WORST_CONSTANT
    return roles
