"""Tables of the benchmark report, as lists of rows (header first) ready for CSV, Markdown and HTML."""

from __future__ import annotations

import math

import numpy as np
from scipy.stats import kendalltau

from bracketry_emulator.metrics.failure_causes import CAUSES, failure_rows
from bracketry_emulator.metrics.manifest import success_counts
from bracketry_emulator.stats.controls import (
    BEST_CONSTANT,
    CONSTANT,
    NON_CAUSAL,
    WORST_CONSTANT,
    constant_ms,
    control_roles,
)
from bracketry_emulator.stats.mannwhitney import METRICS, SYMBOL, Comparison, compare_to_reference, verdict_table
from bracketry_emulator.stats.paired import PairedComparison, friedman, wilcoxon_to_reference, worst_rank
from bracketry_emulator.stats.stability import name_seed, shown_symbol, verdict_stability

RESULT_COLUMNS = ("trajectory", "subset", "method", "slam", "repeats", "n_frames", "success", "time_before_failure_s",
                  "duration_s", "tracked_fraction", "tracked_distance_fraction", "n_segments", "coverage_mean",
                  "matches_mean", "keypoints_mean", "rte_pct", "rte_pct_spread", "rre_deg_per_m",
                  "rre_deg_per_m_spread", "s_per_frame", "reference", "error", "oracle_source")


def _fmt(v, digits: int = 3) -> str:
    if isinstance(v, bool):
        return "yes" if v else "no"
    if isinstance(v, float):
        return "nan" if math.isnan(v) else f"{v:.{digits}f}"
    return str(v)


def _cell(r: dict, c: str) -> str:
    v = r.get(c)
    if c == "error":
        return "; ".join(r.get("errors") or ([v] if v else []))
    if c == "reference":
        return "" if v in (None, "groundtruth") else str(v)
    return "" if v is None else _fmt(v)


def results_table(results: list[dict]) -> list[list[str]]:
    """One row per (trajectory, method); with repeats: medians, spreads (max - min), failed repeats' errors."""
    return [list(RESULT_COLUMNS)] + [[_cell(r, c) for c in RESULT_COLUMNS] for r in results]


def oracle_sources(results: list[dict]) -> dict[str, int]:
    """{method: runs of it the oracle row took} over the oracle's runs (repeats too; ``oracle``: its own step
    search's), most taken first, then by name (:mod:`~bracketry_emulator.benchmark.oracle_rows`); empty without an
    oracle row."""
    counts: dict[str, int] = {}
    for r in results:
        for m in str(r.get("oracle_source") or "").split("/"):
            if m:
                counts[m] = counts.get(m, 0) + 1
    return dict(sorted(counts.items(), key=lambda kv: (-kv[1], kv[0])))


def failed_runs_table(results: list[dict]) -> list[list[str]]:
    """One row per (trajectory, method) with a failed SLAM run: how many repeats failed and why."""
    rows = [["trajectory", "method", "failed runs", "error"]]
    for r in results:
        errors = r.get("errors") or ([r["error"]] if r.get("error") else [])
        if errors:
            rows.append([r["trajectory"], r["method"], f"{len(errors)}/{r.get('repeats', 1)}", errors[0]])
    return rows


def windows_table(results: list[dict]) -> list[list[str]]:
    """One row per (trajectory, method, window): pairs, RTE(t, w) %, RRE(t, w) deg/m."""
    rows = [["trajectory", "method", "window_m", "n_pairs", "rte_pct", "rre_deg_per_m"]]
    for r in results:
        for w in r.get("windows", []):
            rows.append([r["trajectory"], r["method"], _fmt(w["window_m"], 0), str(w["n_pairs"]),
                         _fmt(w["rte_pct"]), _fmt(w["rre_deg_per_m"], 4)])
    return rows


def per_metric_values(results: list[dict], methods: list[str]) -> dict[str, dict[str, list[float]]]:
    """{metric: {method: per-trajectory values}} for the metrics of the statistics table."""
    return {key: {m: [float(r[key]) for r in results if r["method"] == m] for m in methods} for key in METRICS}


