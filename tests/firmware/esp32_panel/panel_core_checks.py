"""Checks of the panel firmware's core modules, written to run unchanged under MicroPython and CPython.

Run as a script with the firmware folder and the folder of ``bproto.py`` on the path; it prints ``PASS <name>`` per
check and raises AssertionError on the first failure. tests/firmware/esp32_panel/test_panel_core.py runs it under
CPython and under the real MicroPython WebAssembly runtime (Node).
"""

import bproto
import panel_app
import panel_buttons
import panel_layout

SENSORS = ("cam_left", "cam_right", "trigger", "imu", "lidar", "gnss")


def _state(states=(1, 1, 1, 1, 1, 1), disk_mb=931000, fps_l=2190, fps_r=2200, rec_s=0, message=b"READY"):
    st = {"free_disk_mb": disk_mb, "fps_left_centi": fps_l, "fps_right_centi": fps_r, "rec_seconds": rec_s,
          "message": (message + b" " * 20)[:20]}
    for i in range(6):
        st[SENSORS[i]] = states[i]
    return st


def _check_screen(lines):
    assert len(lines) == 4, lines
    for line in lines:
        assert len(line) == 20, (line, len(line))
        for ch in line:
            assert 32 <= ord(ch) < 127, line


def check_every_state_combination_fits():
    n = 0
    base = _state(rec_s=4000, disk_mb=4294967295, fps_l=65535, fps_r=0, message=b"\x01\xffxyz" * 6)
    for code in range(5 ** 6):
        c = code
        for name in SENSORS:
            base[name] = c % 5
            c //= 5
        for blink_on in (True, False):
            lines = panel_layout.render_status(base, blink_on)
            _check_screen(lines)
            n += 1
            # every state is visible (ERR only in the 'on' blink phase), in its column
            for i in range(6):
                s = base[SENSORS[i]]
                text = panel_layout.STATE_TEXT[s] if (s != 3 or blink_on) else "   "
                row, col = ((0, 2), (0, 8), (0, 17), (1, 3), (1, 10), (1, 17))[i]
                assert lines[row][col:col + 3] == text, (lines, i, s)
    assert n == 2 * 5 ** 6


def check_number_formats():
    f = panel_layout.fps_text
    assert f(2190) == "21.9" and f(2195) == "22.0" and f(0) == " 0.0" and f(550) == " 5.5"
    assert f(9999) == "100." or f(9999) == " 100", f(9999)
    assert f(65535) == " 655"
    for v in range(0, 65536, 7):
        assert len(f(v)) == 4
    d = panel_layout.disk_text
    assert d(0) == "0.0G" and d(9500) == "9.5G" and d(931000) == "931G" and d(12000) == " 12G"
    assert d(1234567) == "1.2T" and d(99000000) == " 99T" and d(4294967295) == "999T"
    for mb in (0, 49, 50, 9949, 9950, 999499, 999500, 9949999, 9950000, 10 ** 9, 4294967295):
        assert len(d(mb)) == 4, (mb, d(mb))
    r = panel_layout.rec_text
    assert r(0, False) == "--:--" and r(0, True) == "00:00" and r(754, True) == "12:34"
    assert r(5999, True) == "99:59" and r(6000, True) == "1h40m" and r(35999, True) == "9h59m"
    assert r(36000, True) == "  10h" and r(4294967295, True) == "9999h"
    for s in (0, 1, 59, 3599, 5999, 6000, 35999, 36000, 10 ** 7, 4294967295):
        assert len(r(s, True)) == 5
    lines = panel_layout.render_status(_state(states=(2, 2, 2, 4, 2, 3), rec_s=754, message=b"REC 0042 OK"), True)
    assert lines == ["L:REC R:REC TRIG:REC", "IM:CAL LI:REC GN:ERR", "21.9/22.0 931G 12:34", "REC 0042 OK         "]
    msg = panel_layout.render_status(_state(message=b"a\tb\x00\x00"), True)[3]
    assert msg == "a?b                 ", msg


