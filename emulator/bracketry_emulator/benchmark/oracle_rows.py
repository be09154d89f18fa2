"""The oracle row of a benchmark: per (trajectory, repeat), the best whole run among its candidates.

The oracle (method id ``oracle``, a non-causal control) is the best exposure sequence found for a trajectory. Its
candidates on a (trajectory, repeat) are the closed-loop run of its step search (:mod:`bracketry_emulator.ae.oracle`,
which proposes one sequence by a look-ahead score) and the run of every other row of the same benchmark (AE methods,
constants, plug-ins) on the same trajectory and repeat. Its row is the candidate that ranks first by
:func:`run_rank_key`, the order of the benchmark's robustness headline: success (the run never lost track), then
time before failure, then distance tracked, then RTE (smaller first), each as
:func:`~bracketry_emulator.metrics.evaluate.evaluate_run` gives it; a tie goes to the step search's own run, then
to the row first in the benchmark's order. ``oracle_source`` names the candidate taken (``oracle``: its own run).

So the oracle's successes, on every suite and whatever the seed (ORB-SLAM3 is not deterministic run to run), are at
least those of any row benchmarked beside it: it is an upper bound of the rows by construction (per run; combined
over repeats, a row's success is the majority of its repeats whose SLAM ran, so a row with crashed SLAM runs counts
over fewer repeats). Cost: no SLAM run beyond the step search's own (the other candidates are the benchmark's rows).
Benchmarked alone, its row is its own run.
"""

from __future__ import annotations

import math
from typing import Any

from bracketry_emulator.stats.controls import NON_CAUSAL_METHODS

#: the oracle's method id (:data:`~bracketry_emulator.stats.controls.NON_CAUSAL_METHODS`)
ORACLE = NON_CAUSAL_METHODS[0]
#: the fields of the oracle's own run its row keeps whatever candidate it takes: who and which run it is (its cache
#: key) and what its own step search cost (``stages``, ``cached``)
OWN_FIELDS = ("trajectory", "subset", "method", "repeat", "key", "stages", "cached")


def _finite(v: Any, sign: float = 1.0) -> float:
    """``sign * v`` as a float, or -inf when ``v`` is missing or not finite (ranks last)."""
    try:
        f = float(v)
    except (TypeError, ValueError):
        return -math.inf
    return sign * f if math.isfinite(f) else -math.inf


def run_rank_key(run: dict[str, Any]) -> tuple[float, float, float, float]:
    """Sort key of one run's result (larger is better): (success 1/0, time before failure s, distance tracked
    fraction, minus RTE %); a missing or NaN value (a failed SLAM run's) ranks last."""
    ok = 0.0 if run.get("error") else float(bool(run.get("success")))
    return (ok, _finite(run.get("time_before_failure_s")), _finite(run.get("tracked_distance_fraction")),
            _finite(run.get("rte_pct"), -1.0))


def oracle_best_runs(runs: list[dict[str, Any]], oracle: str = ORACLE) -> list[dict[str, Any]]:
    """``runs`` (one result per (trajectory, method, repeat): dicts with trajectory, method, repeat and the
    metrics of :func:`run_rank_key`) with every ``oracle`` row replaced by the best run of its (trajectory, repeat)
    (module docstring): the candidate's metrics, run and SLAM folders, with the oracle's :data:`OWN_FIELDS` and
    ``oracle_source`` (the candidate's method). Other rows and their order are unchanged; the input is not
    modified."""
    groups: dict[tuple[str, int], list[dict[str, Any]]] = {}
    for r in runs:
        groups.setdefault((r["trajectory"], int(r.get("repeat", 0))), []).append(r)
    out = []
    for r in runs:
        if r["method"] != oracle:
            out.append(r)
            continue
        others = [c for c in groups[(r["trajectory"], int(r.get("repeat", 0)))] if c["method"] != oracle]
        best = r
        for c in others:  # strictly better only: a tie keeps the own run, then the row first in the order
            if run_rank_key(c) > run_rank_key(best):
                best = c
        row = {k: v for k, v in best.items() if k not in OWN_FIELDS and k != "oracle_source"}
        out.append({**{k: r[k] for k in OWN_FIELDS if k in r}, **row, "oracle_source": best["method"]})
    return out
