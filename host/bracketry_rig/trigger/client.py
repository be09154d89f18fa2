"""Host client of the STM32 trigger: configure, start, stop, and stream TRIGGER events as
:class:`bracketry_rig.events.TriggerEvent` with host time through the clock model.

It runs on :class:`bracketry_rig.wire.link.SerialLink` (real ports, ``socket://`` for QEMU, ptys for the simulator).
Besides the commands it keeps:

- a :class:`bracketry_rig.wire.clock.ClockModel` fed by PING/PONG (``sync_clock`` and an optional background resync), so
  every event carries ``t_start_host_ns`` (``time.time_ns()`` epoch) once the model has a sample;
- gap detection on ``trigger_seq`` (missed events: counted, with the gaps listed);
- reboot detection: an unsolicited HELLO (the link's reboot listener), or a heartbeat whose uptime went backwards
  (the device clock restarted, so the clock model is reset and the session is marked as lost).
"""

from __future__ import annotations

import queue
import threading
import time
from collections.abc import Callable, Iterator, Sequence
from dataclasses import dataclass, field
from typing import Any

from bracketry_base.errors import BracketryError
from bracketry_rig.events import TriggerEvent
from bracketry_rig.wire import bproto
from bracketry_rig.wire.clock import ClockModel


@dataclass
class TriggerCounters:
    """What the client saw since it was opened.

    Attributes:
        events: TRIGGER events received (of the current or any session).
        missed_events: pulses whose event never arrived, from gaps in ``trigger_seq``: the one count of lost
            trigger events on the host (the link does not count them; the pairer counts only the gaps among the
            events of one recording it was given).
        gaps: (expected trigger_seq, received trigger_seq) of each gap (at most the last 1000).
        foreign_session_events: events of another session than the one this client started (ignored).
        reboots: device reboots, read from the link's ``reboots`` counter (the link owns the count: a boot HELLO
            from a device heard before, or a HEARTBEAT whose uptime went back); 0 for a link without counters.
        queue_overflows: events dropped because nobody consumed the event queue.
    """

    events: int = 0
    missed_events: int = 0
    gaps: list[tuple[int, int]] = field(default_factory=list)
    foreign_session_events: int = 0
    queue_overflows: int = 0
    link: Any = field(default=None, repr=False, compare=False)

    @property
    def reboots(self) -> int:
        counters = getattr(self.link, "counters", None)
        return int(counters["reboots"]) if isinstance(counters, dict) else 0


