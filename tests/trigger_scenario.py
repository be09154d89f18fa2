"""The acceptance scenario of the trigger, run against the real firmware in QEMU and the simulator.

HELLO -> SET_BRACKETS(45454 us, 1000..32000 us) -> START -> at least two full bracket cycles of TRIGGER events with
consecutive trigger_seq, bracket_index cycling 0..5 and the right exposure_us -> STOP (no more events) -> garbage and
corrupted frames ignored, the next command still answered -> invalid tables NACKed BAD_VALUE. No timing assertions.
"""

from __future__ import annotations

import itertools
import random
import time
from collections.abc import Callable

import pytest

from bracketry_rig.trigger.client import TriggerClient
from bracketry_rig.wire import bproto
from bracketry_rig.wire.errors import NackError

PERIOD_US = 45454
EXPOSURES_US = (1000, 2000, 4000, 8000, 16000, 32000)
SESSION_ID = 0xC0FFEE
#: (period_us, exposures_us) that the device must refuse with BAD_VALUE
INVALID_TABLES = [
    (999, [10]),  # period below 1000 us
    (1_000_001, [1000]),  # period above 1 s
    (45454, [9]),  # exposure below 10 us
    (45454, [1000, 45255]),  # exposure + 200 > period
    (45454, []),  # n = 0
    (45454, [1000] * 17),  # n > 16
]


def collect_events(client: TriggerClient, n: int, timeout_s: float = 60.0) -> list:
    """At least ``n`` events (fails after ``timeout_s`` without them)."""
    events = []
    deadline = time.monotonic() + timeout_s
    while len(events) < n and time.monotonic() < deadline:
        ev = client.get_event(0.5)
        if ev is not None:
            events.append(ev)
    assert len(events) >= n, f"only {len(events)} of {n} TRIGGER events within {timeout_s} s"
    return events


def check_events(events: list, session_id: int = SESSION_ID, first_seq: int = 0) -> None:
    """Consecutive trigger_seq from ``first_seq``, bracket_index cycling, the right widths, rising device times."""
    for i, ev in enumerate(events):
        seq = first_seq + i
        assert ev.session_id == session_id
        assert ev.trigger_seq == seq
        assert ev.bracket_index == seq % len(EXPOSURES_US)
        assert ev.exposure_us == EXPOSURES_US[seq % len(EXPOSURES_US)]
    times = [ev.t_start_device_us for ev in events]
    assert all(b > a for a, b in itertools.pairwise(times)), "device pulse times must increase"


def run_scenario(client: TriggerClient, raw_write: Callable[[bytes], None], quiet_s: float = 1.0) -> list:
    """The full scenario; returns the events of the session."""
    hello = client.hello()
    assert hello["device_kind"] == bproto.DEVICE_TRIGGER
    assert len(hello["uid"]) == 12
    client.sync_clock(4)
    client.configure(PERIOD_US, EXPOSURES_US)
    client.start(SESSION_ID)
    events = collect_events(client, 2 * len(EXPOSURES_US) + 1)
    check_events(events)
    # while running: a new table or another session is refused, the same session is acknowledged (no restart)
    with pytest.raises(NackError) as exc:
        client.configure(PERIOD_US, EXPOSURES_US)
    assert exc.value.code == bproto.NACK_BAD_STATE
    client.start(SESSION_ID)
    with pytest.raises(NackError) as exc:
        client.link.request(bproto.MSG_START, {"session_id": SESSION_ID + 1}, timeout_s=client.timeout_s)
    assert exc.value.code == bproto.NACK_BAD_STATE

    client.stop()
    tail = client.drain_events()  # events of pulses before STOP arrive before its ACK
    check_events(events + tail)
    assert client.get_event(quiet_s) is None, "TRIGGER event after STOP"
    client.stop()  # idempotent

    # garbage, a corrupted frame, a truncated frame, an unknown type: ignored / NACKed, next command answered
    rng = random.Random(4)
    raw_write(bytes(rng.randrange(1, 256) for _ in range(300)) + b"\x00")
    good = bproto.encode_message(bproto.MSG_STOP, 0x7777, {})
    corrupted = bytearray(good)
    corrupted[3] ^= 0x10
    raw_write(bytes(corrupted) + good[:3] + b"\x00" + b"\x00\x00\x13\x37")
    raw_write(bproto.encode_frame(0x7E, 0x7778, b""))  # unknown type: NACKed (the link counts an unmatched reply)
    assert client.hello()["device_kind"] == bproto.DEVICE_TRIGGER
    assert client.get_event(0.2) is None

    for period_us, exposures_us in INVALID_TABLES:
        with pytest.raises(NackError) as exc:
            client.configure(period_us, exposures_us)
        assert exc.value.code == bproto.NACK_BAD_VALUE, (period_us, len(exposures_us))
    client.configure(1000, [800])  # the boundary is accepted
    client.configure(PERIOD_US, EXPOSURES_US)
    return events + tail
