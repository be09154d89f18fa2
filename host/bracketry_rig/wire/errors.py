"""Errors of the serial link layer (all are BracketryError, so the CLI prints them as one line)."""

from __future__ import annotations

from bracketry_base.errors import BracketryError


class WireError(BracketryError):
    """Base class of serial link errors."""


class NackError(WireError):
    """The device answered a command with NACK; ``code`` is the NACK code (1..4), ``msg_type`` the command type."""

    def __init__(self, message: str, code: int, msg_type: int, seq: int) -> None:
        super().__init__(message)
        self.code = code
        self.msg_type = msg_type
        self.seq = seq


class DeviceLostError(WireError):
    """No answer after all retries, the port vanished, or the link was closed."""


class LinkClosedError(DeviceLostError):
    """The link was closed while a request was pending or before it was sent."""
