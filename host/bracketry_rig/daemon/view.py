"""The daemon's status and panel view: the status socket, the ESP32 panel and the browser monitor.

Everything here shows the rig's state (``RigState`` snapshots, drawn by the panel at its refresh rate) or turns a
request into one of the rig's actions (:class:`RigControls`): a panel button press, a ``button`` request on the status
socket, a monitor action. It never touches the devices or the recording itself.

Threads: ``start``/``close`` on the daemon's main thread; ``check_panel`` on the 1 Hz supervisor thread (under the
daemon's action lock); ``handle_request`` on the status socket's thread; a panel button press runs its action on a
thread of its own (the panel client's reader thread must not wait for a segment to close). The view's lock guards the
panel client, which those threads replace or read.
"""

from __future__ import annotations

import contextlib
import logging
import threading
from collections.abc import Callable
from pathlib import Path
from typing import TYPE_CHECKING, Any, Protocol

from bracketry_rig.daemon.config import RigConfig
from bracketry_rig.daemon.monitor_link import MonitorRig, start_monitor
from bracketry_rig.daemon.sensors import Backoff
from bracketry_rig.daemon.state import RigState
from bracketry_rig.daemon.status import StatusServer
from bracketry_rig.pairing.pairer import PairedSet

if TYPE_CHECKING:
    from bracketry_rig.monitor.hub import PreviewHub
    from bracketry_rig.monitor.server import MonitorServer
    from bracketry_rig.panel.client import ButtonEvent, PanelClient

log = logging.getLogger("bracketry_rig.daemon")

BUTTONS = ("sensors", "record")


class RigControls(MonitorRig, Protocol):
    """The rig as its view sees it: the monitor's reads and actions, the buttons, the closed segments."""

    def on_button(self, button: str, long_press: bool = False) -> None: ...

    @property
    def segments(self) -> list[dict[str, Any]]: ...


class RigView:
    """Status socket (``status_socket``), panel (``config().panel``) and monitor (``config().monitor``) of ``rig``."""

    def __init__(self, config: Callable[[], RigConfig], state: RigState, rig: RigControls,
                 status_socket: Path | None = None, backoff_s: tuple[float, float] = (0.5, 8.0)) -> None:
        self._config = config
        self.state = state
        self.rig = rig
        self.status_socket = status_socket
        self._lock = threading.Lock()
        self.panel: PanelClient | None = None
        self._panel_backoff = Backoff(*backoff_s)
        self.status_server: StatusServer | None = None
        self.monitor_hub: PreviewHub | None = None
        self.monitor_server: MonitorServer | None = None

    @property
    def preview_tap(self) -> Callable[[PairedSet], None] | None:
        """Where a session hands its paired sets for the monitor (None without a monitor)."""
        return self.monitor_hub.offer if self.monitor_hub is not None else None

    def start_monitor(self) -> None:
        """The browser monitor, when the config has one (before the status socket: a daemon that answers serves
        its monitor); a failure is logged."""
        mc = self._config().monitor
        if mc is not None:
            started = start_monitor(mc, self.rig)
            if started is not None:
                self.monitor_hub, self.monitor_server = started

    def start_links(self) -> None:
        """The status socket and the panel link (failures are logged; the panel is retried later)."""
        cfg = self._config()
        sock = self.status_socket or cfg.status_socket
        try:
            self.status_server = StatusServer(sock, self.handle_request)
        except OSError as exc:
            log.warning("status socket %s unavailable: %s", sock, exc)
        self._connect_panel()

    def close(self) -> None:
        with self._lock:
            panel, self.panel = self.panel, None
        if panel is not None:
            with contextlib.suppress(Exception):
                panel.stop()
                link: Any = panel.link  # the SerialLink ``connect`` opened
                link.close()
        if self.status_server is not None:
            self.status_server.close()
            self.status_server = None
        server, hub = self.monitor_server, self.monitor_hub
        self.monitor_server = self.monitor_hub = None
        if server is not None:
            server.close()
        if hub is not None:
            hub.close()

    # ------------------------------------------------------------------------------------------------ panel
    def check_panel(self) -> None:
        """Reconnect the panel when it is enabled, gone and its backoff is due."""
        if self.panel is None and self._config().panel.enabled and self._panel_backoff.due():
            self._connect_panel()

    def _connect_panel(self) -> None:
        pc = self._config().panel
        if not pc.enabled:
            return
        from bracketry_rig.panel.client import connect, snapshot_fields

        try:
            panel = connect(pc.port, lambda: snapshot_fields(self.state.snapshot()), self._on_panel_button,
                            rate_hz=pc.refresh_hz, baudrate=pc.baudrate)
        except Exception as exc:
            self._panel_backoff.failed()
            log.warning("panel on %s unavailable: %s", pc.port, exc)
            return
        with self._lock:
            self.panel = panel
        self._panel_backoff.reset()
        log.info("panel connected on %s", pc.port)

    def _on_panel_button(self, ev: ButtonEvent) -> None:
        name = "sensors" if ev.button == 1 else "record"
        threading.Thread(target=self._button_thread, args=(name, ev.action == 2), name="button", daemon=True).start()

    def _button_thread(self, button: str, long_press: bool) -> None:
        try:
            self.rig.on_button(button, long_press)
        except Exception:  # the daemon survives any failure of a button action; the panel shows it
            log.exception("button %s failed", button)
            self.state.set_message(f"{button.upper()} FAILED")

    # ------------------------------------------------------------------------------------------------ status
    def handle_request(self, request: dict[str, Any]) -> dict[str, Any]:
        """Status socket handler: ``status`` and ``button``."""
        cmd = request.get("cmd")
        if cmd == "status":
            with self._lock:
                panel = self.panel
            server = self.monitor_server
            return {"ok": True, "state": self.state.snapshot().to_json(), "segments": len(self.rig.segments),
                    "panel": panel.status() if panel is not None else None,
                    "monitor": {"url": server.url} if server is not None else None}
        if cmd == "button":
            button = request.get("button")
            if button not in BUTTONS:
                return {"ok": False, "error": "button must be sensors or record"}
            self.rig.on_button(str(button), bool(request.get("long", False)))
            return {"ok": True}
        return {"ok": False, "error": f"unknown cmd {cmd!r}"}
