"""Host side of the status panel: PANEL_STATE out at 2-5 Hz, BUTTON events in (each handled once), panel health.

The client sits on a wire link (:class:`bracketry_rig.wire.link.SerialLink` or anything with the same ``add_listener`` /
``send`` / ``peer_lost`` interface). Every BUTTON frame is ACKed (with the frame's seq) — duplicates too, so the
panel stops re-sending — but acted on only once per ``event_seq``. An unsolicited HELLO from the panel means it
rebooted: its event numbering restarts, so the duplicate window is cleared and ``reboots`` counts it.

Daemon use::

    client = connect("/dev/ttyUSB0", lambda: snapshot_fields(rig_state.snapshot()), on_button=queue.put)
    ...  # client.status() -> {"lost": bool, "firmware": "1.0.0", "buttons": n, "duplicates": n, "reboots": n, ...}
    client.stop(); client.link.close()
"""

from __future__ import annotations

import logging
import threading
import time
from collections import deque
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any, Protocol

from bracketry_rig.wire import bproto
from bracketry_rig.wire.errors import WireError

log = logging.getLogger(__name__)

SENSOR_FIELDS = ("cam_left", "cam_right", "trigger", "imu", "lidar", "gnss")
BUTTON_NAMES = {1: "SENSORS", 2: "RECORD"}
ACTION_NAMES = {1: "short", 2: "long"}
DUPLICATE_WINDOW = 64


class PanelLinkLike(Protocol):
    """What the client needs from a wire link."""

    def add_listener(self, callback: Callable[[int, int, dict[str, Any]], None]) -> None: ...

    def send(self, msg_type: int, fields: dict[str, Any]) -> Any: ...

    @property
    def peer_lost(self) -> bool: ...


@dataclass(frozen=True)
class ButtonEvent:
    """A button press reported by the panel: ``button`` 1 SENSORS / 2 RECORD, ``action`` 1 short / 2 long."""

    button: int
    action: int
    event_seq: int
    t_ns: int

    @property
    def name(self) -> str:
        return f"{BUTTON_NAMES.get(self.button, str(self.button))} {ACTION_NAMES.get(self.action, str(self.action))}"


def _clamp(value: float, bits: int) -> int:
    return max(0, min(int(value), (1 << bits) - 1))


def _ascii20(text: str) -> str:
    return "".join(ch if 32 <= ord(ch) < 127 else "?" for ch in text)[:20]


def panel_fields(states: dict[str, int], fps_left: float, fps_right: float, free_disk_mb: int, rec_seconds: int,
                 message: str) -> dict[str, Any]:
    """PANEL_STATE fields from plain values: states 0..4 per sensor (missing = OFF), fps in frames/s, disk in MB,
    recording time in s, message (made printable ASCII, cut to 20 chars). Out-of-range numbers are clamped."""
    fields: dict[str, Any] = {name: max(0, min(int(states.get(name, 0)), 4)) for name in SENSOR_FIELDS}
    fields.update(free_disk_mb=_clamp(free_disk_mb, 32), fps_left_centi=_clamp(round(fps_left * 100), 16),
                  fps_right_centi=_clamp(round(fps_right * 100), 16), rec_seconds=_clamp(rec_seconds, 32),
                  message=_ascii20(message))
    return fields


def snapshot_fields(snapshot: Any) -> dict[str, Any]:
    """PANEL_STATE fields from a daemon :class:`bracketry_rig.daemon.state.RigSnapshot`."""
    states = {name: int(snapshot.states.get(name, 0)) for name in SENSOR_FIELDS}
    return panel_fields(states, snapshot.fps.get("left", 0.0), snapshot.fps.get("right", 0.0),
                        snapshot.free_disk_mb, snapshot.rec_seconds, snapshot.message)


