"""Behavioural simulator of the STM32 trigger: the wire protocol of the firmware, with real-time pulses.

It behaves like ``firmware/stm32_trigger`` (same replies, NACK codes, TRIGGER events, 2 Hz heartbeat, unsolicited
HELLO at boot) and adds the imperfections host code must survive: device clock drift (ppm) and offset, pulse jitter,
reply latency jitter (what the clock model must filter), dropped TRIGGER events (the ``trigger_seq`` still advances)
and reboots (state lost, device clock back to 0, unsolicited HELLO).

Transport: a file descriptor that reads and writes bytes (the master side of a pty, see :func:`open_pty`); the host
opens the pty's slave path (or a symlink to it) with pyserial like a real port.
"""

from __future__ import annotations

import contextlib
import os
import random
import select
import termios
import threading
import time
import tty
from dataclasses import dataclass, field
from pathlib import Path

from bracketry_rig.wire import bproto

#: default table of the firmware at boot: 22 fps, 1..32 ms
DEFAULT_PERIOD_US = 45454
DEFAULT_EXPOSURES_US = (1000, 2000, 4000, 8000, 16000, 32000)
HEARTBEAT_PERIOD_S = 0.5
#: HELLO capabilities the simulator reports: bit 4 (exposure while low) and bit 6 "simulated" (firmware: bits 0..5)
SIM_CAPABILITIES = (1 << 4) | (1 << 6)


@dataclass
class SimConfig:
    """Imperfections of the simulated trigger.

    Attributes:
        drift_ppm: device clock rate error; device_us advances (1 + drift_ppm * 1e-6) times as fast as host time.
        offset_us: device clock value at boot (the firmware boots at 0).
        pulse_jitter_us: standard deviation of the real pulse start around its schedule, microseconds.
        reply_jitter_us: mean of an exponential extra delay before each reply (PONG, ACK...), microseconds.
        drop_prob: probability that a TRIGGER event is not sent (its trigger_seq is consumed: the host sees a gap).
        drop_seqs: trigger_seq values whose events are never sent.
        seed: random seed (deterministic imperfections).
        uid: 12-byte unique id reported in HELLO.
    """

    drift_ppm: float = 0.0
    offset_us: int = 0
    pulse_jitter_us: float = 0.0
    reply_jitter_us: float = 0.0
    drop_prob: float = 0.0
    drop_seqs: frozenset[int] = field(default_factory=frozenset)
    seed: int = 0
    uid: bytes = b"BRKTSIM00001"


