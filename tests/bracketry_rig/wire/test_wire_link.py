"""SerialLink over a pseudo-terminal (and socket://) against a scripted device thread speaking real bproto."""

from __future__ import annotations

import subprocess
import threading
import time
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any

import pytest
from wire_fake_device import FakeDevice

from bracketry_rig.panel.client import PanelClient
from bracketry_rig.trigger.client import TriggerClient
from bracketry_rig.wire import bproto
from bracketry_rig.wire.errors import DeviceLostError, LinkClosedError, NackError
from bracketry_rig.wire.link import STARVED_TICK_GAP_S, SerialLink
from bracketry_testkit import stop_process


def wait_for(cond: Callable[[], bool], timeout_s: float = 10.0) -> bool:
    """Poll ``cond`` every 10 ms for up to ``timeout_s`` (generous: the machine is shared)."""
    end = time.monotonic() + timeout_s
    while time.monotonic() < end:
        if cond():
            return True
        time.sleep(0.01)
    return cond()


@pytest.fixture
def device() -> Iterator[FakeDevice]:
    dev = FakeDevice(drift_ppm=100.0, clock_jitter_us=2.0).start()
    yield dev
    dev.close()


@pytest.fixture
def link(device: FakeDevice) -> Iterator[SerialLink]:
    lk = SerialLink(device.path)
    yield lk
    lk.close()


# Generous reply timeout for a loaded 2-core machine; the protocol default (0.1 s) is tested in test_wire_retry_*.
T = 1.0


def test_wire_link_hello_over_pty(link: SerialLink) -> None:
    """The pty rejects the DTR/RTS ioctls or ignores them: opening still works, HELLO is answered."""
    info = link.hello(timeout_s=T)
    assert info["device_kind"] == bproto.DEVICE_TRIGGER and info["uid"] == b"FAKE-DEVICE1"
    assert link.device_info == info
    port = link._port
    assert port is not None and port.dtr is False and port.rts is False  # ESP32 boards reset when these toggle


def test_wire_link_ack_and_device_state(link: SerialLink, device: FakeDevice) -> None:
    reply = link.request(bproto.MSG_SET_BRACKETS, {"period_us": 50_000, "exposures_us": [1000, 2000, 4000]}, T)
    assert device.brackets == (50_000, [1000, 2000, 4000])
    assert reply["acked_seq"] == device.frames_of(bproto.MSG_SET_BRACKETS)[-1].seq
    link.request(bproto.MSG_START, {"session_id": 9}, T)
    assert device.running
    link.request(bproto.MSG_START, {"session_id": 9}, T)  # same session again: ACK, no restart
    link.request(bproto.MSG_STOP, {}, T)
    link.request(bproto.MSG_STOP, {}, T)  # idempotent
    assert not device.running


def test_wire_retry_on_dropped_ack(link: SerialLink, device: FakeDevice) -> None:
    """The first reply is lost: the link re-sends the SAME frame (same seq) and gets the ACK."""
    link.hello(timeout_s=T)
    device.drop_replies[bproto.MSG_START] = 1
    # protocol timing (100 ms); extra retries only absorb scheduling hiccups of the shared test machine
    reply = link.request(bproto.MSG_START, {"session_id": 3}, timeout_s=0.1, retries=10)
    starts = device.frames_of(bproto.MSG_START)
    assert len(starts) >= 2 and len({f.seq for f in starts}) == 1
    assert reply["acked_seq"] == starts[0].seq
    assert link.counters["retries"] >= 1 and link.counters["timeouts"] == 0


def test_wire_nack_surfaces_as_clear_error(link: SerialLink) -> None:
    with pytest.raises(NackError) as info:
        link.request(bproto.MSG_SET_BRACKETS, {"period_us": 1000, "exposures_us": [900]}, T)
    assert info.value.code == bproto.NACK_BAD_VALUE
    assert "SET_BRACKETS" in str(info.value) and "BAD_VALUE" in str(info.value)
    link.request(bproto.MSG_START, {"session_id": 1}, T)
    with pytest.raises(NackError) as info:
        link.request(bproto.MSG_START, {"session_id": 2}, T)
    assert info.value.code == bproto.NACK_BAD_STATE
    with pytest.raises(NackError) as info:
        link.request(bproto.MSG_BUTTON, {"button": 1, "action": 1, "event_seq": 0}, T)  # not a trigger command
    assert info.value.code == bproto.NACK_UNKNOWN_TYPE
    assert link.counters["nacks"] == 3


