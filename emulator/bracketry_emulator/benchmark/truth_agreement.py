"""Which verdicts the emulator changes: a benchmark on emulated images against the same benchmark on truth images.

``bracketry benchmark --images both`` runs every method twice on synthetic trajectories: closed loops on emulated
images (``OUT``) and on the world's renders at the chosen exposures (``OUT/truth``,
:mod:`~bracketry_emulator.ae.truth`).
This module compares the two result sets:

- per metric of the statistics (:data:`~bracketry_emulator.stats.mannwhitney.METRICS`) and method: the median over
  trajectories of the emulated and of the true value;
- per metric: Kendall's tau between the methods' emulated and true medians (1 = the same ranking);
- the verdicts against the reference (better / worse / equal, the report's Mann-Whitney with Bonferroni) of both
  runs: the share that agree and the list of those that flip.

Written as ``OUT/report/truth_agreement.json`` and ``truth_agreement.md``.
"""

from __future__ import annotations

import json
import math
from collections.abc import Sequence
from pathlib import Path

import numpy as np

from ..stats.mannwhitney import METRICS, verdict_table


def _per_metric(results: list[dict], methods: Sequence[str]) -> dict[str, dict[str, list[float]]]:
    return {key: {m: [float(r[key]) for r in results if r["method"] == m and key in r] for m in methods}
            for key in METRICS}


def _median(values: list[float]) -> float:
    finite = [v for v in values if math.isfinite(v)]
    return float(np.median(finite)) if finite else float("nan")


def kendall_tau(a: Sequence[float], b: Sequence[float]) -> float:
    """Kendall's tau-b of two paired sequences (NaN pairs dropped; NaN with fewer than 2 pairs or no variation)."""
    pairs = [(x, y) for x, y in zip(a, b, strict=True) if math.isfinite(x) and math.isfinite(y)]
    if len(pairs) < 2:
        return float("nan")
    from scipy.stats import kendalltau

    xs, ys = zip(*pairs, strict=True)
    if len(set(xs)) < 2 or len(set(ys)) < 2:
        return float("nan")
    return float(kendalltau(xs, ys).statistic)


def truth_agreement(emulated: list[dict], truth: list[dict], methods: Sequence[str], reference: str,
                    alpha: float) -> dict:
    """The comparison (module docstring) of two benchmarks' results (:class:`BenchmarkResult.results` rows)."""
    methods = list(methods)
    pe, pt = _per_metric(emulated, methods), _per_metric(truth, methods)
    ve, vt = verdict_table(pe, reference, alpha), verdict_table(pt, reference, alpha)
    per_metric: dict[str, dict] = {}
    taus: list[float] = []
    agree = total = 0
    flips: list[dict] = []
    for key, (label, higher) in METRICS.items():
        med_e = {m: _median(pe[key][m]) for m in methods}
        med_t = {m: _median(pt[key][m]) for m in methods}
        tau = kendall_tau([med_e[m] for m in methods], [med_t[m] for m in methods])
        if math.isfinite(tau):
            taus.append(tau)
        verdicts = {}
        for m in methods:
            if m == reference or key not in ve or key not in vt:
                continue
            a, b = ve[key][m].verdict, vt[key][m].verdict
            verdicts[m] = {"emulated": a, "truth": b}
            total += 1
            if a == b:
                agree += 1
            else:
                flips.append({"metric": key, "method": m, "emulated": a, "truth": b})
        per_metric[key] = {"label": label, "higher_is_better": higher, "kendall_tau": tau,
                           "methods": {m: {"emulated": med_e[m], "truth": med_t[m]} for m in methods},
                           "verdicts": verdicts}
    return {"reference": reference, "alpha": alpha, "methods": methods, "metrics": per_metric,
            "kendall_tau_median": float(np.median(taus)) if taus else float("nan"),
            "verdicts": {"agree": agree, "total": total, "share": agree / total if total else float("nan"),
                         "flips": flips}}


def _fmt(x: float) -> str:
    return "–" if not math.isfinite(x) else f"{x:.3g}"


def write_truth_agreement(doc: dict, report_dir: Path) -> tuple[Path, Path]:
    """``truth_agreement.json`` and ``truth_agreement.md`` in ``report_dir`` (created); returns their paths."""
    report_dir.mkdir(parents=True, exist_ok=True)
    jpath = report_dir / "truth_agreement.json"
    jpath.write_text(json.dumps(doc, indent=1) + "\n")
    lines = ["# Emulated vs truth images", "",
             f"Kendall tau over methods (median over metrics): {_fmt(doc['kendall_tau_median'])}; verdicts against "
             f"{doc['reference']} that agree: {doc['verdicts']['agree']}/{doc['verdicts']['total']}", "",
             "| metric | method | emulated | truth |", "|---|---|---|---|"]
    for m in doc["metrics"].values():
        for name, v in m["methods"].items():
            lines.append(f"| {m['label']} | {name} | {_fmt(v['emulated'])} | {_fmt(v['truth'])} |")
    lines += ["", "| metric | Kendall tau |", "|---|---|"]
    lines += [f"| {m['label']} | {_fmt(m['kendall_tau'])} |" for m in doc["metrics"].values()]
    if doc["verdicts"]["flips"]:
        lines += ["", "Verdicts that flip:", ""]
        lines += [f"- {f['method']}, {METRICS[f['metric']][0]}: {f['emulated']} (emulated) -> {f['truth']} (truth)"
                  for f in doc["verdicts"]["flips"]]
    mpath = report_dir / "truth_agreement.md"
    mpath.write_text("\n".join(lines) + "\n")
    return jpath, mpath
