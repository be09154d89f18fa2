"""LaTeX forms of the report's tables, for pasting into a paper (``report/latex/*.tex``).

Each file is one float holding a ``tabular`` with booktabs rules (``\\toprule``, ``\\midrule``, ``\\bottomrule``);
the verdicts use amssymb's ``$\\blacktriangle$`` (better than the reference), ``$\\blacktriangledown$`` (worse) and
``$\\equiv$`` (not different). Nothing else is needed in the preamble: ``\\usepackage{booktabs,amssymb}``. One row
per method (a table grows downwards with the methods); the cells are the same figures as the CSV files beside them
(``nan`` and ``n/a`` become ``--``). Method, subset and metric names are escaped.

Width: short column heads on two rows (name, then unit or the subset's size; the caption says what each is), set
``\\small`` (``\\tabcolsep`` 4 pt) or ``\\footnotesize`` (3 pt). A table whose estimated width
(:func:`estimate_width_pt`, Computer Modern widths, with a margin) fits :data:`COLUMN_WIDTH_PT` (one column of a
two-column article, the narrowest of the common classes) is a ``table``; a wider one is a full-width ``table*``
(:data:`LAYOUTS`). Checked by compiling them in a two-column
article with pdflatex (``tests/bracketry_emulator/report/test_report_latex_compile.py``): no overfull box.
"""

from __future__ import annotations

import re
from pathlib import Path

from bracketry_emulator.stats.mannwhitney import SYMBOL
from bracketry_emulator.stats.stability import UNSTABLE

_ESCAPES = {"\\": r"\textbackslash{}", "&": r"\&", "%": r"\%", "$": r"\$", "#": r"\#", "_": r"\_", "{": r"\{",
            "}": r"\}", "~": r"\textasciitilde{}", "^": r"\textasciicircum{}"}

#: verdict symbol of the CSV -> its LaTeX command (amssymb)
LATEX_SYMBOL = {SYMBOL["better"]: r"$\blacktriangle$", SYMBOL["worse"]: r"$\blacktriangledown$",
                SYMBOL["equal"]: r"$\equiv$", SYMBOL["n/a"]: "--", UNSTABLE: "?"}

PREAMBLE = "% needs \\usepackage{booktabs,amssymb}\n"

#: ``\\columnwidth`` of ``\\documentclass[twocolumn]{article}`` (10 pt, letter paper) in pt: the narrowest column of
#: the common two-column classes (IEEEtran's is 252 pt)
COLUMN_WIDTH_PT = 229.5
#: ``\\textwidth`` of the same article (pt): what a ``table*`` spans
TEXT_WIDTH_PT = 469.0
#: the settings tried in turn, the first whose estimated width fits its float's width taken: (float, size command,
#: size relative to the document's 10 pt, ``\\tabcolsep`` in pt); none fitting, the last
LAYOUTS = (("table", r"\small", 0.9, 4.0), ("table", r"\footnotesize", 0.8, 3.0),
           ("table*", r"\small", 0.9, 4.0), ("table*", r"\footnotesize", 0.8, 3.0))
#: the estimate's margin: measured widths were up to 5 % above the estimate (the test compiles them)
ESTIMATE_MARGIN = 1.08
SMALL = 0.9
TABCOLSEP_PT = 4.0

# Computer Modern Roman 10 pt advance widths (pt) of the characters the tables hold; any other counts as "M"
_CM_WIDTH = {**dict.fromkeys("0123456789", 5.0), **dict.fromkeys("abdghknopquv", 5.6), **dict.fromkeys("ceft", 4.4),
             **dict.fromkeys("ijl", 2.8), "m": 8.3, "r": 3.9, "s": 3.9, "w": 7.2, "x": 5.3, "y": 5.3, "z": 4.4,
             **dict.fromkeys("ABCDEFGHKLNOPQRSTUVXYZ", 7.5), "I": 3.6, "J": 5.1, "M": 9.2, "W": 10.3, " ": 3.3,
             ".": 2.8, ",": 2.8, ":": 2.8, ";": 2.8, "(": 3.9, ")": 3.9, "/": 5.0, "-": 3.3, "_": 5.0, "%": 8.3,
             "&": 7.8, "#": 8.3, "$": 5.0, "{": 5.0, "}": 5.0, "~": 5.0, "^": 5.0, "\\": 5.0, "+": 7.8, "=": 7.8}
_MACRO_WIDTH = {r"$\blacktriangle$": "M", r"$\blacktriangledown$": "M", r"$\equiv$": "M", "--": "0",
                r"\textbackslash{}": "\\", r"\textasciitilde{}": "~", r"\textasciicircum{}": "^", "$-$": "+",
                "$^\\circ$": "-"}

