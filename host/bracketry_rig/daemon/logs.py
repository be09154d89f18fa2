"""Structured logs: one JSON object per line (time, level, logger, message, thread) on stderr or a file."""

from __future__ import annotations

import json
import logging
import sys
import time
from pathlib import Path


class JsonFormatter(logging.Formatter):
    """Formats a record as one JSON line: ``{"t": epoch_s, "level", "logger", "msg", "thread"[, "exc"]}``."""

    def format(self, record: logging.LogRecord) -> str:
        entry = {"t": round(record.created, 3), "time": time.strftime("%Y-%m-%dT%H:%M:%S", time.gmtime(record.created)),
                 "level": record.levelname, "logger": record.name, "msg": record.getMessage(),
                 "thread": record.threadName}
        if record.exc_info:
            entry["exc"] = self.formatException(record.exc_info)
        return json.dumps(entry)


def setup_logging(level: str = "INFO", json_lines: bool = True, path: Path | None = None) -> None:
    """Configure the root logger once: JSON lines (default) or plain text, to ``path`` or stderr."""
    handler: logging.Handler = logging.FileHandler(path) if path else logging.StreamHandler(sys.stderr)
    handler.setFormatter(JsonFormatter() if json_lines else logging.Formatter("%(asctime)s %(levelname)s %(name)s: "
                                                                              "%(message)s"))
    root = logging.getLogger()
    for h in list(root.handlers):
        root.removeHandler(h)
    root.addHandler(handler)
    root.setLevel(level.upper())
