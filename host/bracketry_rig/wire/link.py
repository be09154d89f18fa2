"""Host side of a bproto serial link: streaming decode, commands with ACK/NACK/retry, heartbeats, reboots, clock.

:class:`SerialLink` opens a pyserial URL (a real port ``/dev/ttyACM0``, ``socket://127.0.0.1:PORT``, a pty path)
with DTR and RTS de-asserted (ESP32 boards reset when they toggle; ptys that reject the ioctls are tolerated) and
runs two daemon threads: a reader (decodes frames, matches replies, dispatches device events) and a ticker
(heartbeat out at 2 Hz, peer-lost detection after 1.5 s of silence, reconnect after an unplug).

Requests follow PROTOCOL.md section 2: reply within ``timeout_s`` (100 ms), else the same frame (same seq) is re-sent
up to ``retries`` times (3), then :class:`DeviceLostError`. NACK raises :class:`NackError` with ``.code``.
"""

from __future__ import annotations

import contextlib
import logging
import threading
import time
from collections import deque
from collections.abc import Callable
from typing import Any

import serial

from bracketry_rig.wire import bproto
from bracketry_rig.wire.clock import ClockModel
from bracketry_rig.wire.errors import DeviceLostError, LinkClosedError, NackError

log = logging.getLogger(__name__)

Listener = Callable[[int, int, dict[str, Any]], None]

#: a device HEARTBEAT whose uptime_ms is this much below the previous one announces a reboot (milliseconds)
UPTIME_SLACK_MS = 50
#: the ticker's period (peer check, heartbeat, reconnection), seconds
TICK_S = 0.05
#: a tick this long after the previous one shows this process starved: that time counts as no silence of the peer
STARVED_TICK_GAP_S = 0.5

#: device -> host message types handed to listeners
EVENT_TYPES = (bproto.MSG_TRIGGER, bproto.MSG_BUTTON, bproto.MSG_HELLO, bproto.MSG_HEARTBEAT)

COUNTER_NAMES = ("frames_in", "frames_out", "crc_errors", "length_errors", "cobs_errors", "version_errors",
                 "overflows", "resyncs", "bytes_discarded", "requests", "retries", "timeouts", "nacks", "reboots",
                 "unsolicited_hellos", "heartbeats_in", "heartbeats_out", "peer_lost", "trigger_events",
                 "button_events", "bad_payloads", "unknown_types",
                 "unmatched_replies", "listener_errors", "reconnects", "io_errors", "seq_gaps", "send_acks",
                 "send_nacks", "write_timeouts")


def open_serial(url: str, baudrate: int = 921600, read_timeout_s: float = 0.05) -> serial.SerialBase:
    """Open a pyserial URL with DTR and RTS de-asserted before the port opens; tolerate ports without those lines.

    Returns the open port; raises :class:`DeviceLostError` with a one-line reason when it cannot be opened.
    """
    try:
        port = serial.serial_for_url(url, baudrate=baudrate, timeout=read_timeout_s, write_timeout=1.0,
                                     do_not_open=True)
    except (serial.SerialException, ValueError, OSError) as exc:
        raise DeviceLostError(f"cannot use serial port {url}: {exc}") from exc
    for attr in ("dtr", "rts"):
        with contextlib.suppress(serial.SerialException, ValueError, OSError, AttributeError):
            setattr(port, attr, False)  # stored now, applied by open() (ENOTTY/EINVAL of ptys are ignored there)
    try:
        port.open()
    except (serial.SerialException, ValueError, OSError) as exc:
        raise DeviceLostError(f"cannot open serial port {url}: {exc}") from exc
    return port


class _Pending:
    """One outstanding request: what answers it and the result."""

    def __init__(self, msg_type: int, seq: int, host_time_ns: int | None) -> None:
        self.msg_type = msg_type
        self.seq = seq
        self.host_time_ns = host_time_ns  # PING: the stamp of the latest send
        self.sent_ns: dict[int, int] = {}  # PING stamp -> monotonic host ns when sent
        self.event = threading.Event()
        self.reply_type: int | None = None
        self.fields: dict[str, Any] = {}
        self.error: Exception | None = None