#: short two-row heads (name, unit) of the CSV columns and metrics; a column not listed keeps its name on the first row
SHORT_HEADS = {
    "runs": ("runs", ""), "successful": ("succ.", ""),
    "RTE median (%)": ("RTE", "(\\%)"), "RTE spread (%)": ("RTE", "spr."),
    "RRE median (deg/m)": ("RRE", "($^\\circ$/m)"), "RRE spread (deg/m)": ("RRE", "spr."),
    "distance tracked median (%)": ("dist.", "(\\%)"), "coverage median (%)": ("cov.", "(\\%)"),
    "matches median": ("match.", ""), "failure time median (s)": ("fail", "(s)"),
    "Coverage": ("cov.", ""), "# Matches": ("match.", ""), "Failure Time": ("fail", "time"),
}
_HEAD_NOTES = {
    "runs": "runs: SLAM runs", "successful": "succ.: successful runs",
    "RTE median (%)": "RTE (\\%) and RRE ($^\\circ$/m): medians over trajectories",
    "RTE spread (%)": "spr.: their spread over repeats (max $-$ min, median over trajectories)",
    "distance tracked median (%)": "dist.: share of the reference path tracked",
    "coverage median (%)": "cov.: image coverage of the tracked features",
    "matches median": "match.: matches to the map per frame", "failure time median (s)": "fail: time before failure",
}


def escape(text: str) -> str:
    """``text`` with LaTeX's special characters escaped (for names: methods, subsets, metrics)."""
    return "".join(_ESCAPES.get(c, c) for c in str(text))


def _number(cell: str) -> str:
    return "--" if cell in ("", "nan", "n/a") else escape(cell)


def cell_width_pt(cell: str, scale: float = SMALL) -> float:
    """Estimated width (pt) of a table cell's LaTeX text set at ``scale`` x 10 pt (rounded up: Computer Modern's widths
    of its characters, bold 10 % wider, any character not known as wide as an "M")."""
    bold = 1.0
    m = re.fullmatch(r"\\textbf\{(.*)\}", cell)
    if m:
        cell, bold = m.group(1), 1.1
    for macro, like in _MACRO_WIDTH.items():
        cell = cell.replace(macro, like)
    cell = re.sub(r"\\(.)", r"\1", cell)  # an escaped character: its own width
    return scale * bold * sum(_CM_WIDTH.get(c, _CM_WIDTH["M"]) for c in cell)


def estimate_width_pt(rows: list[list[str]], scale: float = SMALL, tabcolsep_pt: float = TABCOLSEP_PT) -> float:
    """Estimated width (pt) of a ``tabular`` of ``rows`` (LaTeX cells, heads included): the widest cell of each column
    plus ``tabcolsep_pt`` on each side."""
    n = max(len(r) for r in rows)
    return sum(max(cell_width_pt(r[j], scale) for r in rows if j < len(r)) + 2 * tabcolsep_pt for j in range(n))


def tabular(heads: list[list[str]], rows: list[list[str]], caption: str, label: str, align: str | None = None) -> str:
    """A float with one booktabs ``tabular``: ``heads`` (the head rows) and ``rows`` are LaTeX cells (already
    escaped). The first of :data:`LAYOUTS` whose estimated width fits: a ``table`` of one column
    (:data:`COLUMN_WIDTH_PT`), else a full-width ``table*`` (:data:`TEXT_WIDTH_PT`)."""
    n = len(heads[0])
    align = align or "l" + "r" * (n - 1)
    env, size, _, sep_pt = next(
        (lay for lay in LAYOUTS if ESTIMATE_MARGIN * estimate_width_pt([*heads, *rows], lay[2], lay[3])
         <= (COLUMN_WIDTH_PT if lay[0] == "table" else TEXT_WIDTH_PT)), LAYOUTS[-1])
    lines = [PREAMBLE.rstrip("\n"), f"\\begin{{{env}}}", r"\centering", f"\\caption{{{caption}}}",
             f"\\label{{{label}}}", size, f"\\setlength{{\\tabcolsep}}{{{sep_pt:g}pt}}",
             f"\\begin{{tabular}}{{{align}}}", r"\toprule"]
    lines += [" & ".join(h) + r" \\" for h in heads]
    lines += [r"\midrule"]
    lines += [" & ".join(r) + r" \\" for r in rows]
    lines += [r"\bottomrule", r"\end{tabular}", f"\\end{{{env}}}", ""]
    return "\n".join(lines)


def _heads(names: list[str]) -> tuple[list[list[str]], list[str]]:
    """(two head rows, the caption's notes) of CSV column or metric names: :data:`SHORT_HEADS` where known (a second
    row only when some column has one), the escaped name otherwise."""
    short = [SHORT_HEADS.get(n, (escape(n), "")) for n in names]
    notes = [_HEAD_NOTES[n] for n in names if n in _HEAD_NOTES]
    rows = [[a for a, _ in short]]
    if any(b for _, b in short):
        rows.append([b for _, b in short])
    return rows, notes