def check_err_blinks():
    st = _state(states=(3, 1, 1, 1, 1, 1))
    on = panel_layout.render_status(st, panel_layout.blink_phase(100))
    off = panel_layout.render_status(st, panel_layout.blink_phase(600))
    assert on[0].startswith("L:ERR") and off[0].startswith("L:   "), (on, off)
    assert on[1:] == off[1:]


def check_boot_and_lost_screens():
    _check_screen(panel_layout.render_boot((1, 2, 3), b"\x24\x6f\x28\xa1\xb2\xc3"))
    assert panel_layout.render_boot((1, 2, 3), b"\x24\x6f\x28\xa1\xb2\xc3")[1].startswith("fw 1.2.3")
    for ms in (0, 1500, 10 ** 9):
        for blink in (True, False):
            lines = panel_layout.render_host_lost(ms, (1, 0, 0), blink)
            _check_screen(lines)
            assert "HOST LOST" in lines[0]


def _events(button, levels, step_ms=5):
    """Feed (pressed, duration_ms) segments; return [(t_ms, action)]."""
    out = []
    t = 0
    for pressed, dur in levels:
        end = t + dur
        while t < end:
            a = button.update(pressed, t)
            if a is not None:
                out.append((t, a))
            t += step_ms
    return out


def check_debounce_and_long_press():
    B = panel_buttons
    # contact bounce of 10 ms pulses: no event
    assert _events(B.Button(1), [(False, 100), (True, 10), (False, 10), (True, 10), (False, 200)]) == []
    # short press with bounce on both edges: exactly one SHORT, on release (after the debounce time)
    ev = _events(B.Button(1), [(False, 50), (True, 5), (False, 5), (True, 200), (False, 5), (True, 5), (False, 200)])
    assert [a for _, a in ev] == [B.ACTION_SHORT], ev
    # long press: one LONG while held (at >= 1000 ms after the debounced press), nothing on release
    ev = _events(B.Button(2), [(False, 50), (True, 2500), (False, 300)])
    assert [a for _, a in ev] == [B.ACTION_LONG], ev
    assert 1000 + 50 <= ev[0][0] <= 1000 + 50 + B.DEBOUNCE_MS + 10, ev
    # two presses -> two events
    ev = _events(B.Button(1), [(False, 50), (True, 100), (False, 100), (True, 100), (False, 100)])
    assert [a for _, a in ev] == [B.ACTION_SHORT, B.ACTION_SHORT], ev


class _Host:
    """A scripted host: collects what the panel sends, encodes frames to it."""

    def __init__(self):
        self.decoder = bproto.Decoder()
        self.rx = []  # (msg_type, seq, fields)
        self.seq = 100

    def write(self, data):
        for fr in self.decoder.feed(data):
            if fr.msg_type == bproto.MSG_HELLO and len(fr.payload) == 0:
                fields = {}
            else:
                fields = bproto.unpack_payload(fr.msg_type, fr.payload)
            self.rx.append((fr.msg_type, fr.seq, fields))

    def frame(self, msg_type, fields):
        self.seq += 1
        return bproto.encode_message(msg_type, self.seq, fields)

    def of_type(self, msg_type):
        return [m for m in self.rx if m[0] == msg_type]


def _panel_state_fields(states=(2, 2, 2, 4, 2, 3), msg=b"HELLO HOST"):
    st = _state(states=states, rec_s=61, message=msg)
    return st