class PanelClient:
    """Drives the panel from ``state_fn() -> PANEL_STATE fields`` and reports button presses to ``on_button``.

    ``rate_hz`` (2..5) is the PANEL_STATE rate. ``on_button(event)`` runs in the link's reader thread after the ACK
    went out; keep it short (queue work elsewhere).
    """

    def __init__(self, link: PanelLinkLike, state_fn: Callable[[], dict[str, Any]],
                 on_button: Callable[[ButtonEvent], None] | None = None, rate_hz: float = 4.0) -> None:
        if not 2.0 <= rate_hz <= 5.0:
            raise ValueError("the panel expects PANEL_STATE at 2-5 Hz")
        self.link = link
        self.state_fn = state_fn
        self.on_button = on_button
        self.period_s = 1.0 / rate_hz
        self.events: list[ButtonEvent] = []
        self.counters = {"states_sent": 0, "buttons": 0, "duplicates": 0, "acks_sent": 0, "hellos": 0,
                         "state_errors": 0, "lost": 0}
        self.panel_hello: dict[str, Any] | None = None
        self._seen: deque[int] = deque(maxlen=DUPLICATE_WINDOW)
        self._lock = threading.Lock()
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None
        link.add_listener(self.handle_message)
        add_lost = getattr(link, "add_lost_listener", None)
        if add_lost is not None:
            add_lost(self._on_lost)

    def _on_lost(self, lost: bool) -> None:
        """Link callback: the panel went silent (lost=True) or is heard again."""
        if lost:
            self.counters["lost"] += 1
            log.warning("panel lost (no frames for 1.5 s)")
        else:
            log.info("panel back")

    # -- incoming
    def send_ack(self, seq: int) -> None:
        """ACK a panel frame (BUTTON) by its seq (a failed write is logged: the panel re-sends anyway)."""
        try:
            self.link.send(bproto.MSG_ACK, {"acked_seq": seq})
        except (WireError, OSError) as exc:
            log.warning("ACK to the panel not sent: %s", exc)
            return
        self.counters["acks_sent"] += 1

    def handle_message(self, msg_type: int, seq: int, fields: dict[str, Any]) -> None:
        """Link listener: BUTTON -> ACK (always) + act once per event_seq; HELLO -> panel (re)boot."""
        if msg_type == bproto.MSG_BUTTON:
            self.send_ack(seq)
            with self._lock:
                duplicate = fields["event_seq"] in self._seen
                if duplicate:
                    self.counters["duplicates"] += 1
                else:
                    self._seen.append(fields["event_seq"])
                    event = ButtonEvent(fields["button"], fields["action"], fields["event_seq"], time.time_ns())
                    self.events.append(event)
                    self.counters["buttons"] += 1
            if not duplicate:
                log.info("panel button %s (event %d)", event.name, event.event_seq)
                if self.on_button is not None:
                    self.on_button(event)
        elif msg_type == bproto.MSG_HELLO and fields:
            with self._lock:
                self.counters["hellos"] += 1
                if self.panel_hello is not None:  # counted once, by the link (see reboots)
                    log.warning("panel rebooted (unsolicited HELLO)")
                self.panel_hello = dict(fields)
                self._seen.clear()

    @property
    def panel_lost(self) -> bool:
        """True when the link has missed the panel's heartbeats (3 x 500 ms)."""
        return bool(self.link.peer_lost)

    def status(self) -> dict[str, Any]:
        """Panel health for `bracketry status`: lost, reboots, firmware version, counters."""
        hello = self.panel_hello
        fw = f"{hello['fw_major']}.{hello['fw_minor']}.{hello['fw_patch']}" if hello else None
        return {"lost": self.panel_lost, "firmware": fw, "reboots": self.reboots, **self.counters}

    @property
    def reboots(self) -> int:
        """Panel reboots, read from the link's ``reboots`` counter (the link owns the count); 0 for a link without
        counters."""
        counters = getattr(self.link, "counters", None)
        return int(counters["reboots"]) if isinstance(counters, dict) else 0

    # -- outgoing
    def send_state(self) -> None:
        """Send one PANEL_STATE from ``state_fn``."""
        try:
            fields = self.state_fn()
            self.link.send(bproto.MSG_PANEL_STATE, fields)
        except (ValueError, KeyError) as exc:
            self.counters["state_errors"] += 1
            log.error("bad panel state: %s", exc)
            return
        self.counters["states_sent"] += 1

    def _run(self) -> None:
        next_t = time.monotonic()
        while not self._stop.is_set():
            try:
                self.send_state()
            except (WireError, OSError) as exc:  # the port went away: keep trying, the link reports it lost
                log.warning("panel state not sent: %s", exc)
            next_t += self.period_s
            delay = next_t - time.monotonic()
            if delay < 0:
                next_t = time.monotonic()
                delay = 0
            self._stop.wait(delay)

    def start(self) -> PanelClient:
        """Start the PANEL_STATE thread."""
        if self._thread is None:
            self._stop.clear()
            self._thread = threading.Thread(target=self._run, name="panel-state", daemon=True)
            self._thread.start()
        return self

    def stop(self) -> None:
        """Stop sending (the panel shows HOST LOST 1.5 s later unless other host frames keep arriving)."""
        self._stop.set()
        if self._thread is not None:
            self._thread.join(timeout=2.0)
            self._thread = None


def connect(url: str, state_fn: Callable[[], dict[str, Any]], on_button: Callable[[ButtonEvent], None] | None = None,
            rate_hz: float = 4.0, baudrate: int = 115200) -> PanelClient:
    """Open a :class:`~bracketry_rig.wire.link.SerialLink` to the panel at ``url`` and start a client on it.

    The link sends no HEARTBEAT of its own (PANEL_STATE is the host heartbeat) and leaves BUTTON ACKs to the client.
    Close with ``client.stop(); client.link.close()``.
    """
    from bracketry_rig.wire.link import SerialLink

    link = SerialLink(url, baudrate, heartbeat_period_s=None, name="panel")
    return PanelClient(link, state_fn, on_button, rate_hz).start()