def verdicts_tex(verdicts: list[list[str]], reference: str, alpha: float) -> str:
    """The verdict table (``verdicts.csv``: metrics as rows, compared methods as columns) transposed: one row per
    method, one column per metric, ▲ ▼ ≡ as amssymb symbols."""
    metrics = [r[0] for r in verdicts[1:]]
    methods = verdicts[0][1:]
    rows = [[escape(m), *[LATEX_SYMBOL.get(r[1 + j], escape(r[1 + j])) for r in verdicts[1:]]]
            for j, m in enumerate(methods)]
    ref = escape(reference)
    heads, _ = _heads(metrics)
    named = [f"{h} {escape(m)}" for h, m in zip(heads[0], metrics) if SHORT_HEADS.get(m, (escape(m),))[0] != escape(m)]
    legend = f" Columns: {', '.join(named)}." if named else ""
    caption = (f"Statistical difference with \\textbf{{{ref}}} (Mann-Whitney U, $\\alpha = {alpha:g}$, Bonferroni). "
               f"$\\blacktriangle$: significantly better than \\textbf{{{ref}}}, $\\blacktriangledown$: significantly "
               f"worse, $\\equiv$: not significantly different.{legend}")
    return tabular([["Method", *h] if k == 0 else ["", *h] for k, h in enumerate(heads)], rows, caption,
                   "table:verdicts", "l" + "c" * len(metrics))


def success_tex(success: list[list[str]]) -> str:
    """The success table (``success.csv``: subsets as rows, methods as columns) transposed: one row per method, one
    column per subset and the total (the name, then the number of trajectories in parentheses); a dataset without
    subsets has one column."""
    subsets = [r[0] for r in success[1:]]
    body = success[1:]
    if len(subsets) == 2 and subsets[0].startswith("all ("):  # one subset: its column is the total
        subsets, body = subsets[:1], body[:1]
    methods = success[0][1:]
    rows = [[escape(m), *[escape(r[1 + j]) for r in body]] for j, m in enumerate(methods)]
    split = [re.fullmatch(r"(.*) (\(\d+\))", s) for s in subsets]
    names = [escape(m.group(1)) if m else escape(s) for m, s in zip(split, subsets)]
    sizes = [m.group(2) if m else "" for m in split]
    caption = ("Successful trajectories (tracked from start to end without getting lost) per subset; the number of "
               "trajectories of each subset in parentheses.")
    return tabular([["Method", *names], ["", *sizes]], rows, caption, "table:success")


def medians_tex(medians: list[list[str]]) -> str:
    """The per-method summary (``medians.csv``), one row per method, its figures as they are, short two-row heads
    (:data:`SHORT_HEADS`) explained in the caption."""
    rows = [[escape(r[0]), *[_number(c) for c in r[1:]]] for r in medians[1:]]
    heads, notes = _heads(medians[0][1:])
    caption = ("Per method: medians over trajectories (each trajectory: the median over its repeats)."
               + (f" {'; '.join(notes)}." if notes else ""))
    return tabular([["Method" if k == 0 else "", *h] for k, h in enumerate(heads)], rows, caption, "table:medians")


def causes_tex(causes: list[list[str]]) -> str:
    """The cause table (``causes``: :func:`~bracketry_emulator.report.tables.cause_table`), one row per method, the
    paper's reading in its last column."""
    rows = [[escape(c) for c in r] for r in causes[1:]]
    caption = ("Runs that lost track per cause of their first loss (from the per-frame saturated and dark shares, "
               "blur length, exposure ratio to the previous frame and keypoints), beside the paper's reading of its "
               "own failures; the paper adds glare (every method on Campus1) and blur at the longest brackets.")
    header = [escape(c.replace("_", " ")) for c in causes[0]]
    return tabular([header], rows, caption, "table:causes", "l" + "r" * (len(header) - 2) + "p{5cm}")


def write_latex(rep: Path, verdicts: list[list[str]], success: list[list[str]], medians: list[list[str]],
                reference: str, alpha: float, causes: list[list[str]] | None = None) -> dict[str, Path]:
    """Write ``rep/latex/{verdicts,success,medians}.tex`` (and ``causes.tex`` with ``causes``); returns
    {``latex/<name>.tex``: path}."""
    out = rep / "latex"
    out.mkdir(parents=True, exist_ok=True)
    texts = {"verdicts.tex": verdicts_tex(verdicts, reference, alpha), "success.tex": success_tex(success),
             "medians.tex": medians_tex(medians)}
    if causes is not None:
        texts["causes.tex"] = causes_tex(causes)
    files = {}
    for name, text in texts.items():
        (out / name).write_text(text)
        files[f"latex/{name}"] = out / name
    return files