def check_link_boot_hello_heartbeat_and_lost():
    host = _Host()
    app = panel_app.PanelApp(host.write, b"\x24\x6f\x28\xa1\xb2\xc3", 0)
    hello = host.of_type(bproto.MSG_HELLO)
    assert len(hello) == 1 and hello[0][2]["device_kind"] == 2, host.rx
    assert hello[0][2]["fw_major"] == panel_app.FW_VERSION[0]
    assert app.screen_name == "boot"
    t = 0
    while t < 1000:
        app.step(t)
        t += 10
    assert app.screen_name == "boot" and len(host.of_type(bproto.MSG_HEARTBEAT)) == 1
    assert host.of_type(bproto.MSG_HEARTBEAT)[0][2] == {"uptime_ms": 500, "state": 0}
    # a HELLO request is answered
    app.step(t, host.frame(bproto.MSG_HELLO, {}))
    assert len(host.of_type(bproto.MSG_HELLO)) == 2
    # PANEL_STATE -> status screen, ACKed with its seq
    app.step(t, host.frame(bproto.MSG_PANEL_STATE, _panel_state_fields()))
    assert app.screen_name == "status", app.screen
    assert app.screen[0] == "L:REC R:REC TRIG:REC" and app.screen[3] == "HELLO HOST          ", app.screen
    assert host.of_type(bproto.MSG_ACK)[-1][2]["acked_seq"] == host.seq
    last_rx = t
    # silent host: still status at 1.49 s, HOST LOST at 1.5 s
    while t < last_rx + 1490:
        t += 10
        app.step(t)
        assert app.screen_name == "status", (t, app.screen)
    t = last_rx + 1500
    app.step(t)
    assert app.screen_name == "host_lost", app.screen
    assert "HOST LOST" in app.screen[0] or "HOST LOST" in app.render(t + 500)[0]
    hb = host.of_type(bproto.MSG_HEARTBEAT)
    t += 600
    app.step(t)
    assert host.of_type(bproto.MSG_HEARTBEAT)[-1][2]["state"] == 1 and len(host.of_type(bproto.MSG_HEARTBEAT)) > len(hb)
    # heartbeat only -> host back, but no state yet: boot screen (never shows stale state)
    app.step(t, host.frame(bproto.MSG_HEARTBEAT, {"uptime_ms": 5, "state": 0}))
    assert app.screen_name == "boot", app.screen
    app.step(t + 10, host.frame(bproto.MSG_PANEL_STATE, _panel_state_fields(msg=b"BACK")))
    assert app.screen_name == "status" and app.screen[3].startswith("BACK"), app.screen


def check_link_button_resend_until_acked():
    host = _Host()
    app = panel_app.PanelApp(host.write, b"\x01\x02\x03\x04\x05\x06", 0)
    t = 0
    app.step(t, host.frame(bproto.MSG_PANEL_STATE, _panel_state_fields()))
    # press RECORD for 150 ms
    for _ in range(15):
        t += 10
        app.step(t, b"", False, True)
    for _ in range(5):
        t += 10
        app.step(t, b"", False, False)
    buttons = host.of_type(bproto.MSG_BUTTON)
    assert len(buttons) == 1 and buttons[0][2]["button"] == 2 and buttons[0][2]["action"] == 1, host.rx
    # no ACK: re-sent with the same frame seq and event_seq, while the host keeps sending state
    for _ in range(60):
        t += 10
        rx = host.frame(bproto.MSG_PANEL_STATE, _panel_state_fields()) if t % 200 == 0 else b""
        app.step(t, rx)
    buttons = host.of_type(bproto.MSG_BUTTON)
    assert len(buttons) >= 3, buttons
    assert len(set([b[1] for b in buttons])) == 1 and len(set([b[2]["event_seq"] for b in buttons])) == 1
    # ACK with the wrong seq: still pending; with the right one: done, no more re-sends
    app.step(t, host.frame(bproto.MSG_ACK, {"acked_seq": (buttons[0][1] + 1) & 0xFFFF}))
    assert app.link.pending_buttons == 1
    app.step(t, host.frame(bproto.MSG_ACK, {"acked_seq": buttons[0][1]}))
    assert app.link.pending_buttons == 0
    n = len(host.of_type(bproto.MSG_BUTTON))
    for _ in range(50):
        t += 10
        app.step(t, host.frame(bproto.MSG_PANEL_STATE, _panel_state_fields()) if t % 200 == 0 else b"")
    assert len(host.of_type(bproto.MSG_BUTTON)) == n
    # a second press gets the next event_seq
    for pressed in [True] * 10 + [False] * 10:
        t += 10
        app.step(t, b"", False, pressed)
    assert host.of_type(bproto.MSG_BUTTON)[-1][2]["event_seq"] == buttons[0][2]["event_seq"] + 1