def test_wire_no_reply_means_device_lost(link: SerialLink, device: FakeDevice) -> None:
    link.hello(timeout_s=T)
    device.heartbeat = False  # a silent device (heartbeats would show it alive again)
    device.drop_replies[bproto.MSG_STOP] = 100
    with pytest.raises(DeviceLostError, match="after 3 retries"):
        link.request(bproto.MSG_STOP, {}, timeout_s=0.1, retries=3)
    assert wait_for(lambda: len(device.frames_of(bproto.MSG_STOP)) >= 4)
    time.sleep(0.3)
    assert len(device.frames_of(bproto.MSG_STOP)) == 4  # 1 send + 3 retries, all with the same seq
    assert len({f.seq for f in device.frames_of(bproto.MSG_STOP)}) == 1
    assert link.peer_lost
    assert link.counters["timeouts"] == 1 and link.counters["retries"] == 3


def test_wire_reboot_detected(device: FakeDevice) -> None:
    reboots: list[dict[str, Any]] = []
    with SerialLink(device.path, on_reboot=reboots.append) as link:
        link.hello(timeout_s=T)
        before = link.counters["reboots"]
        device.reboot()
        assert wait_for(lambda: link.counters["reboots"] == before + 1)
        assert reboots and reboots[-1]["device_kind"] == bproto.DEVICE_TRIGGER
        assert link.clock.n_samples == 0  # the device clock restarted: the model was reset


def test_wire_reboot_from_uptime_counted_once_by_the_link(device: FakeDevice) -> None:
    device.heartbeat = False  # heartbeats sent by hand below
    with SerialLink(device.path) as link:
        link.hello(timeout_s=T)
        client = TriggerClient(link)  # reads the link's count, never counts itself
        before, beats = link.counters["reboots"], link.counters["heartbeats_in"]
        # a 2**32 ms wrap (not a reboot), then uptime back from 60 s to 0.2 s: one reboot whose HELLO was lost
        for uptime_ms in (0xFFFFFFF0, 5, 1000, 60_000, 200, 700):
            device._send(bproto.MSG_HEARTBEAT, {"uptime_ms": uptime_ms, "state": 0})
        assert wait_for(lambda: link.counters["heartbeats_in"] == beats + 6)
        assert link.counters["reboots"] == before + 1
        assert client.counters.reboots == before + 1
        device.reboot()  # a boot HELLO: one more, counted once
        assert wait_for(lambda: link.counters["reboots"] == before + 2)
        assert client.counters.reboots == before + 2


def test_wire_heartbeat_loss_detected_within_1_5s(link: SerialLink, device: FakeDevice) -> None:
    events: list[bool] = []
    link.add_lost_listener(events.append)
    assert wait_for(lambda: link.counters["heartbeats_in"] >= 1)
    assert not link.peer_lost
    assert wait_for(lambda: device.frames_of(bproto.MSG_HEARTBEAT) != [])  # the host heartbeats too
    device.heartbeat = False
    assert wait_for(lambda: link.peer_lost, timeout_s=10.0)
    # Declared at the first check after 1.5 s of silence (= 3 missed heartbeats). The check before saw less than
    # 1.5 s, and a check later than STARVED_TICK_GAP_S after it does not count its wait as silence: so the silence
    # declared stays under 1.5 s + that gap however late the ticker runs.
    assert link.lost_silence_s is not None and 1.5 <= link.lost_silence_s < 1.5 + STARVED_TICK_GAP_S
    device.heartbeat = True
    assert wait_for(lambda: not link.peer_lost)
    assert events[:2] == [True, False]