class TriggerClient:
    """The trigger behind a link.

    Args:
        link: an open :class:`bracketry_rig.wire.link.SerialLink` (or anything with ``request``, ``add_listener`` and
            ``close``); closed by :meth:`close`.
        clock: the clock model mapping device us to host ns (default: the link's own, which the link feeds from
            every PONG and resets on a reboot; open the link with ``time_ns=time.time_ns`` for epoch host times, as
            :meth:`open` does).
        on_event: called in the link's reader thread for each :class:`TriggerEvent` (keep it short).
        on_reboot: called in the link's reader thread when a device reboot is detected.
        clock_sync_period_s: background PING period in seconds (0: only explicit :meth:`sync_clock`).
        queue_size: capacity of the event queue read by :meth:`get_event` / :meth:`events`.
        timeout_s: reply timeout of each command attempt (the protocol's 0.1 s; QEMU on a busy machine needs more),
            retried ``retries`` times with the same seq (the commands are idempotent).
    """

    def __init__(self, link: Any, clock: ClockModel | None = None,
                 on_event: Callable[[TriggerEvent], None] | None = None,
                 on_reboot: Callable[[], None] | None = None, clock_sync_period_s: float = 0.0,
                 queue_size: int = 100_000, timeout_s: float = 0.1, retries: int = 3) -> None:
        self.link = link
        self.timeout_s = timeout_s
        self.retries = retries
        self.clock: ClockModel = clock if clock is not None else link.clock
        self.on_event = on_event
        self.on_reboot = on_reboot
        self.counters = TriggerCounters(link=link)
        self.device: dict[str, Any] = {}
        self.session_id: int | None = None
        self.running = False
        self.last_heartbeat: dict[str, int] | None = None
        self._events: queue.Queue[TriggerEvent] = queue.Queue(maxsize=queue_size)
        self._lock = threading.Lock()
        self._last_seq: int | None = None
        self._closed = threading.Event()
        self._sync_thread: threading.Thread | None = None
        link.add_listener(self._on_message)
        link.add_reboot_listener(self._on_reboot)
        if clock_sync_period_s > 0:
            self._sync_thread = threading.Thread(target=self._sync_loop, args=(clock_sync_period_s,),
                                                 name="trigger-clock-sync", daemon=True)
            self._sync_thread.start()

    @classmethod
    def open(cls, url: str, baudrate: int = 921600, **kwargs: Any) -> TriggerClient:
        """Open ``url`` (a port, ``socket://host:port`` or a pty path) with a SerialLink and wrap it.

        The link's clock runs on ``time.time_ns`` (epoch host times in the events) and, unless
        ``clock_sync_period_s`` is given, the clock model is refreshed by one PING per second, so it follows the
        device's drift over long recordings.
        """
        from bracketry_rig.wire.link import SerialLink

        kwargs.setdefault("clock_sync_period_s", 1.0)
        return cls(SerialLink(url, baudrate=baudrate, time_ns=time.time_ns), **kwargs)

    def close(self) -> None:
        """Stop the background clock sync and close the link."""
        self._closed.set()
        if self._sync_thread is not None:
            self._sync_thread.join(timeout=2.0)
        self.link.close()

    def __enter__(self) -> TriggerClient:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    # ------------------------------------------------------------------ commands
    def _request(self, msg_type: int, fields: dict[str, Any], timeout_s: float | None = None) -> dict[str, Any]:
        return dict(self.link.request(msg_type, fields, timeout_s=self.timeout_s if timeout_s is None else timeout_s,
                                      retries=self.retries))

    def hello(self, timeout_s: float | None = None) -> dict[str, Any]:
        """Ask the device who it is; returns the HELLO fields. BracketryError if it is not a trigger."""
        fields = self._request(bproto.MSG_HELLO, {}, timeout_s)
        if fields.get("device_kind") != bproto.DEVICE_TRIGGER:
            raise BracketryError(f"device is not a trigger (device_kind {fields.get('device_kind')})")
        self.device = dict(fields)
        return fields

    def ping(self, timeout_s: float | None = None) -> dict[str, Any]:
        """One PING/PONG exchange (the link adds it to its clock model); returns the PONG fields."""
        fields = self._request(bproto.MSG_PING, {}, timeout_s)
        if self.clock is not self.link.clock:
            self.clock.add_sample(int(fields["host_time_ns"]), time.time_ns(), int(fields["device_time_us"]))
        return fields

    def sync_clock(self, n_pings: int = 16, interval_s: float = 0.01) -> dict[str, float | int | None]:
        """``n_pings`` PING/PONG exchanges into the clock model; returns its summary (residual_us, drift_ppm...)."""
        for i in range(n_pings):
            self.ping()
            if interval_s > 0 and i + 1 < n_pings:
                time.sleep(interval_s)
        return self.clock.summary()

    def configure(self, period_us: int, exposures_us: Sequence[int]) -> None:
        """SET_BRACKETS: pulses every ``period_us``, widths cycling through ``exposures_us`` (us).

        Raises NackError (``code`` 3 BAD_VALUE for an invalid table, 4 BAD_STATE while running).
        """
        self._request(bproto.MSG_SET_BRACKETS,
                      {"period_us": int(period_us), "exposures_us": [int(e) for e in exposures_us]})

    def start(self, session_id: int) -> None:
        """START a session (``trigger_seq`` restarts at 0). Raises NackError (4 BAD_STATE: another session runs)."""
        with self._lock:
            previous = self.session_id
            self.session_id = int(session_id)
            if previous != self.session_id:
                self._last_seq = None
        self._request(bproto.MSG_START, {"session_id": int(session_id)})
        self.running = True

    def stop(self) -> None:
        """STOP (idempotent). Events of pulses before the STOP arrive before its ACK."""
        self._request(bproto.MSG_STOP, {})
        self.running = False

    # ------------------------------------------------------------------ events
    def get_event(self, timeout_s: float | None = None) -> TriggerEvent | None:
        """Next event of the queue, or None after ``timeout_s``."""
        try:
            return self._events.get(timeout=timeout_s)
        except queue.Empty:
            return None

    def events(self, timeout_s: float = 1.0) -> Iterator[TriggerEvent]:
        """Iterate over events until none arrives for ``timeout_s``."""
        while True:
            ev = self.get_event(timeout_s)
            if ev is None:
                return
            yield ev

    def drain_events(self) -> list[TriggerEvent]:
        """All queued events, without waiting."""
        out = []
        while True:
            try:
                out.append(self._events.get_nowait())
            except queue.Empty:
                return out

    # ------------------------------------------------------------------ link callbacks (reader thread)
    def _on_message(self, msg_type: int, seq: int, fields: dict[str, Any]) -> None:
        if msg_type == bproto.MSG_TRIGGER:
            self._on_trigger(fields)
        elif msg_type == bproto.MSG_HEARTBEAT:  # (a reboot it reveals reaches _on_reboot through the link first)
            self.last_heartbeat = {"uptime_ms": int(fields["uptime_ms"]), "state": int(fields["state"])}

    def _on_reboot(self, fields: dict[str, Any]) -> None:
        """Link reboot listener (the link counts the reboot and restarts the clock model)."""
        if fields:
            self.device = dict(fields)
        with self._lock:
            self._last_seq = None
            self.running = False
            self.last_heartbeat = None
        self.clock.reset()
        if self.on_reboot is not None:
            self.on_reboot()

    def _on_trigger(self, fields: dict[str, Any]) -> None:
        seq = int(fields["trigger_seq"])
        session = int(fields["session_id"])
        with self._lock:
            if self.session_id is not None and session != self.session_id:
                self.counters.foreign_session_events += 1
                return
            self.counters.events += 1
            if self._last_seq is not None and seq != (self._last_seq + 1) & 0xFFFFFFFF:
                expected = (self._last_seq + 1) & 0xFFFFFFFF
                missed = (seq - expected) & 0xFFFFFFFF
                if missed < 0x80000000:  # forward gap (a backwards jump is a restart, not a loss)
                    self.counters.missed_events += missed
                    self.counters.gaps.append((expected, seq))
                    del self.counters.gaps[:-1000]
            self._last_seq = seq
        t_dev = int(fields["t_start_us"])
        try:
            t_host: int | None = self.clock.device_to_host_ns(t_dev)
        except ValueError:
            t_host = None
        ev = TriggerEvent(session_id=session, trigger_seq=seq, bracket_index=int(fields["bracket_index"]),
                          exposure_us=int(fields["exposure_us"]), t_start_device_us=t_dev, t_start_host_ns=t_host)
        try:
            self._events.put_nowait(ev)
        except queue.Full:
            self.counters.queue_overflows += 1
        if self.on_event is not None:
            self.on_event(ev)

    def _sync_loop(self, period_s: float) -> None:
        while not self._closed.wait(period_s):
            try:
                self.ping()
            except Exception:  # a lost PING is retried at the next period; link counters tell
                continue

    # ------------------------------------------------------------------ status
    def status(self) -> dict[str, Any]:
        """Device info, running state, last heartbeat, clock model summary and counters (plain data)."""
        c = self.counters
        return {"device": dict(self.device), "running": self.running, "session_id": self.session_id,
                "heartbeat": self.last_heartbeat, "clock": self.clock.summary(),
                "counters": {"events": c.events, "missed_events": c.missed_events, "gaps": len(c.gaps),
                             "foreign_session_events": c.foreign_session_events, "reboots": c.reboots,
                             "queue_overflows": c.queue_overflows}}