class TriggerSimulator:
    """A simulated trigger serving the wire protocol on ``fd`` (threads: reader, pulse/heartbeat scheduler).

    Args:
        fd: readable and writable file descriptor (pty master); not closed by :meth:`close` unless ``own_fd``.
        config: imperfections (:class:`SimConfig`).
        own_fd: close ``fd`` (and ``keep_fds``) in :meth:`close`.
        keep_fds: other descriptors to close with the simulator (e.g. the pty slave kept open so that the master
            never sees EOF while no host is connected).
    """

    def __init__(self, fd: int, config: SimConfig | None = None, own_fd: bool = False,
                 keep_fds: tuple[int, ...] = ()) -> None:
        self.fd = fd
        self.config = config or SimConfig()
        self._own_fd = own_fd
        self._keep_fds = keep_fds
        self._rng = random.Random(self.config.seed)
        self._noise_rng = random.Random(self.config.seed + 0x5E7A1)  # line noise (send_garbage), apart from _rng
        self._lock = threading.RLock()
        self._write_lock = threading.Lock()
        self._wake = threading.Event()
        self._closed = threading.Event()
        self._threads: list[threading.Thread] = []
        #: counters: pulses generated, events sent, events dropped on purpose, reboots, frames received
        self.counters = {"pulses": 0, "events_sent": 0, "events_dropped": 0, "reboots": 0, "frames_rx": 0,
                         "nacks": 0}
        self._boot()

    # ------------------------------------------------------------------ device state
    def _boot(self) -> None:
        with self._lock:
            self._boot_ns = time.monotonic_ns()
            self._tx_seq = 0
            self._decoder = bproto.Decoder()
            self.period_us = DEFAULT_PERIOD_US
            self.exposures_us: tuple[int, ...] = DEFAULT_EXPOSURES_US
            self.running = False
            self.session_id = 0
            self._next_seq = 0
            self._first_pulse_dev_us = 0
            self._next_heartbeat_ns = self._boot_ns + int(HEARTBEAT_PERIOD_S * 1e9)

    def device_time_us(self, mono_ns: int | None = None) -> int:
        """Device clock (microseconds since boot, with drift and offset) at host monotonic time ``mono_ns``."""
        if mono_ns is None:
            mono_ns = time.monotonic_ns()
        elapsed_ns = mono_ns - self._boot_ns
        return self.config.offset_us + int(elapsed_ns * (1.0 + self.config.drift_ppm * 1e-6) / 1000.0)

    def _mono_ns_of_device_us(self, device_us: float) -> int:
        return self._boot_ns + int((device_us - self.config.offset_us) * 1000.0 / (1.0 + self.config.drift_ppm * 1e-6))

    # ------------------------------------------------------------------ transport
    def _send(self, msg_type: int, fields: dict | None = None, delay: bool = False) -> None:
        if delay and self.config.reply_jitter_us > 0:
            time.sleep(self._rng.expovariate(1.0 / self.config.reply_jitter_us) * 1e-6)
        with self._write_lock:
            frame = bproto.encode_message(msg_type, self._tx_seq, fields or {})
            self._tx_seq = (self._tx_seq + 1) & 0xFFFF
            with contextlib.suppress(OSError):  # nobody listening: like a UART with no cable
                os.write(self.fd, frame)

    def send_garbage(self, n_bytes: int = 256) -> bytes:
        """Line noise: ``n_bytes`` pseudo-random bytes (seeded by ``config.seed``) written between two frames, as a
        loose cable or a ground loop would put on the wire; returns them. The host's decoder drops and counts them."""
        with self._write_lock:
            noise = bytes(self._noise_rng.randrange(256) for _ in range(n_bytes))
            with contextlib.suppress(OSError):
                os.write(self.fd, noise)
            self.counters["garbage_bytes"] = self.counters.get("garbage_bytes", 0) + n_bytes
        return noise

    def start(self) -> TriggerSimulator:
        """Start the threads and announce the device with an unsolicited HELLO. Returns self."""
        for target, name in ((self._reader, "trigger-sim-rx"), (self._scheduler, "trigger-sim-pulses")):
            t = threading.Thread(target=target, name=name, daemon=True)
            t.start()
            self._threads.append(t)
        self._send_hello()
        return self

    def close(self) -> None:
        """Stop the threads (and close the descriptors if owned)."""
        self._closed.set()
        self._wake.set()
        for t in self._threads:
            t.join(timeout=2.0)
        if self._own_fd:
            for fd in (self.fd, *self._keep_fds):
                with contextlib.suppress(OSError):
                    os.close(fd)

    def __enter__(self) -> TriggerSimulator:
        return self.start()

    def __exit__(self, *exc: object) -> None:
        self.close()

    def reboot(self, announce: bool = True) -> None:
        """Simulate a reset: outputs stop, state and device clock restart, unsolicited HELLO (unless
        ``announce`` is False: a HELLO lost on the wire, so the host must notice from the heartbeat uptime)."""
        with self._lock:
            self.counters["reboots"] += 1
            self._boot()
        if announce:
            self._send_hello()
        self._wake.set()

    # ------------------------------------------------------------------ protocol
    def _send_hello(self) -> None:
        self._send(bproto.MSG_HELLO, {"device_kind": bproto.DEVICE_TRIGGER, "proto_minor": 0, "fw_major": 0,
                                      "fw_minor": 1, "fw_patch": 0, "uid": self.config.uid,
                                      "capabilities": SIM_CAPABILITIES})

    def _reply(self, seq: int, code: int = 0) -> None:
        """ACK (code 0) or NACK ``code`` of the command numbered ``seq``."""
        if code:
            self.counters["nacks"] += 1
            self._send(bproto.MSG_NACK, {"acked_seq": seq, "code": code}, delay=True)
        else:
            self._send(bproto.MSG_ACK, {"acked_seq": seq}, delay=True)

    def handle_frame(self, frame: bproto.Frame) -> None:
        """Answer one decoded host frame exactly like the firmware's ``trig_core_handle_frame``."""
        self.counters["frames_rx"] += 1
        t, seq, payload = frame.msg_type, frame.seq, bytes(frame.payload)
        if t in (bproto.MSG_HEARTBEAT, bproto.MSG_ACK, bproto.MSG_NACK):
            return
        if t not in (bproto.MSG_HELLO, bproto.MSG_PING, bproto.MSG_SET_BRACKETS, bproto.MSG_START, bproto.MSG_STOP):
            self._reply(seq, bproto.NACK_UNKNOWN_TYPE)
            return
        if t == bproto.MSG_HELLO:
            if payload:
                self._reply(seq, bproto.NACK_BAD_LENGTH)
            else:
                self._send_hello()
            return
        code = bproto.nack_code_for(t, payload)
        if code:
            self._reply(seq, code)
            return
        fields = bproto.unpack_payload(t, payload)
        if t == bproto.MSG_PING:
            device_us = self.device_time_us()
            self._send(bproto.MSG_PONG, {"host_time_ns": fields["host_time_ns"], "device_time_us": device_us},
                       delay=True)
        elif t == bproto.MSG_SET_BRACKETS:
            with self._lock:
                if self.running:
                    code = bproto.NACK_BAD_STATE
                else:
                    code = bproto.check_set_brackets(fields["period_us"], fields["exposures_us"])
                    if not code:
                        self.period_us = int(fields["period_us"])
                        self.exposures_us = tuple(int(e) for e in fields["exposures_us"])
            self._reply(seq, code)
        elif t == bproto.MSG_START:
            with self._lock:
                if self.running:
                    code = 0 if fields["session_id"] == self.session_id else bproto.NACK_BAD_STATE
                    self._reply(seq, code)
                    return
                self.session_id = int(fields["session_id"])
                self._next_seq = 0
                self._reply(seq)  # the ACK precedes the first TRIGGER
                self._first_pulse_dev_us = self.device_time_us() + 1
                self.running = True
            self._wake.set()
        elif t == bproto.MSG_STOP:
            with self._lock:
                self.running = False
                self._reply(seq)

    def _reader(self) -> None:
        while not self._closed.is_set():
            try:
                ready, _, _ = select.select([self.fd], [], [], 0.1)
            except (OSError, ValueError):
                return
            if not ready:
                continue
            try:
                data = os.read(self.fd, 4096)
            except OSError:
                time.sleep(0.05)  # pty master without a slave open: wait for the host
                continue
            if not data:
                time.sleep(0.05)
                continue
            with self._lock:
                frames = self._decoder.feed(data)
            for frame in frames:
                self.handle_frame(frame)

    # ------------------------------------------------------------------ pulses and heartbeat
    def _emit_pulse(self) -> None:
        k = self._next_seq
        self._next_seq += 1
        n = len(self.exposures_us)
        idx = k % n
        scheduled = self._first_pulse_dev_us + k * self.period_us
        jitter = self._rng.gauss(0.0, self.config.pulse_jitter_us) if self.config.pulse_jitter_us > 0 else 0.0
        t_start_us = max(0, round(scheduled + jitter))
        self.counters["pulses"] += 1
        if k in self.config.drop_seqs or (self.config.drop_prob > 0 and self._rng.random() < self.config.drop_prob):
            self.counters["events_dropped"] += 1
            return
        self._send(bproto.MSG_TRIGGER, {"session_id": self.session_id, "trigger_seq": k & 0xFFFFFFFF,
                                        "bracket_index": idx, "exposure_us": self.exposures_us[idx],
                                        "t_start_us": t_start_us})
        self.counters["events_sent"] += 1

    def _scheduler(self) -> None:
        while not self._closed.is_set():
            now_ns = time.monotonic_ns()
            with self._lock:
                due_ns = self._next_heartbeat_ns
                if now_ns >= self._next_heartbeat_ns:
                    uptime_ms = (self.device_time_us(now_ns) - self.config.offset_us) // 1000
                    self._send(bproto.MSG_HEARTBEAT, {"uptime_ms": uptime_ms & 0xFFFFFFFF, "state": int(self.running)})
                    self._next_heartbeat_ns += int(HEARTBEAT_PERIOD_S * 1e9)
                    if self._next_heartbeat_ns <= now_ns:
                        self._next_heartbeat_ns = now_ns + int(HEARTBEAT_PERIOD_S * 1e9)
                    due_ns = self._next_heartbeat_ns
                if self.running:
                    pulse_dev_us = self._first_pulse_dev_us + self._next_seq * self.period_us
                    pulse_ns = self._mono_ns_of_device_us(pulse_dev_us)
                    if now_ns >= pulse_ns:
                        self._emit_pulse()
                        continue
                    due_ns = min(due_ns, pulse_ns)
            self._wake.wait(timeout=max(0.0, min(0.1, (due_ns - time.monotonic_ns()) * 1e-9)))
            self._wake.clear()


def open_pty(link_path: str | Path | None = None) -> tuple[int, int, str]:
    """A raw pty pair for a simulated device: returns (master_fd, slave_fd, host_path).

    ``host_path`` is the slave's /dev/pts path, or ``link_path`` made a symlink to it (replacing a stale link).
    Raw mode is set with TCSANOW (TCSAFLUSH silently drops bytes already queued).
    """
    master, slave = os.openpty()
    for fd in (master, slave):
        tty.setraw(fd, termios.TCSANOW)
    path = os.ttyname(slave)
    if link_path is not None:
        link = Path(link_path)
        if link.is_symlink() or link.exists():
            if not link.is_symlink():
                os.close(master)
                os.close(slave)
                raise FileExistsError(f"{link} exists and is not a symlink")
            link.unlink()
        link.symlink_to(path)
        path = str(link)
    return master, slave, path


def simulate_on_pty(link_path: str | Path | None = None, config: SimConfig | None = None
                    ) -> tuple[TriggerSimulator, str]:
    """Start a :class:`TriggerSimulator` on a new pty; returns (simulator, path the host opens)."""
    master, slave, path = open_pty(link_path)
    sim = TriggerSimulator(master, config, own_fd=True, keep_fds=(slave,))
    sim.start()
    return sim, path