def summary_table(results: list[dict], methods: list[str]) -> list[list[str]]:
    """Per method: RTE and RRE (mean over trajectories of the per-trajectory means over windows, the paper's
    equations), median coverage (%) and matches, median time before failure, successful trajectories."""
    rows = [["method", "RTE (%)", "RRE (deg/m)", "coverage median (%)", "matches median",
             "time before failure median (s)", "successful", "distance tracked (%)"]]
    for m in methods:
        rs = [r for r in results if r["method"] == m]
        cov = [c for r in rs for c in r.get("coverage", [])]
        mat = [c for r in rs for c in r.get("matches", [])]
        rte = [r["rte_pct"] for r in rs if np.isfinite(r["rte_pct"])]
        rre = [r["rre_deg_per_m"] for r in rs if np.isfinite(r["rre_deg_per_m"])]
        dist = [r.get("tracked_distance_fraction", float("nan")) for r in rs]
        dist = [d for d in dist if np.isfinite(d)]
        tbf = [r["time_before_failure_s"] for r in rs if np.isfinite(r["time_before_failure_s"])]
        rows.append([m, _fmt(float(np.mean(rte)) if rte else float("nan"), 2),
                     _fmt(float(np.mean(rre)) if rre else float("nan"), 3),
                     _fmt(100 * float(np.median(cov)) if cov else float("nan"), 1),
                     _fmt(float(np.median(mat)) if mat else float("nan"), 0),
                     _fmt(float(np.median(tbf)) if tbf else float("nan"), 1),
                     f"{sum(bool(r['success']) for r in rs)}/{len(rs)}",
                     _fmt(100 * float(np.mean(dist)) if dist else float("nan"), 1)])
    return rows


def success_table(results: list[dict], methods: list[str]) -> list[list[str]]:
    """Successful trajectories per subset (rows) and method (columns); the subset's size in parentheses."""
    counts = success_counts(results)
    subsets = [*sorted(s for s in counts if s != "Total"), "Total"]
    rows = [["subset", *methods]]
    for s in subsets:
        total = max(c[1] for c in counts[s].values())
        rows.append([f"{s} ({total})", *[str(counts[s].get(m, (0, 0))[0]) for m in methods]])
    return rows


def stats_tables(results: list[dict], methods: list[str], reference: str, alpha: float
                 ) -> tuple[list[list[str]], list[list[str]], dict[str, dict[str, Comparison]]]:
    """(verdict table with ▲ better / ▼ worse / ≡ equal / ? unstable, p-value table with each verdict's stability,
    raw comparisons). Stability: :mod:`~bracketry_emulator.stats.stability` (bootstrap resamples of the
    trajectories). The verdict table holds symbols only, the result that must not move between two runs of the same
    benchmark; the stability, a share computed from the runs' values, is in the p-value table."""
    table = verdict_table(per_metric_values(results, methods), reference, alpha)
    others = [m for m in methods if m != reference]
    verdicts = [["metric", *others]]
    pvalues = [["metric", "method", "n", "median", f"median {reference}", "p two-sided", "p one-sided",
                "alpha (Bonferroni)", "verdict", "stability"]]
    for key, comps in table.items():
        label, higher = METRICS[key]

        def test(sample: dict[str, dict[str, float]], ref: str, higher: bool = higher) -> dict[str, Comparison]:
            return compare_to_reference({m: list(v.values()) for m, v in sample.items()}, ref, higher, alpha)

        share = verdict_stability(per_trajectory_values(results, methods, key), reference,
                                  {m: comps[m].verdict for m in others}, test, name_seed("mann-whitney", key))
        verdicts.append([label, *[shown_symbol(comps[m].verdict, share[m]) for m in others]])
        for m in others:
            c = comps[m]
            pvalues.append([label, m, str(c.n), _fmt(c.median), _fmt(c.median_ref), _fmt(c.p_two_sided, 4),
                            _fmt(c.p_one_sided, 4), _fmt(c.alpha_corrected, 4), c.verdict, _fmt(share[m], 2)])
    return verdicts, pvalues, table


#: error metrics a run that never tracked has no value of: in the paired test it ranks worst (not left out, which
#: would drop exactly the trajectories where a method failed)
WORST_RANK_METRICS = ("rte_pct", "rre_deg_per_m")


