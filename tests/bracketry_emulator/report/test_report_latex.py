"""The report's LaTeX tables: well formed (balanced environments and braces, booktabs rules, the same column count
on every row, one row per method, names escaped) and the same figures as the CSV files beside them (their widths:
``test_report_latex_compile.py``)."""

from __future__ import annotations

import csv
import math
import re
from pathlib import Path

import pytest
from report_results import LONG_METHODS, synthetic_results

from bracketry_emulator.report import write_report
from bracketry_emulator.report.latex import SHORT_HEADS, escape

_UNESCAPE = [(r"\textbackslash{}", "\\"), (r"\textasciitilde{}", "~"), (r"\textasciicircum{}", "^")] + [
    ("\\" + c, c) for c in "&%$#_{}"]
_SYMBOLS = {r"$\blacktriangle$": "▲", r"$\blacktriangledown$": "▼", r"$\equiv$": "≡", "--": "–", "?": "?"}


def _unescape(cell: str) -> str:
    for a, b in _UNESCAPE:
        cell = cell.replace(a, b)
    return cell


def _csv(path: Path) -> list[list[str]]:
    with path.open(newline="") as fh:
        return list(csv.reader(fh))


def _heads(names: list[str]) -> list[str]:
    """The first head row of CSV column or metric names (their short heads where the tables have one)."""
    return [SHORT_HEADS[n][0] if n in SHORT_HEADS else escape(n) for n in names]


def _parse(tex: str) -> tuple[list[list[str]], list[list[str]]]:
    """(head rows, body rows) of the file's one tabular, checking that it is well formed on the way."""
    assert tex.startswith("% needs \\usepackage{booktabs,amssymb}")
    stack = []
    for m in re.finditer(r"\\(begin|end)\{(\w+)\}", tex):
        if m.group(1) == "begin":
            stack.append(m.group(2))
        else:
            assert stack and stack.pop() == m.group(2), f"unbalanced \\end{{{m.group(2)}}}"
    assert not stack, f"unclosed environments {stack}"
    depth = 0
    for c in re.sub(r"\\[{}]", "", tex):  # escaped braces are text
        depth += {"{": 1, "}": -1}.get(c, 0)
        assert depth >= 0, "a closing brace without its opening one"
    assert depth == 0
    commands = set(re.findall(r"\\([A-Za-z]+)", tex))
    assert commands <= {"usepackage", "begin", "end", "centering", "caption", "label", "toprule", "midrule",
                        "bottomrule", "textbf", "alpha", "blacktriangle", "blacktriangledown", "equiv",
                        "textbackslash", "textasciitilde", "textasciicircum", "small", "footnotesize", "setlength",
                        "tabcolsep", "circ"}, commands
    align = re.search(r"\\begin\{tabular\}\{([lcr]+)\}", tex)
    assert align is not None
    inner = tex[tex.index(r"\toprule") + len(r"\toprule"):tex.index(r"\bottomrule")]
    head, body = inner.split(r"\midrule")

    def cells(line: str) -> list[str]:
        line = line.strip()
        assert line.endswith(r"\\"), line
        return [c.strip() for c in re.split(r"(?<!\\)&", line[:-2])]

    heads = [cells(line) for line in head.strip().splitlines()]
    rows = [cells(line) for line in body.strip().splitlines()]
    for r in [*heads, *rows]:
        assert len(r) == len(align.group(1)), (r, align.group(1))
    return heads, rows


def _number(cell: str) -> float:
    return math.nan if cell in ("--", "nan", "") else float(cell)


@pytest.fixture(scope="module", params=["wide", "one_subset"])
def report(request, tmp_path_factory) -> tuple[Path, list[str], str]:
    root = tmp_path_factory.mktemp(f"latex_{request.param}")
    if request.param == "wide":  # 12 trajectories, two subsets, 8 methods with special characters, 3 repeats
        methods = LONG_METHODS
        results = synthetic_results(root, n_traj=12, methods=methods, repeats=3)
    else:  # one subset ("all"), one run per trajectory, the reference not first
        methods = ["fix", "ae50", "my_ae#1"]
        results = synthetic_results(root, n_traj=5, methods=methods, repeats=1, subsets=("all",))
    write_report(results, root, "ae50", methods, localisation="test")
    return root / "report", methods, "ae50"


