"""Write the benchmark report: CSV tables, Markdown and a self-contained HTML page with the figures.

Files in ``<out>/report/``: ``results.csv`` (per trajectory and method), ``windows.csv`` (RTE/RRE per window),
``summary.csv``, ``medians.csv`` (per method: medians and spread over repeats), ``success.csv`` (per subset),
``success_paper.csv`` (per method of the paper's: our successes beside the paper's table), ``stats.csv`` (p-values,
verdicts and their stability), ``failure_causes.csv`` (trajectory, method, repeat, time_s,
cause: one row per run that lost track, :mod:`~bracketry_emulator.metrics.failure_causes`; with the cause x method
table in the report and ``latex/causes.tex``), ``verdicts.csv``, ``verdicts_paired.csv`` (each method's verdict as a
symbol, ``?`` where its stability over bootstrap resamples is low, :mod:`~bracketry_emulator.stats.stability`: the
shares themselves are in ``stats.csv`` and ``wilcoxon.csv``; the Wilcoxon signed-rank verdicts as the same table),
``controls.csv`` (with control rows), ``report.md``, ``report.html``, the PNG figures (box plots
per metric and method over trajectories and repeats ``box_<metric>.png``, per-frame coverage and matches box plots,
time before failure, exposure traces, qualitative grid) and ``latex/`` (the verdict, success and medians tables as
LaTeX, :mod:`~bracketry_emulator.report.latex`).
"""

from __future__ import annotations

import csv
import html
import json
import math
from pathlib import Path

import cv2
import numpy as np

from bracketry_emulator.report import html_page, plots
from bracketry_emulator.report.latex import write_latex
from bracketry_emulator.report.tables import (
    METRIC_UNITS,
    PAPER_TRAJECTORIES,
    cause_table,
    controls_table,
    failed_runs_table,
    failure_causes_rows,
    medians_table,
    method_labels,
    oracle_sources,
    paired_tables,
    paired_verdicts_table,
    relabel,
    results_table,
    run_values,
    stats_tables,
    success_beside_paper,
    success_table,
    summary_table,
    windows_table,
)
from bracketry_emulator.stats.controls import NON_CAUSAL_METHODS
from bracketry_emulator.stats.stability import N_RESAMPLES, STABLE_SHARE


def _write_csv(path: Path, rows: list[list[str]]) -> Path:
    with path.open("w", newline="") as fh:
        csv.writer(fh).writerows(rows)
    return path


def _markdown(rows: list[list[str]]) -> str:
    out = ["| " + " | ".join(rows[0]) + " |", "|" + "---|" * len(rows[0])]
    out += ["| " + " | ".join(r) + " |" for r in rows[1:]]
    return "\n".join(out)


