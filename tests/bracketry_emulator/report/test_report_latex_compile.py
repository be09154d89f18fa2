"""The report's LaTeX tables compiled by pdflatex (TeX Live from Debian) in a two-column article with booktabs and
amssymb: no overfull box, and each table's own width within its float's (a ``table`` within the column, a ``table*``
within the text width)."""

from __future__ import annotations

import re
import shutil
import subprocess
from pathlib import Path

import pytest
from report_results import LONG_METHODS, synthetic_results

from bracketry_emulator.report import write_report

PAPER_METHODS = ["fix", "ae30", "ae50", "ae70", "shim", "wang", "kim"]
TABLES = ("verdicts", "success", "medians")

# Each table once in a box of its natural width (the float's caption left out), its width written to the log; then
# every table as the paper has it, between paragraphs of a two-column article.
_DOC = r"""\documentclass[twocolumn]{article}
\usepackage{booktabs,amssymb}
\begin{document}
\typeout{WIDTHS column=\the\columnwidth\space text=\the\textwidth}
%(measure)s
\section{Results}
%(body)s
\end{document}
"""
_MEASURE = r"""{\renewenvironment{table}{\setbox0\hbox\bgroup\renewcommand\caption[1]{}}{\egroup
  \typeout{TABLE %(name)s table \the\wd0}}%%
 \renewenvironment{table*}{\setbox0\hbox\bgroup\renewcommand\caption[1]{}}{\egroup
  \typeout{TABLE %(name)s table* \the\wd0}}%%
 \input{%(path)s}}"""
_TEXT = "The methods differ in how they expose the next frame. " * 12


@pytest.fixture(scope="module")
def reports(tmp_path_factory) -> dict[str, Path]:
    """Three reports from synthetic results: the paper's seven methods on four subsets, eight methods with long plug-in
    names and LaTeX special characters in two subsets with repeats, three methods without subsets."""
    root = tmp_path_factory.mktemp("latex_compile")
    cases = {"paper": (PAPER_METHODS, ("forest", "sun-shadow", "glare", "day-cycle"), 8, 1),
             "long_names": (LONG_METHODS, ("Campus_1", "Forest", "Forest"), 4, 2),
             "one_subset": (["fix", "ae50", "my_ae#1"], ("all",), 3, 1)}
    out = {}
    for name, (methods, subsets, n_traj, repeats) in cases.items():
        results = synthetic_results(root / name, n_traj=n_traj, methods=methods, repeats=repeats, subsets=subsets)
        write_report(results, root / name, "ae50", methods, localisation="test")
        out[name] = root / name / "report" / "latex"
    return out


def _compile(tex: Path) -> str:
    pdflatex = shutil.which("pdflatex")
    assert pdflatex is not None
    r = subprocess.run([pdflatex, "-interaction=nonstopmode", "-halt-on-error", tex.name], cwd=tex.parent,
                       capture_output=True, text=True, timeout=120)
    log = tex.with_suffix(".log").read_text(errors="replace")
    assert r.returncode == 0, log[-3000:]
    return log


@pytest.mark.latex
def test_tables_fit_a_two_column_article(reports: dict[str, Path], tmp_path: Path) -> None:
    widths: dict[tuple[str, str], tuple[str, float]] = {}
    for case, latex in reports.items():
        parts = {t: latex / f"{t}.tex" for t in TABLES}
        measure = "\n".join(_MEASURE % {"name": t, "path": p} for t, p in parts.items())
        body = "\n".join(f"{_TEXT}\n\n\\input{{{p}}}\n" for p in parts.values())
        doc = tmp_path / f"{case}.tex"
        doc.write_text(_DOC % {"measure": measure, "body": body})
        log = _compile(doc)
        overfull = re.findall(r"Overfull \\hbox \(([\d.]+)pt too wide\)[^\n]*", log)
        assert not overfull, f"{case}: overfull boxes of {overfull} pt"
        m = re.search(r"WIDTHS column=([\d.]+)pt text=([\d.]+)pt", log)
        assert m is not None
        column, text = float(m.group(1)), float(m.group(2))
        for name, env, width in re.findall(r"TABLE (\w+) (table\*?) ([\d.]+)pt", log):
            widths[case, name] = env, float(width)
            assert float(width) <= (column if env == "table" else text), (case, name, env, width, column, text)
        assert {n for c, n in widths if c == case} == set(TABLES)
    # the paper's seven methods: the verdicts and the successes fit one column; the 11 columns of medians span both
    assert widths["paper", "verdicts"][0] == widths["paper", "success"][0] == "table"
    assert widths["paper", "medians"][0] == "table*"
    assert widths["one_subset", "success"][0] == "table"
