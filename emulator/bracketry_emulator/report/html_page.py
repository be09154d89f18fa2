"""The report's HTML page: what a reader wants at a glance first, the long tables folded below.

Order: the verdict table against the reference, coloured (▲ green, ▼ red, ≡ grey); the box plots per metric and
method; the paired (Wilcoxon) verdict table; the control rows, when any; the success table per subset; the
per-method summaries; the exposure traces and the qualitative strip; then, folded in ``<details>``, the per-trajectory
table, the tests, the per-frame figures and where the time went. Nothing is wider than the page: the body has a
maximum width, every table sits in its own horizontal scroll box and every image is at most as wide as its box.
"""

from __future__ import annotations

import html

from bracketry_emulator.stats.mannwhitney import SYMBOL

STYLE = (
    "*{box-sizing:border-box}"
    "body{font-family:sans-serif;max-width:1100px;margin:auto;padding:0 12px;line-height:1.4}"
    "p,li,figcaption,summary{overflow-wrap:anywhere}"
    ".scroll{max-width:100%;overflow-x:auto;margin:8px 0}"
    "table{border-collapse:collapse}"
    "td,th{border:1px solid #bbb;padding:3px 7px;text-align:right;white-space:nowrap}"
    "th{background:#eee;white-space:normal;vertical-align:bottom}td:first-child,th:first-child{text-align:left}"
    "td.better{background:#d7f2d7;color:#1b6e1b;text-align:center;font-weight:bold}"
    "td.worse{background:#f6d5d2;color:#9c1c12;text-align:center;font-weight:bold}"
    "td.equal,td.na{color:#555;text-align:center}"
    "img{max-width:100%;height:auto}"
    ".figs{display:grid;grid-template-columns:repeat(auto-fill,minmax(min(100%,480px),1fr));gap:10px}"
    "figure{margin:0}figcaption{font-size:90%;color:#444}"
    "details{margin:10px 0;border-top:1px solid #ccc;padding-top:6px}summary{cursor:pointer;font-weight:bold}"
    ".legend span{padding:1px 6px;margin-right:8px}"
)

_VERDICT_CLASS = {SYMBOL["better"]: "better", SYMBOL["worse"]: "worse", SYMBOL["equal"]: "equal",
                  SYMBOL["n/a"]: "na"}


def table(rows: list[list[str]], verdict_cells: bool = False) -> str:
    """``rows`` (header first) as a table in its own scroll box; ``verdict_cells``: colour ▲ ▼ ≡ cells."""
    head = "".join(f"<th>{html.escape(c)}</th>" for c in rows[0])

    def cell(c: str) -> str:
        cls = _VERDICT_CLASS.get(c) if verdict_cells else None
        return f"<td class='{cls}'>{html.escape(c)}</td>" if cls else f"<td>{html.escape(c)}</td>"

    body = "".join("<tr>" + "".join(cell(c) for c in r) + "</tr>" for r in rows[1:])
    return f"<div class='scroll'><table><thead><tr>{head}</tr></thead><tbody>{body}</tbody></table></div>"


def by_method(rows: list[list[str]]) -> list[list[str]]:
    """A table with the methods as columns (the verdicts, the success per subset) turned to one row per method (a
    page holds any number of methods that way). A success table of one subset (``all``) keeps one column."""
    if len(rows) == 3 and rows[1][0].startswith("all (") and rows[2][0].startswith("Total ("):
        rows = rows[:2]
    return [["method", *[r[0] for r in rows[1:]]], *[[m, *[r[1 + j] for r in rows[1:]]]
                                                      for j, m in enumerate(rows[0][1:])]]


def verdict_legend(reference: str) -> str:
    ref = html.escape(reference)
    return (f"<p class='legend'><span class='better'>▲ better than {ref}</span>"
            f"<span class='worse'>▼ worse than {ref}</span><span>≡ not different from {ref}</span></p>")


def figures(figs: list[tuple[str, str]]) -> str:
    """PNG figures ``(file name, caption)`` in a grid of boxes (each image at most its box's width)."""
    items = "".join(f"<figure><img src='{html.escape(n)}' alt='{html.escape(c)}'>"
                    f"<figcaption>{html.escape(c)}</figcaption></figure>" for n, c in figs)
    return f"<div class='figs'>{items}</div>"


def section(title: str, inner: str, folded: bool = False) -> str:
    if folded:
        return f"<details><summary>{html.escape(title)}</summary>{inner}</details>"
    return f"<h2>{html.escape(title)}</h2>{inner}"


def document(title: str, intro: str, blocks: list[str]) -> str:
    """The whole self-contained page (figures are files beside it)."""
    return (f"<!doctype html><html><head><meta charset='utf-8'>"
            f"<meta name='viewport' content='width=device-width, initial-scale=1'><title>{html.escape(title)}</title>"
            f"<style>{STYLE}</style></head><body><h1>{html.escape(title)}</h1>"
            f"<p>{html.escape(intro).replace('**', '')}</p>{''.join(blocks)}</body></html>")
