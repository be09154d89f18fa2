"""Block diagram of ``hw/wiring.yaml``: a self-contained SVG (no Graphviz needed) and Graphviz DOT text.

Colours follow the paper's figure: black = power, purple = Ethernet, green = USB/serial; signal lines (triggers, LCD
bus, buttons) are blue, grounds grey. One line per (node pair, kind), labelled with the number of wires if > 1.
"""

from __future__ import annotations

from html import escape
from typing import Any

EDGE_COLOURS = {"power": "#000000", "ethernet": "#7b2cbf", "usb": "#2b9348", "serial": "#2b9348",
                "signal": "#1d4ed8", "ground": "#888888"}
GROUP_COLUMN = {"power": 0, "compute": 1, "network": 1, "sensor": 2, "controller": 3, "panel": 4}
GROUP_FILL = {"power": "#fde2e4", "compute": "#e2ece9", "network": "#dfe7fd", "sensor": "#fff1c1",
              "controller": "#e9e3ff", "panel": "#d8f3dc"}
BOX_W, BOX_H, COL_W, ROW_H, MARGIN = 210, 34, 270, 56, 30


def edges(wiring: dict[str, Any]) -> list[tuple[str, str, str, int]]:
    """(node_a, node_b, kind, wire count) of every rail and connection between two different nodes."""
    acc: dict[tuple[str, str, str], int] = {}
    for rail in wiring["rails"]:
        for to in rail["to"]:
            key = (rail["from"], to, "power")
            acc[key] = acc.get(key, 0) + 1
    for conn in wiring["connections"]:
        a = str(conn["from"]).split(".")[0]
        b = str(conn["to"]).split(".")[0]
        if a == b:
            continue
        kind = conn.get("kind", "signal")
        key = (a, b, kind) if (b, a, kind) not in acc else (b, a, kind)
        acc[key] = acc.get(key, 0) + 1
    return [(a, b, k, n) for (a, b, k), n in acc.items()]


def layout(wiring: dict[str, Any]) -> dict[str, tuple[float, float]]:
    """Top-left corner (x, y) of every node box, by group column, in YAML order."""
    rows: dict[int, int] = {}
    pos: dict[str, tuple[float, float]] = {}
    for node, (_label, group) in wiring["nodes"].items():
        col = GROUP_COLUMN.get(group, 4)
        row = rows.get(col, 0)
        rows[col] = row + 1
        pos[node] = (MARGIN + col * COL_W, MARGIN + 40 + row * ROW_H)
    return pos


def to_svg(wiring: dict[str, Any]) -> str:
    """The diagram as SVG text (deterministic for a given wiring)."""
    pos = layout(wiring)
    width = MARGIN * 2 + (max(GROUP_COLUMN.values()) + 1) * COL_W
    height = max(y for _x, y in pos.values()) + BOX_H + MARGIN + 60
    out = [f'<svg xmlns="http://www.w3.org/2000/svg" width="{width}" height="{height}" '
           f'viewBox="0 0 {width} {height}" font-family="DejaVu Sans, Arial, sans-serif" font-size="11">',
           f'<rect width="{width}" height="{height}" fill="white"/>',
           f'<text x="{MARGIN}" y="{MARGIN + 10}" font-size="15" font-weight="bold">bracketry backpack wiring '
           '(generated from hw/wiring.yaml)</text>']
    for i, (a, b, kind, n) in enumerate(sorted(edges(wiring))):
        if a not in pos or b not in pos:
            continue
        x1, y1 = pos[a][0] + BOX_W / 2, pos[a][1] + BOX_H / 2
        x2, y2 = pos[b][0] + BOX_W / 2, pos[b][1] + BOX_H / 2
        bend = 40 + 12 * (i % 4) if abs(x1 - x2) < 1 else 10 * ((i % 5) - 2)
        mx, my = (x1 + x2) / 2 + bend, (y1 + y2) / 2 + (bend if abs(x1 - x2) >= 1 else 0) / 3
        colour = EDGE_COLOURS.get(kind, "#000000")
        dash = ' stroke-dasharray="4 3"' if kind == "ground" else ""
        out.append(f'<path d="M{x1:.0f},{y1:.0f} Q{mx:.0f},{my:.0f} {x2:.0f},{y2:.0f}" fill="none" '
                   f'stroke="{colour}" stroke-width="{1.5 + 0.5 * min(n, 6):.1f}"{dash}>'
                   f'<title>{escape(a)} - {escape(b)}: {kind} x{n}</title></path>')
        if n > 1:
            out.append(f'<text x="{mx:.0f}" y="{my:.0f}" fill="{colour}">x{n}</text>')
    for node, (label, group) in wiring["nodes"].items():
        x, y = pos[node]
        fill = GROUP_FILL.get(group, "#eee")
        out.append(f'<rect x="{x}" y="{y}" width="{BOX_W}" height="{BOX_H}" rx="5" fill="{fill}" stroke="#333"/>')
        out.append(f'<text x="{x + BOX_W / 2:.0f}" y="{y + BOX_H / 2 + 4:.0f}" text-anchor="middle">'
                   f'{escape(str(label))}</text>')
    ly = height - 30
    for i, (kind, colour) in enumerate(EDGE_COLOURS.items()):
        lx = MARGIN + i * 150
        out.append(f'<line x1="{lx}" y1="{ly}" x2="{lx + 30}" y2="{ly}" stroke="{colour}" stroke-width="3"/>')
        out.append(f'<text x="{lx + 36}" y="{ly + 4}">{kind}</text>')
    out.append("</svg>")
    return "\n".join(out) + "\n"


def to_dot(wiring: dict[str, Any]) -> str:
    """Graphviz DOT text of the same diagram (render with ``dot -Tsvg`` where Graphviz is installed)."""
    lines = ["graph bracketry {", '  rankdir=LR; node [shape=box, style="rounded,filled", fontname="Helvetica"];']
    for node, (label, group) in wiring["nodes"].items():
        lines.append(f'  {node} [label="{label}", fillcolor="{GROUP_FILL.get(group, "#eeeeee")}"];')
    for a, b, kind, n in sorted(edges(wiring)):
        style = ", style=dashed" if kind == "ground" else ""
        label = f', label="x{n}"' if n > 1 else ""
        lines.append(f'  {a} -- {b} [color="{EDGE_COLOURS.get(kind, "#000000")}"{style}{label}];')
    lines.append("}")
    return "\n".join(lines) + "\n"
