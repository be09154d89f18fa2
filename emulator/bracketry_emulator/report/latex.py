"""LaTeX forms of the report's tables, for pasting into a paper (``report/latex/*.tex``).

Each file is one ``table`` float holding a ``tabular`` with booktabs rules (``\\toprule``, ``\\midrule``,
``\\bottomrule``); the verdicts use amssymb's ``$\\blacktriangle$`` (better than the reference),
``$\\blacktriangledown$`` (worse) and ``$\\equiv$`` (not different). Nothing else is needed in the preamble:
``\\usepackage{booktabs,amssymb}``. One row per method (a table grows downwards with the methods, so any number of
them fits a column); the cells are the same figures as the CSV files beside them (``nan`` and ``n/a`` become
``--``). Method, subset and metric names are escaped.
"""

from __future__ import annotations

from pathlib import Path

from bracketry_emulator.stats.mannwhitney import SYMBOL
from bracketry_emulator.stats.stability import UNSTABLE

_ESCAPES = {"\\": r"\textbackslash{}", "&": r"\&", "%": r"\%", "$": r"\$", "#": r"\#", "_": r"\_", "{": r"\{",
            "}": r"\}", "~": r"\textasciitilde{}", "^": r"\textasciicircum{}"}

#: verdict symbol of the CSV -> its LaTeX command (amssymb)
LATEX_SYMBOL = {SYMBOL["better"]: r"$\blacktriangle$", SYMBOL["worse"]: r"$\blacktriangledown$",
                SYMBOL["equal"]: r"$\equiv$", SYMBOL["n/a"]: "--", UNSTABLE: "?"}

PREAMBLE = "% needs \\usepackage{booktabs,amssymb}\n"


def escape(text: str) -> str:
    """``text`` with LaTeX's special characters escaped (for names: methods, subsets, metrics)."""
    return "".join(_ESCAPES.get(c, c) for c in str(text))


def _number(cell: str) -> str:
    return "--" if cell in ("", "nan", "n/a") else escape(cell)


def tabular(header: list[str], rows: list[list[str]], caption: str, label: str, align: str | None = None) -> str:
    """A ``table`` float with one booktabs ``tabular``: ``header`` and ``rows`` are LaTeX cells (already escaped)."""
    align = align or "l" + "r" * (len(header) - 1)
    lines = [PREAMBLE.rstrip("\n"), r"\begin{table}", r"\centering", f"\\caption{{{caption}}}", f"\\label{{{label}}}",
             f"\\begin{{tabular}}{{{align}}}", r"\toprule", " & ".join(header) + r" \\", r"\midrule"]
    lines += [" & ".join(r) + r" \\" for r in rows]
    lines += [r"\bottomrule", r"\end{tabular}", r"\end{table}", ""]
    return "\n".join(lines)


def verdicts_tex(verdicts: list[list[str]], reference: str, alpha: float) -> str:
    """The verdict table (``verdicts.csv``: metrics as rows, compared methods as columns) transposed: one row per
    method, one column per metric, ▲ ▼ ≡ as amssymb symbols."""
    metrics = [r[0] for r in verdicts[1:]]
    methods = verdicts[0][1:]
    rows = [[escape(m), *[LATEX_SYMBOL.get(r[1 + j], escape(r[1 + j])) for r in verdicts[1:]]]
            for j, m in enumerate(methods)]
    ref = escape(reference)
    caption = (f"Statistical difference with \\textbf{{{ref}}} (Mann-Whitney U, $\\alpha = {alpha:g}$, Bonferroni). "
               f"$\\blacktriangle$: significantly better than \\textbf{{{ref}}}, $\\blacktriangledown$: significantly "
               f"worse, $\\equiv$: not significantly different.")
    return tabular(["Method", *[escape(m) for m in metrics]], rows, caption, "table:verdicts",
                   "l" + "c" * len(metrics))


def success_tex(success: list[list[str]]) -> str:
    """The success table (``success.csv``: subsets as rows, methods as columns) transposed: one row per method, one
    column per subset (its size in parentheses) and the total; a dataset without subsets has one column."""
    subsets = [r[0] for r in success[1:]]
    body = success[1:]
    if len(subsets) == 2 and subsets[0].startswith("all ("):  # one subset: its column is the total
        subsets, body = subsets[:1], body[:1]
    methods = success[0][1:]
    rows = [[escape(m), *[escape(r[1 + j]) for r in body]] for j, m in enumerate(methods)]
    caption = ("Successful trajectories (tracked from start to end without getting lost) per subset; the number of "
               "trajectories of each subset in parentheses.")
    return tabular(["Method", *[escape(s) for s in subsets]], rows, caption, "table:success")


def medians_tex(medians: list[list[str]]) -> str:
    """The per-method summary (``medians.csv``), one row per method, as it is."""
    rows = [[escape(r[0]), *[_number(c) for c in r[1:]]] for r in medians[1:]]
    caption = ("Per method: medians over trajectories (each trajectory: the median over its repeats) and the spread "
               "over repeats (max $-$ min over a trajectory's repeats, median over trajectories).")
    return tabular([escape(c) for c in medians[0]], rows, caption, "table:medians")


def write_latex(rep: Path, verdicts: list[list[str]], success: list[list[str]], medians: list[list[str]],
                reference: str, alpha: float) -> dict[str, Path]:
    """Write ``rep/latex/{verdicts,success,medians}.tex``; returns {``latex/<name>.tex``: path}."""
    out = rep / "latex"
    out.mkdir(parents=True, exist_ok=True)
    texts = {"verdicts.tex": verdicts_tex(verdicts, reference, alpha), "success.tex": success_tex(success),
             "medians.tex": medians_tex(medians)}
    files = {}
    for name, text in texts.items():
        (out / name).write_text(text)
        files[f"latex/{name}"] = out / name
    return files
