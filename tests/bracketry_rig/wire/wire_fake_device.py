"""A scripted bproto device on a pseudo-terminal (or a TCP socket) for link-layer tests.

It speaks the real protocol (bproto codec) from a thread: HELLO at boot and on request, PONG with a simulated device
clock (offset, drift, jitter), ACK/NACK of commands with the trigger's SET_BRACKETS/START/STOP rules, HEARTBEAT at
2 Hz. Scripting knobs: drop the next N replies of a type, mute heartbeats, go silent, reboot, emit TRIGGER/BUTTON
events, inject garbage.
"""

from __future__ import annotations

import contextlib
import os
import random
import select
import socket
import threading
import time
import tty
from typing import Any

from bracketry_rig.wire import bproto


class FakeDevice:
    """A device thread. ``path`` is the pty slave the link opens (or use ``url`` for both kinds); with ``tty_path``
    the device sits on that existing tty (one end of a socat pty pair) and the link opens the other end.

    Clock: ``device_time_us = offset_us + (monotonic_ns - t0) * (1 + drift_ppm * 1e-6) / 1000`` (+ a uniform
    ``clock_jitter_us`` and a random 0..``reply_delay_us`` delay before answering a PING).
    """

    def __init__(self, kind: int = bproto.DEVICE_TRIGGER, *, offset_us: int = 5_000_000_000, drift_ppm: float = 0.0,
                 clock_jitter_us: float = 0.0, reply_delay_us: float = 0.0, heartbeat: bool = True,
                 send_hello_at_boot: bool = True, seed: int = 1, tcp: bool = False,
                 tty_path: str | None = None) -> None:
        self.kind = kind
        self.offset_us = offset_us
        self.drift_ppm = drift_ppm
        self.clock_jitter_us = clock_jitter_us
        self.reply_delay_us = reply_delay_us
        self.heartbeat = heartbeat
        self.silent = False
        self.rng = random.Random(seed)
        self.t0_ns = time.monotonic_ns()
        self.drop_replies: dict[int, int] = {}  # msg_type -> number of next commands of that type left unanswered
        self.received: list[bproto.Frame] = []
        self.acked_buttons: list[int] = []
        self.running = False
        self.session_id: int | None = None
        self.brackets: tuple[int, list[int]] | None = None
        self._seq = 0
        self._decoder = bproto.Decoder()
        self._stop = threading.Event()
        self._lock = threading.Lock()
        self._boot_hello = send_hello_at_boot
        self._conn: socket.socket | None = None
        self._drop_conn = threading.Event()
        self._server: socket.socket | None = None
        if tcp:
            self._server = socket.socket(socket.AF_INET, socket.SOCK_STREAM)
            self._server.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
            self._server.bind(("127.0.0.1", 0))
            self._server.listen(1)
            self.url = f"socket://127.0.0.1:{self._server.getsockname()[1]}"
            self.path = self.url
            self._master = -1
            self._slave = -1
        elif tty_path is not None:  # one end of an existing pty pair (e.g. made by socat)
            self._master = os.open(tty_path, os.O_RDWR | os.O_NOCTTY)
            tty.setraw(self._master)
            self._slave = -1
            self.path = self.url = tty_path
        else:
            self._master, self._slave = os.openpty()
            tty.setraw(self._slave)  # no echo / line discipline before the link configures the port
            self.path = os.ttyname(self._slave)
            self.url = self.path
        self._thread = threading.Thread(target=self._run, name="fake-device", daemon=True)

    # ------------------------------------------------------------------ control
    def start(self) -> FakeDevice:
        self._thread.start()
        return self

    def close(self) -> None:
        self._stop.set()
        self._thread.join(timeout=5)
        for fd in (self._master, self._slave):
            if fd >= 0:
                os.close(fd)
        for s in (self._conn, self._server):
            if s is not None:
                s.close()

    def __enter__(self) -> FakeDevice:
        return self.start()

    def __exit__(self, *exc: object) -> None:
        self.close()

    def device_time_us(self) -> int:
        dt_ns = time.monotonic_ns() - self.t0_ns
        jitter = self.rng.uniform(-self.clock_jitter_us, self.clock_jitter_us) if self.clock_jitter_us else 0.0
        return int(self.offset_us + dt_ns * (1.0 + self.drift_ppm * 1e-6) / 1000.0 + jitter)

    def true_host_ns(self, device_us: int) -> int:
        """The monotonic host ns at which the device clock read ``device_us`` (ground truth, no jitter)."""
        return self.t0_ns + round((device_us - self.offset_us) * 1000.0 / (1.0 + self.drift_ppm * 1e-6))

    def reboot(self) -> None:
        """Simulate a reset: state cleared, clock restarted, unsolicited HELLO."""
        with self._lock:
            self.running = False
            self.session_id = None
            self.t0_ns = time.monotonic_ns()
            self._seq = 0
        self._send(bproto.MSG_HELLO, self._hello())

    def emit_trigger(self, session_id: int, trigger_seq: int, bracket_index: int = 0, exposure_us: int = 1000) -> None:
        self._send(bproto.MSG_TRIGGER, {"session_id": session_id, "trigger_seq": trigger_seq,
                                        "bracket_index": bracket_index, "exposure_us": exposure_us,
                                        "t_start_us": self.device_time_us()})

    def emit_button(self, button: int, action: int, event_seq: int, seq: int | None = None) -> int:
        return self._send(bproto.MSG_BUTTON, {"button": button, "action": action, "event_seq": event_seq}, seq)

    def disconnect(self) -> None:
        """TCP mode: drop the current connection ("unplug"); the next connection gets a boot HELLO."""
        self._drop_conn.set()

    def write_raw(self, data: bytes) -> None:
        self._write(data)

    def frames_of(self, msg_type: int) -> list[bproto.Frame]:
        with self._lock:
            return [f for f in self.received if f.msg_type == msg_type]

    # ------------------------------------------------------------------ internals
    def _hello(self) -> dict[str, Any]:
        return {"device_kind": self.kind, "proto_minor": 0, "fw_major": 1, "fw_minor": 2, "fw_patch": 3,
                "uid": b"FAKE-DEVICE1", "capabilities": 0}

    def _write(self, data: bytes) -> None:
        if self._server is not None:
            if self._conn is not None:
                with contextlib.suppress(OSError):
                    self._conn.sendall(data)
            return
        os.write(self._master, data)

    def _send(self, msg_type: int, fields: dict[str, Any], seq: int | None = None) -> int:
        with self._lock:
            if seq is None:
                seq = self._seq
                self._seq = (self._seq + 1) & 0xFFFF
        self._write(bproto.encode_message(msg_type, seq, fields))
        return seq

    def _reply(self, cmd: bproto.Frame, msg_type: int, fields: dict[str, Any]) -> None:
        with self._lock:
            left = self.drop_replies.get(cmd.msg_type, 0)
            if left > 0:
                self.drop_replies[cmd.msg_type] = left - 1
                return
        if self.silent:
            return
        self._send(msg_type, fields)

    def _handle(self, f: bproto.Frame) -> None:
        with self._lock:
            self.received.append(f)
        t = f.msg_type
        if t in (bproto.MSG_HEARTBEAT, bproto.MSG_NACK):
            return
        if t == bproto.MSG_ACK:
            if len(f.payload) == 2:
                self.acked_buttons.append(bproto.unpack_payload(t, f.payload)["acked_seq"])
            return
        code = bproto.nack_code_for(t, f.payload) if t != bproto.MSG_PANEL_STATE else 0
        if t not in (bproto.MSG_HELLO, bproto.MSG_PING, bproto.MSG_SET_BRACKETS, bproto.MSG_START, bproto.MSG_STOP,
                     bproto.MSG_PANEL_STATE):
            code = bproto.NACK_UNKNOWN_TYPE
        if code:
            self._reply(f, bproto.MSG_NACK, {"acked_seq": f.seq, "code": code})
            return
        fields = bproto.unpack_payload(t, f.payload)
        if t == bproto.MSG_HELLO:
            self._reply(f, bproto.MSG_HELLO, self._hello())
        elif t == bproto.MSG_PING:
            if self.reply_delay_us:
                time.sleep(self.rng.uniform(0, self.reply_delay_us) / 1e6)
            self._reply(f, bproto.MSG_PONG, {"host_time_ns": fields["host_time_ns"],
                                             "device_time_us": self.device_time_us()})
        elif t == bproto.MSG_SET_BRACKETS:
            if self.running:
                code = bproto.NACK_BAD_STATE
            else:
                code = bproto.check_set_brackets(fields["period_us"], fields["exposures_us"])
            if code == 0:
                self.brackets = (fields["period_us"], fields["exposures_us"])
            self._ack_or_nack(f, code)
        elif t == bproto.MSG_START:
            if self.running and self.session_id != fields["session_id"]:
                self._ack_or_nack(f, bproto.NACK_BAD_STATE)
                return
            self.running, self.session_id = True, fields["session_id"]
            self._ack_or_nack(f, 0)
        elif t == bproto.MSG_STOP:
            self.running = False
            self._ack_or_nack(f, 0)
        else:  # PANEL_STATE
            self._ack_or_nack(f, 0)

    def _ack_or_nack(self, f: bproto.Frame, code: int) -> None:
        if code:
            self._reply(f, bproto.MSG_NACK, {"acked_seq": f.seq, "code": code})
        else:
            self._reply(f, bproto.MSG_ACK, {"acked_seq": f.seq})

    def _read(self, timeout_s: float) -> bytes:
        if self._server is not None:
            if self._drop_conn.is_set() and self._conn is not None:
                self._drop_conn.clear()
                self._conn.close()
                self._conn = None
            if self._conn is None:
                r, _, _ = select.select([self._server], [], [], timeout_s)
                if r:
                    self._conn, _ = self._server.accept()
                    if self._boot_hello:
                        self._send(bproto.MSG_HELLO, self._hello())
                return b""
            r, _, _ = select.select([self._conn], [], [], timeout_s)
            if not r:
                return b""
            data = self._conn.recv(4096)
            if not data:  # host closed: wait for the next connection
                self._conn.close()
                self._conn = None
            return data
        r, _, _ = select.select([self._master], [], [], timeout_s)
        if not r:
            return b""
        try:
            return os.read(self._master, 4096)
        except OSError:
            return b""

    def _run(self) -> None:
        if self._boot_hello and self._server is None:
            self._send(bproto.MSG_HELLO, self._hello())
        next_hb = time.monotonic() + 0.5
        while not self._stop.is_set():
            data = self._read(0.01)
            for frame in self._decoder.feed(data):
                self._handle(frame)
            now = time.monotonic()
            if now >= next_hb:
                next_hb = now + 0.5
                if self.heartbeat and not self.silent and (self._server is None or self._conn is not None):
                    uptime_ms = (time.monotonic_ns() - self.t0_ns) // 1_000_000
                    self._send(bproto.MSG_HEARTBEAT, {"uptime_ms": uptime_ms & 0xFFFFFFFF,
                                                      "state": 1 if self.running else 0})