class SerialLink:
    """A bproto link to one device over pyserial. Thread-safe; use as a context manager or call :meth:`close`.

    Parameters: ``url`` (pyserial URL or path), ``baudrate``, ``heartbeat_period_s`` (0.5 = 2 Hz; ``None`` sends no
    HEARTBEAT, e.g. for the panel whose PANEL_STATE is the host heartbeat), ``peer_lost_after_s`` (1.5 s = 3 missed
    heartbeats; time this process was not run, a ticker gap over ``STARVED_TICK_GAP_S``, does not count as
    silence), ``reconnect`` (reopen the port after an I/O error, e.g. an unplug), ``time_ns`` (host clock for
    PING stamps and the clock model; default ``time.monotonic_ns``). BUTTON frames are handed to the listeners as
    they come (ACKs and duplicates are the panel client's).

    Attributes: ``clock`` (:class:`ClockModel`), ``device_info`` (fields of the last device HELLO or None),
    ``peer_lost`` (bool), ``connected`` (bool), ``counters`` (dict, see :data:`COUNTER_NAMES`; a snapshot).
    """

    def __init__(self, url: str, baudrate: int = 921600, *, heartbeat_period_s: float | None = 0.5,
                 peer_lost_after_s: float = 1.5, reconnect: bool = True,
                 time_ns: Callable[[], int] = time.monotonic_ns, name: str | None = None,
                 on_reboot: Callable[[dict[str, Any]], None] | None = None) -> None:
        self.url = url
        self.name = name or url
        self.baudrate = baudrate
        self.heartbeat_period_s = heartbeat_period_s
        self.peer_lost_after_s = peer_lost_after_s
        self.reconnect = reconnect
        self._time_ns = time_ns
        self.clock = ClockModel()
        self.device_info: dict[str, Any] | None = None
        self.device_state: int | None = None
        self.peer_lost = False
        self.lost_silence_s: float | None = None  # silence measured when the peer was declared lost
        self._counters = dict.fromkeys(COUNTER_NAMES, 0)
        self._decoder = bproto.Decoder()
        self._lock = threading.RLock()
        self._write_lock = threading.Lock()
        self._pending: dict[int, _Pending] = {}
        self._seq = 0
        self._listeners: list[Listener] = []
        self._reboot_listeners: list[Callable[[dict[str, Any]], None]] = []
        self._lost_listeners: list[Callable[[bool], None]] = []
        if on_reboot is not None:
            self._reboot_listeners.append(on_reboot)
        self._last_uptime_ms: int | None = None  # of the device's last HEARTBEAT (None until one after a boot)
        self._heard_device = False
        self._last_device_seq: int | None = None
        self._sent_seqs: deque[int] = deque(maxlen=64)  # seqs of recent fire-and-forget sends (their ACKs are fine)
        self._opened_s = time.monotonic()
        self._last_rx_s = time.monotonic()
        self._closed = threading.Event()
        self._port: serial.SerialBase | None = open_serial(url, baudrate)
        self.connected = True
        self._reader = threading.Thread(target=self._read_loop, name=f"bproto-rx {self.name}", daemon=True)
        self._ticker = threading.Thread(target=self._tick_loop, name=f"bproto-tick {self.name}", daemon=True)
        self._reader.start()
        self._ticker.start()

    # ------------------------------------------------------------------------------------------------ public
    def __enter__(self) -> SerialLink:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    @property
    def counters(self) -> dict[str, int]:
        """Snapshot of the counters, including the decoder's (frames_in = valid frames, resyncs = rejected ones)."""
        with self._lock:
            out = dict(self._counters)
            st = self._decoder.stats
        for k in ("crc_errors", "length_errors", "cobs_errors", "version_errors", "overflows", "bytes_discarded"):
            out[k] = st[k]
        out["frames_in"] = st["frames_ok"]
        out["resyncs"] = self._decoder.errors
        return out

    def add_listener(self, callback: Listener) -> None:
        """Call ``callback(msg_type, seq, fields)`` (on the reader thread) for every unsolicited device message:
        TRIGGER, BUTTON, unsolicited HELLO, HEARTBEAT and unknown types (fields ``{"payload": bytes}``)."""
        self._listeners.append(callback)

    def add_reboot_listener(self, callback: Callable[[dict[str, Any]], None]) -> None:
        """Call ``callback(hello_fields)`` when the device announces a (re)boot with an unsolicited HELLO.

        Every unsolicited HELLO counts in ``unsolicited_hellos``; it counts in ``reboots`` when the device had
        already been heard on this link (a HELLO as the very first frame is a boot after the link opened).
        """
        self._reboot_listeners.append(callback)

    def add_lost_listener(self, callback: Callable[[bool], None]) -> None:
        """Call ``callback(lost)`` when the peer is declared lost (True) or heard again (False)."""
        self._lost_listeners.append(callback)

    def next_seq(self) -> int:
        """Allocate the next host sequence number (0..65535, wrapping)."""
        with self._lock:
            seq = self._seq
            self._seq = (self._seq + 1) & 0xFFFF
            return seq

    def send(self, msg_type: int, fields: dict[str, Any] | None = None, seq: int | None = None) -> int:
        """Send one message without waiting for a reply (PANEL_STATE, ACK of a BUTTON, ...); returns its seq.

        A later ACK of it counts in ``send_acks``, a NACK in ``send_nacks`` (and is logged).
        """
        if seq is None:
            seq = self.next_seq()
        frame = bproto.encode_message(msg_type, seq, fields or {})
        if msg_type not in (bproto.MSG_ACK, bproto.MSG_NACK, bproto.MSG_HEARTBEAT):
            with self._lock:
                self._sent_seqs.append(seq)
        self._write(frame)
        return seq

    def request(self, msg_type: int, fields: dict[str, Any] | None = None, timeout_s: float = 0.1,
                retries: int = 3) -> dict[str, Any]:
        """Send a command and wait for its reply; returns the reply fields.

        HELLO (empty ``fields``) -> the device HELLO fields; PING (``fields`` ignored: stamped with the host clock
        at each send) -> the PONG fields, also fed to :attr:`clock`; any other command -> the ACK fields
        (``{"acked_seq": seq}``). Raises :class:`NackError` on NACK, :class:`DeviceLostError` after ``retries``
        re-sends of the same frame without a reply (the peer is then marked lost), :class:`LinkClosedError`
        when the link is closed.
        """
        if self._closed.is_set():
            raise LinkClosedError(f"{self.name}: link closed")
        if not self.connected:
            raise DeviceLostError(f"{self.name}: serial port not connected")
        fields = dict(fields or {})
        is_ping = msg_type == bproto.MSG_PING
        seq = self.next_seq()
        pending = _Pending(msg_type, seq, None)
        with self._lock:
            self._pending[seq] = pending
            self._counters["requests"] += 1
        try:
            for attempt in range(retries + 1):
                if attempt:
                    with self._lock:
                        self._counters["retries"] += 1
                if is_ping:
                    stamp = self._time_ns()
                    with self._lock:
                        pending.host_time_ns = stamp
                        pending.sent_ns[stamp] = stamp
                    frame = bproto.encode_message(msg_type, seq, {"host_time_ns": stamp})
                else:
                    frame = bproto.encode_message(msg_type, seq, fields)
                try:
                    self._write(frame)
                except DeviceLostError:
                    if self._closed.is_set():
                        raise LinkClosedError(f"{self.name}: link closed") from None
                    raise
                if pending.event.wait(timeout_s):
                    break
                if self._closed.is_set():
                    raise LinkClosedError(f"{self.name}: link closed")
            else:
                with self._lock:
                    self._counters["timeouts"] += 1
                self._declare_lost(True)
                name = bproto.MSG_NAMES.get(msg_type, hex(msg_type))
                raise DeviceLostError(f"{self.name}: no reply to {name} (seq {seq}) after {retries} retries")
        finally:
            with self._lock:
                self._pending.pop(seq, None)
        if pending.error is not None:
            raise pending.error
        if pending.reply_type == bproto.MSG_NACK:
            code = int(pending.fields["code"])
            with self._lock:
                self._counters["nacks"] += 1
            name = bproto.MSG_NAMES.get(msg_type, hex(msg_type))
            raise NackError(f"{self.name}: device refused {name} (seq {seq}): NACK "
                            f"{bproto.NACK_NAMES.get(code, str(code))}", code=code, msg_type=msg_type, seq=seq)
        return pending.fields

    def hello(self, timeout_s: float = 0.1, retries: int = 3) -> dict[str, Any]:
        """Ask the device who it is (HELLO request); returns its HELLO fields."""
        return self.request(bproto.MSG_HELLO, {}, timeout_s, retries)

    def ping(self, timeout_s: float = 0.1, retries: int = 3) -> dict[str, Any]:
        """One PING/PONG exchange (adds a sample to :attr:`clock`); returns the PONG fields."""
        return self.request(bproto.MSG_PING, {}, timeout_s, retries)

    def sync_clock(self, n: int = 32, interval_s: float = 0.01) -> ClockModel:
        """Run ``n`` PING/PONG exchanges ``interval_s`` apart and return the updated :attr:`clock`."""
        for _ in range(n):
            self.ping()
            time.sleep(interval_s)
        return self.clock

    def check_peer(self, now_s: float | None = None) -> bool:
        """Declare the peer lost if it was silent for ``peer_lost_after_s``; returns :attr:`peer_lost`.

        Called by the ticker every 50 ms; ``now_s`` (``time.monotonic()`` seconds) may be given for tests.
        """
        now = time.monotonic() if now_s is None else now_s
        silence = now - self._last_rx_s
        if not self.peer_lost and silence >= self.peer_lost_after_s:
            self.lost_silence_s = silence
            self._declare_lost(True)
        return self.peer_lost

    def close(self) -> None:
        """Stop the threads, fail pending requests with LinkClosedError, close the port. Idempotent."""
        if self._closed.is_set():
            return
        self._closed.set()
        with self._lock:
            for p in self._pending.values():
                p.error = LinkClosedError(f"{self.name}: link closed")
                p.event.set()
        port = self._port
        if port is not None:
            with contextlib.suppress(Exception):
                port.cancel_read()
        for t in (self._reader, self._ticker):
            if t is not threading.current_thread():
                t.join(timeout=2.0)
        if port is not None:
            with contextlib.suppress(Exception):
                port.close()
        self.connected = False

    # ------------------------------------------------------------------------------------------------ writing
    def _write(self, frame: bytes) -> None:
        port = self._port
        if port is None or not self.connected:
            raise DeviceLostError(f"{self.name}: serial port not connected")
        try:
            with self._write_lock:
                port.write(frame)
        except serial.SerialTimeoutException as exc:
            # the peer does not read (a device busy, a simulator not run on a loaded host): the port is fine, and
            # reopening it would throw away what the peer sent meanwhile; this frame is lost, counted
            with self._lock:
                self._counters["write_timeouts"] += 1
            log.warning("%s: write timed out (the peer does not read): frame dropped", self.name)
            raise DeviceLostError(f"{self.name}: write timed out: {exc}") from exc
        except (serial.SerialException, OSError) as exc:
            self._io_failed(exc)
            raise DeviceLostError(f"{self.name}: write failed: {exc}") from exc
        with self._lock:
            self._counters["frames_out"] += 1

    # ------------------------------------------------------------------------------------------------ threads
    def _read_loop(self) -> None:
        while not self._closed.is_set():
            port = self._port
            if port is None or not self.connected:
                self._closed.wait(0.05)
                continue
            try:
                data = port.read(max(1, port.in_waiting))
            except (serial.SerialException, OSError, TypeError, AttributeError) as exc:
                if self._closed.is_set():
                    return
                self._io_failed(exc)
                continue
            if data:
                for frame in self._decoder.feed(data):
                    self._handle(frame)

    def _tick_loop(self) -> None:
        next_hb = time.monotonic()
        next_reconnect = 0.0
        last_tick = next_hb
        while not self._closed.wait(TICK_S):
            now = time.monotonic()
            if now - last_tick > STARVED_TICK_GAP_S:
                # this process was not run (a loaded host): its reader could not take what the peer sent either, so
                # that time is no silence of the peer's
                self._last_rx_s = min(now, self._last_rx_s + (now - last_tick - TICK_S))
            last_tick = now
            if not self.connected:
                if self.reconnect and now >= next_reconnect:
                    next_reconnect = now + 0.5
                    self._try_reopen()
                continue
            self.check_peer(now)
            if self.heartbeat_period_s is not None and now >= next_hb:
                next_hb = now + self.heartbeat_period_s
                uptime_ms = int((now - self._opened_s) * 1000) & 0xFFFFFFFF
                try:
                    self.send(bproto.MSG_HEARTBEAT, {"uptime_ms": uptime_ms, "state": 0})
                    with self._lock:
                        self._counters["heartbeats_out"] += 1
                except DeviceLostError:
                    pass

    def _io_failed(self, exc: BaseException) -> None:
        if self._closed.is_set() or not self.connected:
            return
        log.warning("%s: serial I/O error: %s", self.name, exc)
        with self._lock:
            self._counters["io_errors"] += 1
        self.connected = False
        port, self._port = self._port, None
        if port is not None:
            with contextlib.suppress(Exception):
                port.close()
        self._declare_lost(True)

    def _try_reopen(self) -> None:
        try:
            port = open_serial(self.url, self.baudrate)
        except DeviceLostError:
            return
        self._decoder.reset()
        self._port = port
        self.connected = True
        with self._lock:
            self._counters["reconnects"] += 1
        log.info("%s: serial port reopened", self.name)

    # ------------------------------------------------------------------------------------------------ receiving
    def _declare_lost(self, lost: bool) -> None:
        with self._lock:
            if self.peer_lost == lost:
                return
            self.peer_lost = lost
            if lost:
                self._counters["peer_lost"] += 1
        for cb in list(self._lost_listeners):
            self._call(cb, lost)

    def _call(self, cb: Callable[..., None], *args: Any) -> None:
        try:
            cb(*args)
        except Exception:  # a listener must never kill the reader thread
            log.exception("%s: listener failed", self.name)
            with self._lock:
                self._counters["listener_errors"] += 1

    def _emit(self, msg_type: int, seq: int, fields: dict[str, Any]) -> None:
        for cb in list(self._listeners):
            self._call(cb, msg_type, seq, fields)

    def _handle(self, frame: bproto.Frame) -> None:
        recv_ns = self._time_ns()
        self._last_rx_s = time.monotonic()
        heard_before, self._heard_device = self._heard_device, True
        self._count_seq_gap(frame)
        if self.peer_lost and self.connected:
            self.lost_silence_s = None
            self._declare_lost(False)
        t = frame.msg_type
        try:
            fields = bproto.unpack_payload(t, frame.payload)
        except ValueError:
            with self._lock:
                if t in bproto.MSG_NAMES:
                    self._counters["bad_payloads"] += 1
                else:
                    self._counters["unknown_types"] += 1
            if t not in bproto.MSG_NAMES:
                self._emit(t, frame.seq, {"payload": frame.payload})
            return
        if t in (bproto.MSG_ACK, bproto.MSG_NACK):
            self._resolve_by_seq(fields["acked_seq"], t, fields)
        elif t == bproto.MSG_PONG:
            self._resolve_pong(fields, recv_ns)
        elif t == bproto.MSG_HELLO:
            self._on_hello(frame.seq, fields, heard_before)
        elif t == bproto.MSG_HEARTBEAT:
            self.device_state = fields["state"]
            uptime_ms = int(fields["uptime_ms"])
            with self._lock:
                self._counters["heartbeats_in"] += 1
                last, self._last_uptime_ms = self._last_uptime_ms, uptime_ms
            # uptime going back (not a 2**32 ms wrap) = the device rebooted and its boot HELLO was lost
            if last is not None and uptime_ms + UPTIME_SLACK_MS < last and last - uptime_ms < 1 << 31:
                log.info("%s: device uptime went back from %d to %d ms: rebooted", self.name, last, uptime_ms)
                self._rebooted(dict(self.device_info or {}), uptime_ms)
            self._emit(t, frame.seq, fields)
        elif t == bproto.MSG_TRIGGER:
            self._on_trigger(frame.seq, fields)
        elif t == bproto.MSG_BUTTON:
            self._on_button(frame.seq, fields)
        else:  # a host->device type sent by the device: count, hand over
            with self._lock:
                self._counters["unmatched_replies"] += 1
            self._emit(t, frame.seq, fields)

    def _count_seq_gap(self, frame: bproto.Frame) -> None:
        """Frames lost from the device: forward jumps of its own seq (re-sent frames repeat a seq: not gaps)."""
        with self._lock:
            last = self._last_device_seq
            if frame.msg_type == bproto.MSG_HELLO and frame.seq == 0:
                last = None  # boot: numbering restarts
            if last is not None:
                jump = (frame.seq - last) & 0xFFFF
                if jump == 0 or jump >= 0x8000:  # a repeat or an older frame
                    return
                self._counters["seq_gaps"] += jump - 1
            self._last_device_seq = frame.seq

    def _resolve_by_seq(self, acked_seq: int, reply_type: int, fields: dict[str, Any]) -> None:
        with self._lock:
            p = self._pending.get(acked_seq)
            if p is None and acked_seq in self._sent_seqs:
                self._counters["send_acks" if reply_type == bproto.MSG_ACK else "send_nacks"] += 1
                if reply_type == bproto.MSG_NACK:
                    log.warning("%s: device NACKed sent frame seq %d: %s", self.name, acked_seq,
                                bproto.NACK_NAMES.get(fields["code"], fields["code"]))
                return
            if p is None or (p.msg_type in (bproto.MSG_HELLO, bproto.MSG_PING) and reply_type == bproto.MSG_ACK):
                self._counters["unmatched_replies"] += 1
                return
            if p.event.is_set():
                return
            p.reply_type, p.fields = reply_type, fields
        p.event.set()

    def _resolve_pong(self, fields: dict[str, Any], recv_ns: int) -> None:
        stamp = fields["host_time_ns"]
        with self._lock:
            match = next((p for p in self._pending.values() if p.msg_type == bproto.MSG_PING and stamp in p.sent_ns),
                         None)
            if match is None:
                self._counters["unmatched_replies"] += 1
                return
        # A late PONG of an earlier send of the same PING is still a true exchange: use its own stamp.
        with contextlib.suppress(ValueError):
            self.clock.add_sample(stamp, recv_ns, fields["device_time_us"])
        with self._lock:
            if match.event.is_set():
                return
            match.reply_type, match.fields = bproto.MSG_PONG, fields
        match.event.set()

    def _on_hello(self, seq: int, fields: dict[str, Any], heard_before: bool) -> None:
        if not fields:  # a HELLO request from the device side: not expected, ignore
            with self._lock:
                self._counters["unmatched_replies"] += 1
            return
        self.device_info = fields
        # A device numbers its frames from 0 at boot and its boot HELLO is its first frame, so a HELLO with seq 0 is
        # a boot announcement even while a HELLO request is pending (its reply follows with a later seq).
        waiting: list[_Pending] = []
        if seq != 0:
            with self._lock:
                waiting = sorted((p for p in self._pending.values()
                                  if p.msg_type == bproto.MSG_HELLO and not p.event.is_set()), key=lambda p: p.seq)
                if waiting:
                    waiting[0].reply_type, waiting[0].fields = bproto.MSG_HELLO, fields
        if waiting:
            waiting[0].event.set()
            return
        with self._lock:
            self._counters["unsolicited_hellos"] += 1
        log.info("%s: device (re)booted: %s", self.name, fields)
        # heard before: this HELLO announces a reboot (else: the device booted after the link opened)
        self._rebooted(fields, None, count=heard_before)
        self._emit(bproto.MSG_HELLO, seq, fields)

    def _rebooted(self, fields: dict[str, Any], uptime_ms: int | None, count: bool = True) -> None:
        """The device (re)booted: count it (``reboots`` here is the one reboot count of a link; the trigger and
        panel clients read it), restart the clock model and call the reboot listeners with the device's HELLO
        fields."""
        with self._lock:
            if count:
                self._counters["reboots"] += 1
            self._last_uptime_ms = uptime_ms
        self.clock.reset()  # the device clock restarted
        for cb in list(self._reboot_listeners):
            self._call(cb, fields)

    def _on_trigger(self, seq: int, fields: dict[str, Any]) -> None:
        # Missing trigger_seq numbers are counted once, by the trigger client (it knows the session it started).
        with self._lock:
            self._counters["trigger_events"] += 1
        self._emit(bproto.MSG_TRIGGER, seq, fields)

    def _on_button(self, seq: int, fields: dict[str, Any]) -> None:
        # ACKs and duplicate BUTTON events are the panel client's (the application's) business, counted there once.
        with self._lock:
            self._counters["button_events"] += 1
        self._emit(bproto.MSG_BUTTON, seq, fields)