def per_trajectory_values(results: list[dict], methods: list[str], key: str,
                          impute_failures: bool = False) -> dict[str, dict[str, float]]:
    """{method: {trajectory: value}} of one metric (failed runs are NaN). With ``impute_failures``, a run without
    the value because it never tracked (its SLAM ran, the trajectory has a reference, it failed, and its error
    metric is NaN: no pose pair in any window) gets the worst rank instead (:func:`~..stats.paired.worst_rank`)."""
    higher = METRICS[key][1] if key in METRICS else True

    def value(r: dict) -> float:
        v = float(r.get(key, float("nan")))
        if (impute_failures and key in WORST_RANK_METRICS and np.isnan(v) and not r.get("error")
                and r.get("reference", "groundtruth") == "groundtruth" and not r.get("success", True)):
            return worst_rank(higher)
        return v

    return {m: {r["trajectory"]: value(r) for r in results if r["method"] == m} for m in methods}


def paired_tables(results: list[dict], methods: list[str], reference: str, alpha: float
                  ) -> tuple[list[list[str]], list[list[str]]]:
    """(Wilcoxon signed-rank vs ``reference`` per metric and method, Friedman across ``methods`` per metric)."""
    others = [m for m in methods if m != reference]
    wil = [["metric", "method", "pairs", f"median difference vs {reference}", "p two-sided", "effect r (rank-biserial)",
            "alpha (Bonferroni)", "verdict", "stability"]]
    fri = [["metric", "trajectories", "methods", "chi2", "p", "Kendall W", "mean ranks (1 = smallest)"]]
    for key, (label, higher) in METRICS.items():
        values = per_trajectory_values(results, methods, key, impute_failures=True)
        comps = wilcoxon_to_reference(values, reference, higher, alpha)

        def test(sample: dict[str, dict[str, float]], ref: str, higher: bool = higher
                 ) -> dict[str, PairedComparison]:
            return wilcoxon_to_reference(sample, ref, higher, alpha, n_tests=len(others), method="approx")

        share = verdict_stability(values, reference, {m: comps[m].verdict for m in others}, test,
                                  name_seed("wilcoxon", key))
        for m in others:
            c = comps[m]
            wil.append([label, m, str(c.n_pairs), _fmt(c.median_difference), _fmt(c.p_two_sided, 4),
                        _fmt(c.effect_r, 2), _fmt(c.alpha_corrected, 4), c.verdict, _fmt(share[m], 2)])
        f = friedman(values, methods)
        ranks = ", ".join(f"{m} {_fmt(v, 2)}" for m, v in f.mean_ranks.items())
        fri.append([label, str(f.n_blocks), str(len(f.methods)), _fmt(f.statistic, 2), _fmt(f.p_value, 4),
                    _fmt(f.kendall_w, 2), ranks])
    return wil, fri


def paired_verdicts_table(wilcoxon_rows: list[list[str]], methods: list[str], reference: str) -> list[list[str]]:
    """The Wilcoxon signed-rank verdicts of :func:`paired_tables` shaped as the Mann-Whitney verdict table (metrics
    as rows, compared methods as columns, ▲ ▼ ≡ – and ? for an unstable one; the stability is in the Wilcoxon
    rows): the paired test, which sees a difference that every trajectory shows in the same direction even when it
    is small against the spread between trajectories."""
    others = [m for m in methods if m != reference]
    by_metric: dict[str, dict[str, str]] = {}
    for label, method, *_rest, verdict, share in wilcoxon_rows[1:]:
        by_metric.setdefault(label, {})[method] = shown_symbol(verdict, float(share))
    return [["metric", *others],
            *[[label, *[v.get(m, SYMBOL["n/a"]) for m in others]] for label, v in by_metric.items()]]


#: metric key -> (axis label with unit, scale to that unit) of the box plots and the medians table
METRIC_UNITS: dict[str, tuple[str, float]] = {
    "coverage_mean": ("coverage (%)", 100.0),
    "matches_mean": ("matches to the map", 1.0),
    "rte_pct": ("RTE (%)", 1.0),
    "rre_deg_per_m": ("RRE (deg/m)", 1.0),
    "time_before_failure_s": ("time before failure (s)", 1.0),
    "tracked_distance_fraction": ("distance tracked (%)", 100.0),
}