def _qualitative_images(results: list[dict], methods: list[str]) -> tuple[str, dict[str, np.ndarray]]:
    from bracketry_emulator.vo.runner import list_side_images, read_gray8

    if not results:
        return "", {}
    traj = results[0]["trajectory"]
    images: dict[str, np.ndarray] = {}
    for m in methods:
        r = next((r for r in results if r["trajectory"] == traj and r["method"] == m), None)
        if r is None:
            continue
        try:
            frames = list_side_images(Path(r["run_dir"]), "left")
            if frames:
                images[m] = read_gray8(frames[len(frames) // 2][1])
                continue
        except Exception:
            pass
        preview = Path(r.get("vo_dir", "")) / "preview_left.png"  # SLAM was fed in memory: its kept middle frame
        img = cv2.imread(str(preview), cv2.IMREAD_UNCHANGED) if preview.is_file() else None
        if img is not None:
            images[m] = img
    return traj, images


def _oracle_text(results: list[dict], methods: list[str]) -> str:
    """The report's clause on the oracle row (empty without one): what it is and which runs it took."""
    if not any(m.lower() in NON_CAUSAL_METHODS for m in methods):
        return ""
    sources = oracle_sources(results)
    taken = (f"; runs taken (results.csv oracle_source): {', '.join(f'{m} {n}' for m, n in sources.items())}"
             if sources else "")
    return (" the oracle is NON-CAUSAL, the best exposure sequence found (no camera can run it: an upper reference, "
            "not a method): per trajectory and repeat, the best whole run among its own step search's (which reads "
            "the next step's images) and every other row's on that trajectory, ranked by success, then time before "
            "failure, then distance tracked, then RTE, so it keeps at least as many trajectories as any row, at no "
            f"SLAM run beyond its step search's{taken};")


def write_report(results: list[dict], out_dir: str | Path, reference: str, methods: list[str],
                 alpha: float = 0.05, localisation: str = "not given", stats_methods: list[str] | None = None,
                 stages: dict | None = None, plugins: list[str] | None = None) -> dict[str, Path]:
    """Write every table and figure; returns {name: path}. ``plugins``: per AE plugin "name: source, options"
    (:meth:`~bracketry_emulator.ae.registry.MethodSpec.describe`), printed in the introduction.
    ``localisation``: one line naming the SLAM backend and
    its settings (the benchmark's :func:`~bracketry_emulator.benchmark.slam.describe`).
    ``stats_methods``: the methods the statistical tests cover (default: all of ``methods``). ``stages``: where the
    benchmark's time went (:func:`~bracketry_emulator.benchmark.orchestrate.stage_document`): the report ends with
    its stage table (also ``stages.csv``)."""
    rep = Path(out_dir) / "report"
    rep.mkdir(parents=True, exist_ok=True)
    files: dict[str, Path] = {}
    res_rows = results_table(results)
    sum_rows = summary_table(results, methods)
    suc_rows = success_table(results, methods)
    tested = [m for m in methods if m in set(stats_methods or methods)]
    verdicts, pvalues, _ = stats_tables(results, tested, reference, alpha)
    wilcoxon_rows, friedman_rows = paired_tables(results, tested, reference, alpha)
    files["results.csv"] = _write_csv(rep / "results.csv", res_rows)
    files["windows.csv"] = _write_csv(rep / "windows.csv", windows_table(results))
    files["summary.csv"] = _write_csv(rep / "summary.csv", sum_rows)
    med_rows = medians_table(results, methods)
    files["medians.csv"] = _write_csv(rep / "medians.csv", med_rows)
    files["success.csv"] = _write_csv(rep / "success.csv", suc_rows)
    paper_rows, paper_tau = success_beside_paper(results, methods)
    if len(paper_rows) > 1:
        files["success_paper.csv"] = _write_csv(rep / "success_paper.csv", paper_rows)
    files["verdicts.csv"] = _write_csv(rep / "verdicts.csv", verdicts)
    files["stats.csv"] = _write_csv(rep / "stats.csv", pvalues)
    files["wilcoxon.csv"] = _write_csv(rep / "wilcoxon.csv", wilcoxon_rows)
    paired_verdicts = paired_verdicts_table(wilcoxon_rows, tested, reference)
    files["verdicts_paired.csv"] = _write_csv(rep / "verdicts_paired.csv", paired_verdicts)
    files["friedman.csv"] = _write_csv(rep / "friedman.csv", friedman_rows)
    failed_rows = failed_runs_table(results)
    files["failed_runs.csv"] = _write_csv(rep / "failed_runs.csv", failed_rows)
    files["failure_causes.csv"] = _write_csv(rep / "failure_causes.csv", failure_causes_rows(results))
    cause_rows = cause_table(results, methods)
    ctl_rows = controls_table(results, methods)
    if len(ctl_rows) > 1:
        files["controls.csv"] = _write_csv(rep / "controls.csv", ctl_rows)
    labels = method_labels(results, methods)
    files.update(write_latex(rep, verdicts, suc_rows, med_rows, reference, alpha, cause_rows))

    box_figs: list[tuple[str, str]] = []
    for key, (label, _scale) in METRIC_UNITS.items():
        values = {m: run_values(results, m, key) for m in methods}
        name = f"box_{key}.png"
        what = label.split(" (")[0]
        files[name] = plots.box_plot(values, label, f"{what[0].upper()}{what[1:]}",
                                     rep / name, horizontal=True)
        box_figs.append((name, f"{label} per method over trajectories and repeats"))

    figs: list[tuple[str, str]] = []  # per-frame figures
    cov = {m: [100 * c for r in results if r["method"] == m for c in r.get("coverage", [])] for m in methods}
    files["coverage.png"] = plots.box_plot(cov, "filled cells (%)", "Keypoint coverage, 20x20 grid",
                                           rep / "coverage.png")
    figs.append(("coverage.png", "Keypoint coverage (20x20 grid) per frame"))
    mat = {m: [c for r in results if r["method"] == m for c in r.get("matches", [])] for m in methods}
    files["matches.png"] = plots.box_plot(mat, "matches to the map", "Matches to the map", rep / "matches.png")
    figs.append(("matches.png", "Matches to the map per frame"))
    tbf = {m: [r["time_before_failure_s"] for r in results if r["method"] == m] for m in methods}
    files["failure.png"] = plots.box_plot(tbf, "time before failure (s)", "Time before first failure",
                                          rep / "failure.png")
    figs.append(("failure.png", "Time before the first VO failure, per trajectory"))
    look_figs: list[tuple[str, str]] = []  # exposure traces and the qualitative strip
    for traj in sorted({r["trajectory"] for r in results})[:4]:
        traces = {r["method"]: plots.read_exposure_trace(Path(r["run_dir"]))
                  for r in results if r["trajectory"] == traj}
        name = f"exposure_{traj}.png"
        files[name] = plots.exposure_traces(traces, f"Exposure traces: {traj}", rep / name)
        look_figs.append((name, f"Exposure chosen by each method on {traj}"))
    traj, images = _qualitative_images(results, methods)
    if images:
        files["qualitative.png"] = plots.qualitative_grid(images, f"{traj}: middle frame, left camera",
                                                          rep / "qualitative.png")
        look_figs.append(("qualitative.png", f"The same frame of {traj} under each method"))

    n_traj = len({r["trajectory"] for r in results})
    intro = (f"{n_traj} trajectories x {len(methods)} methods. Reference: **{reference}**. Mann-Whitney U, "
             f"alpha = {alpha} with Bonferroni over {max(len(tested) - 1, 1)} methods "
             f"(▲ better, ▼ worse, ≡ not different from {reference}; ? a verdict given by fewer than "
             f"{STABLE_SHARE:.0%} of {N_RESAMPLES} bootstrap resamples of the trajectories, a verdict resting on "
             f"noise: stats.csv and wilcoxon.csv give each verdict's share). RTE/RRE: evo RPE, windows "
             f"{_window_text(results)} m, per segment, paper equations; distance tracked = share of the reference "
             f"path covered by tracked segments. Localisation: {localisation}.")
    untested = [m for m in methods if m not in tested]
    if untested:
        intro += (f" Reported but not in the statistics: {', '.join(untested)} (--stats-methods all adds them to the "
                  f"tests and the Bonferroni count).")
    if plugins:
        intro += " Plugins (name: source, options): " + "; ".join(plugins) + "."
    if len(ctl_rows) > 1:
        intro += " Control rows (marked):" + _oracle_text(results, methods) + (
            " constant exposures frame the results, the grid's best and worst ranked by successful trajectories, "
            "then time before failure, then RTE.")
    intro += (" Paired tests (every method runs on the same trajectories): Wilcoxon signed-rank against the reference "
              "with the rank-biserial effect r (a run that never tracked ranks worst on RTE and RRE instead of being "
              "left out), and Friedman across methods with Kendall's W.")
    no_ref = sorted({r["reference"] for r in results if str(r.get("reference", "")).startswith("no reference")})
    if no_ref:
        intro += " RTE/RRE: " + "; ".join(no_ref) + "."
    verdict_title = "Statistical difference with " + reference
    paired_title = f"Paired difference with {reference} (Wilcoxon signed-rank, Bonferroni)"
    failed_title = "Failed SLAM runs (left out of the statistics)"
    # at a glance (in this order), then the long tables (folded in the HTML page)
    suc_shown, sum_shown, med_shown = (relabel(suc_rows, labels, header=True), relabel(sum_rows, labels),
                                       relabel(med_rows, labels))
    glance = [(verdict_title, relabel(verdicts, labels, header=True)),
              (paired_title, relabel(paired_verdicts, labels, header=True)),
              *([("Control rows", ctl_rows)] if len(ctl_rows) > 1 else []),
              *([(failed_title, failed_rows)] if len(failed_rows) > 1 else []),
              ("Successful trajectories per subset", suc_shown),
              *([(f"Successful trajectories beside the paper's (ORB-SLAM2, {PAPER_TRAJECTORIES} trajectories; "
                  f"Kendall's tau of the counts {_fmt_tau(paper_tau)})", relabel(paper_rows, labels))]
                if len(paper_rows) > 1 else []),
              ("Why runs lost track (cause of the first loss) beside the paper's reading", relabel(cause_rows, labels)),
              ("Summary", sum_shown),
              ("Medians and spread over repeats", med_shown)]
    folded = [("Per trajectory", res_rows), ("Tests", pvalues),
              ("Paired: Wilcoxon signed-rank against " + reference, wilcoxon_rows),
              ("Paired: Friedman across methods", friedman_rows)]
    sections = [*glance, *folded]
    md = ["# Auto-exposure benchmark", "", intro, "", f"## {verdict_title}", "", _markdown(glance[0][1]), "",
          f"## {paired_title}", "", _markdown(glance[1][1]), "",
          "## Metrics per method", ""] + [f"![{cap}]({name})\n" for name, cap in box_figs]
    for title, rows in sections[2:]:
        md += [f"## {title}", "", _markdown(rows), ""]
    md += ["## Figures", ""] + [f"![{cap}]({name})\n" for name, cap in [*look_figs, *figs]]
    stage_rows, stage_text = _stage_section(stages)
    if stage_rows:
        files["stages.csv"] = _write_csv(rep / "stages.csv", stage_rows)
        md += ["## Where the time went", "", stage_text, "", _markdown(stage_rows), ""]
    files["report.md"] = rep / "report.md"
    files["report.md"].write_text("\n".join(md))
    hp = html_page
    body = [hp.section(verdict_title, hp.verdict_legend(reference)
                       + hp.table(hp.by_method(glance[0][1]), verdict_cells=True)),
            hp.section("Metrics per method", hp.figures(box_figs)),
            hp.section(paired_title, hp.table(hp.by_method(glance[1][1]), verdict_cells=True))]
    body += [hp.section(title, hp.table(hp.by_method(rows) if rows is suc_shown else rows))
             for title, rows in glance[2:]]
    if look_figs:
        body.append(hp.section("Exposure and images", hp.figures(look_figs)))
    body.append("<h2>Details</h2>")
    body += [hp.section(title, hp.table(rows), folded=True) for title, rows in folded]
    body.append(hp.section("Per-frame figures", hp.figures(figs), folded=True))
    if stage_rows:
        body.append(hp.section("Where the time went", f"<p>{html.escape(stage_text)}</p>{hp.table(stage_rows)}",
                               folded=True))
    files["report.html"] = rep / "report.html"
    files["report.html"].write_text(hp.document("Auto-exposure benchmark", intro, body))
    files["results.json"] = rep / "results.json"
    files["results.json"].write_text(json.dumps(results, indent=1, default=float))
    return files


def _stage_section(doc: dict | None) -> tuple[list[list[str]], str]:
    """The stage table and its one-paragraph legend (machine, trajectory minutes, cached runs)."""
    from bracketry_emulator.stages import machine_line, stage_rows

    if not doc:
        return [], ""
    rows = stage_rows(doc["stages"], float(doc.get("trajectory_s", 0.0)), doc.get("wall_s"))
    minutes = float(doc.get("trajectory_s", 0.0)) / 60.0
    cached = int(doc.get("runs_cached", 0))
    text = (f"Measured on {machine_line(doc.get('machine', {}))}. {minutes:.2f} trajectory-minutes benchmarked; "
            "seconds are summed over the threads and processes that did the work (stages overlap, so they do not "
            "add up to the wall clock); SLAM = each run's process from start to exit (paced runs wait for their "
            "frames' time) and its CPU time.")
    if doc.get("slam_late_s") is not None:
        text += (f" Paced SLAM runs fell behind their real-time clock by up to {doc['slam_late_s']:.1f} s (a frame fed"
                 " late when the machine could not keep up).")
    if cached:
        text += f" {cached} of {doc.get('runs', cached)} SLAM runs came from the cache (no time spent now)."
    return rows, text


def _fmt_tau(tau: float) -> str:
    return "n/a: fewer than 3 of its methods, or equal counts" if math.isnan(tau) else f"{tau:.2f}"


def _window_text(results: list[dict]) -> str:
    ws = sorted({w["window_m"] for r in results for w in r.get("windows", [])})
    if not ws:
        return "(none)"
    return f"{ws[0]:g}..{ws[-1]:g}" if len(ws) > 1 else f"{ws[0]:g}"