def test_wire_peer_check_is_exact() -> None:
    """The rule itself, on explicit times: lost at >= 1.5 s of silence, not before."""
    dev = FakeDevice(heartbeat=False, send_hello_at_boot=False).start()
    try:
        link = SerialLink(dev.path, heartbeat_period_s=None)
        try:
            last = link._last_rx_s
            assert not link.check_peer(last + 1.49)
            assert link.check_peer(last + 1.5)
            assert link.lost_silence_s == pytest.approx(1.5)
        finally:
            link.close()
    finally:
        dev.close()


def test_wire_clock_model_over_pty(link: SerialLink, device: FakeDevice) -> None:
    """PING/PONG over the pty against a device clock with 100 ppm drift and +-2 us tick jitter: every exchange is a
    sample, and the map's error against the truth is within the bound the model gives from its own round trips (a
    guarantee for stamps that bracket the device's reading, whatever the pty's timing; the model's accuracy on
    seeded round trips is tests/bracketry_rig/wire/test_wire_clock.py's)."""
    for _ in range(80):
        link.ping(timeout_s=T)
        time.sleep(0.005)
    clock = link.clock
    assert clock.n_samples == 80 and clock.n_fit_samples == 8
    for _ in range(5):
        d = device.device_time_us()
        err_us = abs(clock.device_to_host_ns(d) - device.true_host_ns(d)) / 1000.0
        assert err_us <= clock.error_bound_us(d, device_jitter_us=device.clock_jitter_us)


def test_wire_trigger_gaps_and_buttons(device: FakeDevice) -> None:
    got: list[tuple[int, dict[str, Any]]] = []
    pressed: list[int] = []
    with SerialLink(device.path) as link:
        link.add_listener(lambda t, s, f: got.append((t, f)))
        client = TriggerClient(link)  # the one counter of missing trigger events
        panel = PanelClient(link, dict, on_button=lambda e: pressed.append(e.event_seq))  # the one of duplicates
        link.hello(timeout_s=T)
        for k in (0, 1, 2, 5, 6):  # 3 and 4 lost
            device.emit_trigger(77, k)
        seq = device.emit_button(2, 1, event_seq=0)
        device.emit_button(2, 1, event_seq=0, seq=seq)  # re-sent before the ACK arrived
        assert wait_for(lambda: link.counters["button_events"] == 2 and link.counters["trigger_events"] == 5)
        assert client.counters.missed_events == 2 and client.counters.gaps == [(3, 5)]
        assert "trigger_gaps" not in link.counters  # counted once, by the trigger client
        assert "button_duplicates" not in link.counters  # counted once, by the panel client
        assert wait_for(lambda: panel.counters["duplicates"] == 1)
        assert wait_for(lambda: device.acked_buttons.count(seq) == 2)  # every copy ACKed, by the panel client
        assert [f["event_seq"] for t, f in got if t == bproto.MSG_BUTTON] == [0, 0]  # the link hands on both
        assert pressed == [0] and panel.counters["buttons"] == 1  # acted on once
        assert [f["trigger_seq"] for t, f in got if t == bproto.MSG_TRIGGER] == [0, 1, 2, 5, 6]


def test_wire_fire_and_forget_send(link: SerialLink, device: FakeDevice) -> None:
    """send() does not wait; the device's ACK/NACK of it is counted, not taken for a stray reply."""
    link.hello(timeout_s=T)
    fields = {"cam_left": 2, "cam_right": 2, "trigger": 1, "imu": 0, "lidar": 0, "gnss": 0, "free_disk_mb": 10,
              "fps_left_centi": 1000, "fps_right_centi": 1000, "rec_seconds": 1, "message": "REC"}
    seq = link.send(bproto.MSG_PANEL_STATE, fields)
    link.send(bproto.MSG_BUTTON, {"button": 1, "action": 1, "event_seq": 0})  # not a device command: NACK
    assert wait_for(lambda: link.counters["send_acks"] == 1 and link.counters["send_nacks"] == 1)
    assert device.frames_of(bproto.MSG_PANEL_STATE)[-1].seq == seq
    assert link.counters["unmatched_replies"] == 0