def run_values(results: list[dict], method: str, key: str) -> list[float]:
    """Every value of ``key`` for ``method`` over trajectories and repeats (a trajectory's ``<key>_runs`` when it was
    repeated, else its one value), in the unit of :data:`METRIC_UNITS`; NaN kept."""
    scale = METRIC_UNITS.get(key, ("", 1.0))[1]
    out: list[float] = []
    for r in results:
        if r["method"] == method:
            runs = r.get(f"{key}_runs") or [r.get(key, float("nan"))]
            out += [scale * float(v) for v in runs]
    return out


def _median(values: list[float], scale: float = 1.0) -> float:
    a = np.asarray(values, float)
    a = a[np.isfinite(a)]
    return scale * float(np.median(a)) if len(a) else float("nan")


def medians_table(results: list[dict], methods: list[str]) -> list[list[str]]:
    """Per method: SLAM runs (trajectories x repeats), successful trajectories, and the medians over trajectories of
    each trajectory's value (its median over repeats), with the spread over repeats (max - min of a trajectory's
    repeats, median over trajectories) for RTE and RRE."""
    rows = [["method", "runs", "successful", "RTE median (%)", "RTE spread (%)", "RRE median (deg/m)",
             "RRE spread (deg/m)", "distance tracked median (%)", "coverage median (%)", "matches median",
             "failure time median (s)"]]
    for m in methods:
        rs = [r for r in results if r["method"] == m]

        def med(key: str, scale: float = 1.0, rs: list[dict] = rs) -> float:
            return _median([float(r.get(key, float("nan"))) for r in rs], scale)

        n_ok = sum(bool(r["success"]) for r in rs)
        rows.append([m, str(sum(int(r.get("repeats", 1)) for r in rs)), f"{n_ok}/{len(rs)}",
                     _fmt(med("rte_pct"), 2), _fmt(med("rte_pct_spread"), 2), _fmt(med("rre_deg_per_m"), 3),
                     _fmt(med("rre_deg_per_m_spread"), 3), _fmt(med("tracked_distance_fraction", 100.0), 1),
                     _fmt(med("coverage_mean", 100.0), 1), _fmt(med("matches_mean"), 0),
                     _fmt(med("time_before_failure_s"), 1)])
    return rows


def controls_table(results: list[dict], methods: list[str]) -> list[list[str]]:
    """The control rows among ``methods`` (:func:`~bracketry_emulator.stats.controls.control_roles`): role, constant
    exposure (ms), successful trajectories, median time before failure and RTE; header only without controls."""
    rows = [["method", "role", "exposure (ms)", "successful", "failure time median (s)", "RTE median (%)"]]
    roles = control_roles(results, methods)
    for m in methods:
        if m not in roles:
            continue
        rs = [r for r in results if r["method"] == m]
        ms = constant_ms(m)
        rows.append([m, roles[m], "per step" if ms is None else f"{ms:g}",
                     f"{sum(bool(r['success']) for r in rs)}/{len(rs)}",
                     _fmt(_median([float(r.get("time_before_failure_s", float("nan"))) for r in rs]), 1),
                     _fmt(_median([float(r.get("rte_pct", float("nan"))) for r in rs]), 2)])
    return rows


#: role -> the short mark a control row's name carries in the report's tables
ROLE_MARKS = {NON_CAUSAL: "non-causal", CONSTANT: "control", BEST_CONSTANT: "best constant",
              WORST_CONSTANT: "worst constant"}


def method_labels(results: list[dict], methods: list[str]) -> dict[str, str]:
    """{method: its name as the report's Markdown and HTML tables show it}: control rows carry a mark of their role
    (:data:`ROLE_MARKS`), e.g. ``oracle (non-causal)``, ``constant-0.0625 (worst constant)``."""
    roles = control_roles(results, methods)
    return {m: f"{m} ({ROLE_MARKS[roles[m]]})" if m in roles else m for m in methods}


