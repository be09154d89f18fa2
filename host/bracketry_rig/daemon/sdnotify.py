"""Minimal systemd notification (``sd_notify``) over ``$NOTIFY_SOCKET``: READY, WATCHDOG, STATUS, STOPPING.

A no-op when the daemon does not run under systemd (no ``NOTIFY_SOCKET``).
"""

from __future__ import annotations

import os
import socket


class Notifier:
    """Sends notifications to systemd; ``watchdog_interval_s`` is half of ``$WATCHDOG_USEC`` (None if unset)."""

    def __init__(self) -> None:
        self._addr = os.environ.get("NOTIFY_SOCKET")
        usec = os.environ.get("WATCHDOG_USEC")
        self.watchdog_interval_s: float | None = int(usec) / 2e6 if usec and usec.isdigit() else None

    @property
    def enabled(self) -> bool:
        """True when running under systemd with a notify socket."""
        return bool(self._addr)

    def notify(self, message: str) -> bool:
        """Send one notification (e.g. ``"READY=1"``); returns False when not under systemd or on error."""
        if not self._addr:
            return False
        addr = self._addr
        if addr.startswith("@"):
            addr = "\0" + addr[1:]
        try:
            with socket.socket(socket.AF_UNIX, socket.SOCK_DGRAM) as s:
                s.setblocking(False)  # a listener that does not read (full queue) must never hang the daemon
                s.connect(addr)
                s.send(message.encode())
            return True
        except OSError:
            return False

    def ready(self) -> bool:
        return self.notify("READY=1")

    def watchdog(self) -> bool:
        return self.notify("WATCHDOG=1")

    def status(self, text: str) -> bool:
        return self.notify(f"STATUS={text}")

    def stopping(self) -> bool:
        return self.notify("STOPPING=1")
