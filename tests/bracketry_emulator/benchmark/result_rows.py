"""Benchmark result rows made from one number per (method, trajectory), for the statistics' and reports' tests."""

from __future__ import annotations


def metric_rows(values: dict[str, list[float]]) -> list[dict]:
    """Result rows: one per (trajectory ``t<k>``, method), every metric of the statistics set from ``values``
    (``{method: [v per trajectory]}``; coverage v, matches 100 v, RTE 10 - v, RRE 1 - v / 10, failure time 10 v)."""
    rows = []
    for method, vals in values.items():
        for k, v in enumerate(vals):
            rows.append({"trajectory": f"t{k}", "method": method, "coverage_mean": v, "matches_mean": 100 * v,
                         "rte_pct": 10 - v, "rre_deg_per_m": 1 - v / 10, "time_before_failure_s": 10 * v})
    return rows