def test_verdicts_tex_equals_verdicts_csv(report) -> None:
    rep, methods, reference = report
    heads, rows = _parse((rep / "latex" / "verdicts.tex").read_text())
    table = _csv(rep / "verdicts.csv")  # metrics as rows, compared methods as columns
    assert heads[0][1:] == _heads([r[0] for r in table[1:]])
    assert [_unescape(r[0]) for r in rows] == [m for m in methods if m != reference] == table[0][1:]
    for j, r in enumerate(rows):
        assert [_SYMBOLS[c] for c in r[1:]] == [t[1 + j] for t in table[1:]]
    assert f"\\textbf{{{escape(reference)}}}" in (rep / "latex" / "verdicts.tex").read_text()


def test_success_tex_equals_success_csv(report) -> None:
    rep, methods, _ = report
    heads, rows = _parse((rep / "latex" / "success.tex").read_text())
    table = _csv(rep / "success.csv")  # subsets as rows, methods as columns
    subsets = [r[0] for r in table[1:]]
    named = [f"{_unescape(a)} {b}" for a, b in zip(heads[0][1:], heads[1][1:])]  # name, then (size)
    if subsets[0].startswith("all ("):
        assert named == subsets[:1]  # no subsets: one column
    else:
        assert named == subsets and subsets[-1].startswith("Total (")
    assert [_unescape(r[0]) for r in rows] == methods == table[0][1:]
    for j, r in enumerate(rows):
        assert [int(c) for c in r[1:]] == [int(t[1 + j]) for t in table[1:len(r)]]


def test_medians_tex_equals_medians_csv(report) -> None:
    rep, methods, _ = report
    heads, rows = _parse((rep / "latex" / "medians.tex").read_text())
    table = _csv(rep / "medians.csv")
    assert heads[0][1:] == _heads(table[0][1:]) and table[0][0] == "method"
    assert [_unescape(r[0]) for r in rows] == methods == [t[0] for t in table[1:]]
    for r, t in zip(rows, table[1:]):
        assert r[2] == t[2] and int(r[1]) == int(t[1])  # runs, successful k/n
        for a, b in zip(r[3:], t[3:]):
            x, y = _number(a), _number(b)
            assert (math.isnan(x) and math.isnan(y)) or x == y, (a, b)


def test_medians_csv_is_the_median_over_trajectories_with_the_spread_over_repeats(tmp_path: Path) -> None:
    methods = ["ae50", "fix"]
    results = synthetic_results(tmp_path, n_traj=3, methods=methods, repeats=3, subsets=("all",))
    write_report(results, tmp_path, "ae50", methods, localisation="test")
    table = {r[0]: r for r in _csv(tmp_path / "report" / "medians.csv")}
    col = _csv(tmp_path / "report" / "medians.csv")[0].index
    for m in methods:
        rs = [r for r in results if r["method"] == m]
        rte = sorted(r["rte_pct"] for r in rs)[1]
        spread = sorted(max(r["rte_pct_runs"]) - min(r["rte_pct_runs"]) for r in rs)[1]
        assert float(table[m][col("RTE median (%)")]) == pytest.approx(rte, abs=0.006)
        assert float(table[m][col("RTE spread (%)")]) == pytest.approx(spread, abs=0.006)
        assert table[m][col("runs")] == "9"


def test_escape_names() -> None:
    assert escape("my_ae:Target%50&#1 {x} ~^\\") == (
        r"my\_ae:Target\%50\&\#1 \{x\} \textasciitilde{}\textasciicircum{}\textbackslash{}")
