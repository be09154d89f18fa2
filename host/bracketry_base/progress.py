"""The one progress display of every bracketry tool: a bar on a terminal, elsewhere a line every few seconds.

When the stream is a terminal, :class:`Progress` draws a ``tqdm`` bar. When it is not (a log file, a pipe, CI), it
writes one plain line at most every ``every_s`` seconds and one final line at :meth:`Progress.close`, never one line
per item, so a long run's log grows by a handful of lines.

    with Progress("export", total=n, unit="img") as bar:
        for item in items:
            ...
            bar.update(1)
"""

from __future__ import annotations

import sys
import time
from typing import IO, Any

#: seconds between two plain progress lines when the output is not a terminal
EVERY_S = 5.0


def _is_tty(stream: IO[str]) -> bool:
    try:
        return bool(stream.isatty())
    except (AttributeError, ValueError):
        return False


class Progress:
    """Progress of ``total`` items (None: unknown) named ``desc``, counted in ``unit``.

    Args:
        desc: what is progressing (the line's prefix).
        total: number of items, or None while unknown (see :meth:`set`).
        unit: name of one item ("img", "frame", "step").
        file: the stream (standard error by default).
        enabled: False shows nothing (``--quiet``).
        every_s: seconds between plain lines when ``file`` is not a terminal.
        bar: force the bar (True) or the plain lines (False); None decides from ``file.isatty()``.
    """

    def __init__(self, desc: str, total: int | None = None, unit: str = "item", *, file: IO[str] | None = None,
                 enabled: bool = True, every_s: float = EVERY_S, bar: bool | None = None) -> None:
        self.desc = desc
        self.total = total
        self.unit = unit
        self.n = 0
        self.file = file if file is not None else sys.stderr
        self.enabled = enabled
        self.every_s = float(every_s)
        self.postfix = ""
        self._t0 = time.monotonic()
        self._last = self._t0
        self._closed = False
        self._tqdm: Any = None
        if enabled and (bar if bar is not None else _is_tty(self.file)):
            from tqdm import tqdm

            self._tqdm = tqdm(total=total, desc=desc, unit=unit, file=self.file, dynamic_ncols=True, leave=False)

    # ----------------------------------------------------------------------------------------------- counting
    def update(self, n: int = 1) -> None:
        """``n`` more items done."""
        self.set(self.n + int(n))

    def set(self, done: int, total: int | None = None) -> None:
        """``done`` items of ``total`` (None keeps the current total) are done."""
        if total is not None and total != self.total:
            self.total = int(total)
            if self._tqdm is not None:
                self._tqdm.total = self.total
                self._tqdm.refresh()
        delta = int(done) - self.n
        self.n = int(done)
        if self._tqdm is not None:
            if delta:
                self._tqdm.update(delta)
            return
        self._maybe_line()

    def set_postfix(self, text: str) -> None:
        """A short status after the count (e.g. the item being worked on)."""
        self.postfix = str(text)
        if self._tqdm is not None:
            self._tqdm.set_postfix_str(self.postfix)

    def write(self, text: str) -> None:
        """Print a message line without breaking the bar."""
        if self._tqdm is not None:
            self._tqdm.write(text, file=self.file)
        else:
            print(text, file=self.file, flush=True)

    # ----------------------------------------------------------------------------------------------- output
    def line(self) -> str:
        """The plain progress line: ``desc: done/total unit (pct %), rate unit/s, elapsed s``."""
        elapsed = time.monotonic() - self._t0
        count = f"{self.n}/{self.total}" if self.total else f"{self.n}"
        pct = f" ({100.0 * self.n / self.total:.0f} %)" if self.total else ""
        rate = f", {self.n / elapsed:.1f} {self.unit}/s" if elapsed > 0 else ""
        post = f" [{self.postfix}]" if self.postfix else ""
        return f"{self.desc}: {count} {self.unit}{pct}{rate}, {elapsed:.0f} s{post}"

    def _maybe_line(self) -> None:
        if not self.enabled:
            return
        now = time.monotonic()
        if now - self._last >= self.every_s:
            self._last = now
            print(self.line(), file=self.file, flush=True)

    def close(self) -> None:
        """End the display (a plain final line when not on a terminal and something was counted)."""
        if self._closed:
            return
        self._closed = True
        if self._tqdm is not None:
            self._tqdm.close()
        elif self.enabled and self.n:
            print(self.line(), file=self.file, flush=True)

    def __enter__(self) -> Progress:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()