def test_wire_device_frame_gaps_counted(link: SerialLink, device: FakeDevice) -> None:
    client = TriggerClient(link)
    link.hello(timeout_s=T)
    before = link.counters["seq_gaps"]
    device.emit_trigger(1, 0)
    with device._lock:
        device._seq = (device._seq + 5) & 0xFFFF  # five device frames "lost on the wire"
    device.emit_trigger(1, 1)
    assert wait_for(lambda: link.counters["trigger_events"] == 2)
    assert link.counters["seq_gaps"] == before + 5
    assert client.counters.missed_events == 0 and client.counters.events == 2  # frames lost, no trigger event


def test_wire_link_survives_garbage(link: SerialLink, device: FakeDevice) -> None:
    device.write_raw(b"\x13\x37noise\x00\xff" * 20 + b"\x01" * 400 + b"\x00")
    assert link.hello(timeout_s=T)["device_kind"] == bproto.DEVICE_TRIGGER
    assert link.counters["resyncs"] >= 2 and link.counters["overflows"] >= 1


def test_wire_concurrent_requests(link: SerialLink) -> None:
    errors: list[BaseException] = []

    def worker() -> None:
        try:
            for _ in range(10):
                link.request(bproto.MSG_STOP, {}, T)
                link.ping(timeout_s=T)
        except BaseException as exc:  # pragma: no cover - reported below
            errors.append(exc)

    threads = [threading.Thread(target=worker) for _ in range(3)]
    for t in threads:
        t.start()
    for t in threads:
        t.join(60)
    assert errors == []
    assert link.clock.n_samples == 30


def test_wire_close_fails_pending_and_later_requests(link: SerialLink, device: FakeDevice) -> None:
    device.silent = True
    result: list[BaseException] = []

    def blocked() -> None:
        try:
            link.request(bproto.MSG_STOP, {}, timeout_s=5.0, retries=0)
        except BaseException as exc:
            result.append(exc)

    t = threading.Thread(target=blocked)
    t.start()
    time.sleep(0.2)
    link.close()
    t.join(10)
    assert result and isinstance(result[0], LinkClosedError)
    with pytest.raises(LinkClosedError):
        link.request(bproto.MSG_STOP, {})


def test_wire_link_over_socket_url_and_reconnect() -> None:
    """socket:// works the same; when the peer drops the connection the link reconnects by itself."""
    dev = FakeDevice(tcp=True).start()
    try:
        with SerialLink(dev.url) as link:
            assert link.hello(timeout_s=T)["uid"] == b"FAKE-DEVICE1"
            dev.disconnect()  # "unplug"
            assert wait_for(lambda: link.counters["reconnects"] >= 1, timeout_s=15)
            assert wait_for(lambda: _try_hello(link), timeout_s=15)
    finally:
        dev.close()


def _try_hello(link: SerialLink) -> bool:
    try:
        link.hello(timeout_s=0.5)
        return True
    except DeviceLostError:
        return False


def test_wire_open_failure_is_one_line() -> None:
    with pytest.raises(DeviceLostError, match="cannot open serial port /nonexistent/tty"):
        SerialLink("/nonexistent/tty")


@pytest.mark.socat
def test_wire_link_over_socat_pty_pair(tmp_path: Path) -> None:
    """A socat-made pty pair (as used to bridge a QEMU UART or a remote board): the link works end to end."""
    dev_end, host_end = tmp_path / "dev", tmp_path / "host"
    proc = subprocess.Popen(["socat", f"pty,raw,echo=0,link={dev_end}", f"pty,raw,echo=0,link={host_end}"],
                            stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    try:
        assert wait_for(lambda: dev_end.exists() and host_end.exists(), timeout_s=15)
        dev = FakeDevice(tty_path=str(dev_end), send_hello_at_boot=False).start()
        try:
            with SerialLink(str(host_end)) as link:
                assert link.hello(timeout_s=T)["device_kind"] == bproto.DEVICE_TRIGGER
                link.request(bproto.MSG_SET_BRACKETS, {"period_us": 20_000, "exposures_us": [100, 200]}, T)
                assert dev.brackets == (20_000, [100, 200])
                assert wait_for(lambda: link.counters["heartbeats_in"] >= 1)
        finally:
            dev.close()
    finally:
        stop_process(proc)