def relabel(rows: list[list[str]], labels: dict[str, str], header: bool = False) -> list[list[str]]:
    """``rows`` with the method names of the first column (``header``: of the header row) as ``labels`` give them."""
    if header:
        return [[labels.get(c, c) for c in rows[0]], *rows[1:]]
    return [rows[0], *[[labels.get(r[0], r[0]), *r[1:]] for r in rows[1:]]]


#: the columns of ``failure_causes.csv``: one row per run that lost track (its first loss)
FAILURE_CAUSE_COLUMNS = ("trajectory", "method", "repeat", "time_s", "cause")
#: the paper's reading of its own failures, per method (BorealHDR benchmark, Results): what the cause table sits
#: beside; beyond these, glare failed every method on Campus1 and blur grows at the longest brackets
PAPER_FAILURE_READING = {
    "kim": "abrupt exposure changes (its exploration steps)",
    "wang": "abrupt exposure changes (its jumps); saturation once converged too high",
    "shim": "short exposures: least blur",
}


#: the paper's successful trajectories per method (BorealHDR benchmark, ORB-SLAM2, table of successful trajectories per
#: deployment day: Forest 42, Belair 8, Campus1 3, Campus2 6), of :data:`PAPER_TRAJECTORIES`
PAPER_SUCCESS = {"fix": 40, "ae30": 29, "ae50": 31, "ae70": 23, "shim": 39, "wang": 12, "kim": 19, "drl": 27}
PAPER_TRAJECTORIES = 59


def success_beside_paper(results: list[dict], methods: list[str]) -> tuple[list[list[str]], float]:
    """Per method of the paper's (:data:`PAPER_SUCCESS`, in ``methods`` order): our successful trajectories and share,
    the paper's, and Kendall's tau-b between the two counts over those methods (NaN with fewer than 3 of them or
    no spread on one side): how far the ranking of robustness agrees, a measurement, not a target.
    Returns (rows with a header, tau)."""
    counts = success_counts(results).get("Total", {})
    shared = [m for m in methods if m in PAPER_SUCCESS and m in counts]
    rows = [["method", "successful", "share (%)", f"paper (of {PAPER_TRAJECTORIES})", "paper share (%)"]]
    for m in shared:
        ok, n = counts[m]
        rows.append([m, f"{ok}/{n}", _fmt(100.0 * ok / n, 0), str(PAPER_SUCCESS[m]),
                     _fmt(100.0 * PAPER_SUCCESS[m] / PAPER_TRAJECTORIES, 0)])
    ours = [counts[m][0] / counts[m][1] for m in shared]
    paper = [PAPER_SUCCESS[m] for m in shared]
    tau = float("nan")
    if len(shared) >= 3 and len(set(ours)) > 1:
        tau = float(kendalltau(ours, paper).statistic)
    return rows, tau


def failure_causes_rows(results: list[dict]) -> list[list[str]]:
    """``failure_causes.csv``: :data:`FAILURE_CAUSE_COLUMNS`, one row per run that lost track (every failed repeat
    of a combined result; :func:`~bracketry_emulator.metrics.failure_causes.failure_rows`)."""
    rows = [list(FAILURE_CAUSE_COLUMNS)]
    for r in results:
        for f in failure_rows(r):
            rows.append([str(r["trajectory"]), str(r["method"]), str(int(f["repeat"])), _fmt(float(f["time_s"]), 2),
                         str(f["cause"])])
    return rows


def cause_table(results: list[dict], methods: list[str]) -> list[list[str]]:
    """Failed runs per cause (columns, :data:`~bracketry_emulator.metrics.failure_causes.CAUSES`) and method (rows),
    with the runs that lost track and the paper's reading of that method's failures (:data:`PAPER_FAILURE_READING`;
    ``-`` when it gives none)."""
    rows = [["method", *CAUSES, "lost", "the paper's reading"]]
    for m in methods:
        causes = [f["cause"] for r in results if r["method"] == m for f in failure_rows(r)]
        rows.append([m, *[str(causes.count(c)) for c in CAUSES], str(len(causes)),
                     PAPER_FAILURE_READING.get(m, "-")])
    return rows