def check_link_buttons_dropped_while_host_lost():
    host = _Host()
    app = panel_app.PanelApp(host.write, b"\x01\x02\x03\x04\x05\x06", 0)
    t = 2000
    app.step(t)
    assert app.screen_name == "host_lost"
    for pressed in [True] * 10 + [False] * 10:
        t += 10
        app.step(t, b"", pressed, False)
    assert host.of_type(bproto.MSG_BUTTON) == [] and app.link.counters["buttons_dropped"] == 1


def check_link_ping_nack_and_garbage():
    host = _Host()
    app = panel_app.PanelApp(host.write, b"\x01\x02\x03\x04\x05\x06", 0, device_us=lambda: 123456789012)
    app.step(10, host.frame(bproto.MSG_PING, {"host_time_ns": 987654321}))
    pong = host.of_type(bproto.MSG_PONG)
    assert pong[-1][2]["host_time_ns"] == 987654321 and pong[-1][2]["device_time_us"] == 123456789012, pong
    # unknown type -> NACK UNKNOWN_TYPE; truncated PANEL_STATE -> NACK BAD_LENGTH; state 7 -> NACK BAD_VALUE
    app.step(20, bproto.encode_frame(0x7E, 7, b""))
    assert host.of_type(bproto.MSG_NACK)[-1][2] == {"acked_seq": 7, "code": bproto.NACK_UNKNOWN_TYPE}
    app.step(30, bproto.encode_frame(bproto.MSG_PANEL_STATE, 8, b"\x01\x02"))
    assert host.of_type(bproto.MSG_NACK)[-1][2] == {"acked_seq": 8, "code": bproto.NACK_BAD_LENGTH}
    bad = _panel_state_fields(states=(7, 1, 1, 1, 1, 1))
    app.step(40, bproto.encode_frame(bproto.MSG_PANEL_STATE, 9, bproto.pack_payload(bproto.MSG_PANEL_STATE, bad)))
    assert host.of_type(bproto.MSG_NACK)[-1][2] == {"acked_seq": 9, "code": bproto.NACK_BAD_VALUE}
    # right length, but a message that is not printable ASCII -> NACK BAD_VALUE too
    good = bproto.pack_payload(bproto.MSG_PANEL_STATE, _panel_state_fields(msg=b"OK"))
    app.step(45, bproto.encode_frame(bproto.MSG_PANEL_STATE, 10, good[:-20] + b"\xff" * 20))
    assert host.of_type(bproto.MSG_NACK)[-1][2] == {"acked_seq": 10, "code": bproto.NACK_BAD_VALUE}
    assert app.link.state is None
    # garbage, then a frame split in 1-byte pieces: recovered
    app.step(50, b"\x11\x22\x00\x05garbage\x00")
    frame = host.frame(bproto.MSG_PANEL_STATE, _panel_state_fields(msg=b"SPLIT"))
    for i in range(len(frame)):
        app.step(60 + i, frame[i:i + 1])
    assert app.screen_name == "status" and app.screen[3].startswith("SPLIT"), app.screen


CHECKS = (check_every_state_combination_fits, check_number_formats, check_err_blinks, check_boot_and_lost_screens,
          check_debounce_and_long_press, check_link_boot_hello_heartbeat_and_lost,
          check_link_button_resend_until_acked, check_link_buttons_dropped_while_host_lost,
          check_link_ping_nack_and_garbage)


def run_all():
    for check in CHECKS:
        check()
        print("PASS " + check.__name__)


run_all()
