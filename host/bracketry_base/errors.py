"""Errors that the CLI turns into one clear line and a non-zero exit code (never a traceback)."""

from __future__ import annotations


class BracketryError(Exception):
    """A user-facing error: bad input, a missing component, an unreadable file.

    ``exit_code`` is what the CLI exits with (2 unless a command documents otherwise).
    """

    exit_code: int = 2

    def __init__(self, message: str, exit_code: int | None = None) -> None:
        super().__init__(message)
        if exit_code is not None:
            self.exit_code = exit_code


class MissingComponentError(BracketryError):
    """A system component or an optional Python extra is not installed; the message says how to fix it."""
