"""The shared progress display: a line every few seconds when the output is not a terminal, never one per item."""

from __future__ import annotations

import io
import time

from bracketry_base.progress import Progress


def test_not_a_terminal_writes_a_line_every_few_seconds_not_one_per_item() -> None:
    out = io.StringIO()
    with Progress("work", total=20000, unit="img", file=out, every_s=0.05) as bar:
        for _ in range(20000):
            bar.update(1)
        time.sleep(0.06)
        bar.update(0)
    lines = out.getvalue().splitlines()
    assert 1 <= len(lines) <= 20, lines  # a few lines for 20000 items
    assert lines[-1].startswith("work: 20000/20000 img (100 %)")


def test_quiet_and_unknown_total() -> None:
    out = io.StringIO()
    with Progress("quiet", file=out, enabled=False) as bar:
        bar.update(5)
    assert out.getvalue() == ""
    with Progress("count", file=out, every_s=3600) as bar:
        bar.set(3)
        bar.set(7, total=10)
        bar.set_postfix("ae50")
    assert out.getvalue().splitlines() == [out.getvalue().splitlines()[-1]]
    assert out.getvalue().startswith("count: 7/10 item (70 %)") and "[ae50]" in out.getvalue()


def test_terminal_gets_a_bar() -> None:
    out = io.StringIO()
    with Progress("bar", total=3, file=out, bar=True) as bar:
        for _ in range(3):
            bar.update(1)
    text = out.getvalue()
    assert "\r" in text and "bar:" in text and "|" in text and "\n" not in text  # redrawn in place
