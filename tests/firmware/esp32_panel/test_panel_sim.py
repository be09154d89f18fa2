"""The simulator runs the actual firmware files over a pty: a scripted host checks HELLO, the screen it produces,
button re-sends until ACKed, HOST LOST and recovery (`bracketry panel simulate --link PTY --screen-file FILE`)."""

from __future__ import annotations

import time
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest

from bracketry_rig.wire import bproto
from bracketry_testkit import stop_process
from panel_pty import Pty, read_screen, start_simulator, wait_for

STATE = {"cam_left": 2, "cam_right": 1, "trigger": 2, "imu": 4, "lidar": 0, "gnss": 1, "free_disk_mb": 931000,
         "fps_left_centi": 2190, "fps_right_centi": 2200, "rec_seconds": 754, "message": "SIM TEST"}
EXPECTED = ["L:REC R:IDL TRIG:REC", "IM:CAL LI:OFF GN:IDL", "21.9/22.0 931G 12:34", "SIM TEST            "]


class ScriptedHost:
    """The host end of the pty: sends PANEL_STATE on demand, decodes what the panel sends."""

    def __init__(self, pty: Pty) -> None:
        self.pty = pty
        self.decoder = bproto.Decoder()
        self.rx: list[tuple[int, int, dict[str, Any]]] = []
        self.seq = 0
        self.state = dict(STATE)

    def send(self, msg_type: int, fields: dict[str, Any]) -> int:
        self.seq += 1
        self.pty.write(bproto.encode_message(msg_type, self.seq, fields))
        return self.seq

    def pump(self, duration_s: float, send_state: bool = True) -> None:
        end = time.monotonic() + duration_s
        next_state = 0.0
        while time.monotonic() < end:
            if send_state and time.monotonic() >= next_state:
                self.send(bproto.MSG_PANEL_STATE, self.state)
                next_state = time.monotonic() + 0.25
            for fr in self.decoder.feed(self.pty.read(0.02)):
                fields = bproto.unpack_payload(fr.msg_type, fr.payload)
                self.rx.append((fr.msg_type, fr.seq, fields))

    def of_type(self, msg_type: int) -> list[tuple[int, int, dict[str, Any]]]:
        return [m for m in self.rx if m[0] == msg_type]

    def pump_until(self, pred: Any, timeout_s: float = 20.0, send_state: bool = True) -> bool:
        end = time.monotonic() + timeout_s
        while time.monotonic() < end:
            self.pump(0.1, send_state)
            if pred():
                return True
        return False


@pytest.fixture
def sim(tmp_path: Path) -> Iterator[tuple[Any, ScriptedHost, Path]]:
    pty = Pty()
    screen = tmp_path / "screen.txt"
    proc = start_simulator(pty.path, screen)
    try:
        yield proc, ScriptedHost(pty), screen
    finally:
        stop_process(proc)
        pty.close()


def test_panel_sim_screen_buttons_lost_and_recovery(sim: tuple[Any, ScriptedHost, Path]) -> None:
    proc, host, screen = sim
    # boot: the firmware announces itself with an unsolicited HELLO (panel, fw 1.0.0)
    assert host.pump_until(lambda: host.of_type(bproto.MSG_HELLO), send_state=False), proc.stderr
    hello = host.of_type(bproto.MSG_HELLO)[0][2]
    assert hello["device_kind"] == bproto.DEVICE_PANEL and (hello["fw_major"], hello["fw_minor"]) == (1, 0)
    # PANEL_STATE -> the LCD (driven pin by pin by the firmware's HD44780 driver) shows it
    assert host.pump_until(lambda: read_screen(screen) == EXPECTED), read_screen(screen)
    text = screen.read_text()
    assert text.count("\n") == 4 and all(len(line) == 20 for line in text.splitlines())
    assert host.of_type(bproto.MSG_ACK), "PANEL_STATE frames are ACKed"
    # RECORD short press on stdin -> BUTTON, re-sent with the same seq until ACKed
    proc.stdin.write("record\n")
    proc.stdin.flush()
    assert host.pump_until(lambda: len(host.of_type(bproto.MSG_BUTTON)) >= 3)
    buttons = host.of_type(bproto.MSG_BUTTON)
    assert {(b[1], b[2]["button"], b[2]["action"], b[2]["event_seq"]) for b in buttons} == \
        {(buttons[0][1], 2, 1, buttons[0][2]["event_seq"])}
    host.send(bproto.MSG_ACK, {"acked_seq": buttons[0][1]})
    host.pump(0.8)
    n = len(host.of_type(bproto.MSG_BUTTON))
    host.pump(1.0)
    assert len(host.of_type(bproto.MSG_BUTTON)) == n, "no re-send after the ACK"
    # SENSORS long press -> BUTTON(1, long)
    proc.stdin.write("sensors long\n")
    proc.stdin.flush()
    assert host.pump_until(lambda: any(b[2]["button"] == 1 and b[2]["action"] == 2
                                       for b in host.of_type(bproto.MSG_BUTTON)))
    long_press = next(b for b in host.of_type(bproto.MSG_BUTTON) if b[2]["button"] == 1)
    host.send(bproto.MSG_ACK, {"acked_seq": long_press[1]})
    # host silent -> HOST LOST (heartbeat state 1), then recovery when frames return
    assert host.pump_until(lambda: "HOST LOST" in "".join(read_screen(screen) or []), send_state=False)
    assert host.pump_until(lambda: any(h[2]["state"] == 1 for h in host.of_type(bproto.MSG_HEARTBEAT)),
                           send_state=False)
    host.state["message"] = "BACK AGAIN"
    assert host.pump_until(lambda: (read_screen(screen) or [""])[-1] == "BACK AGAIN          ")
    # quit on stdin ends the simulator cleanly
    proc.stdin.write("quit\n")
    proc.stdin.flush()
    assert proc.wait(timeout=20) == 0


def test_panel_sim_rejects_missing_link(tmp_path: Path) -> None:
    proc = start_simulator(str(tmp_path / "no-such-tty"), tmp_path / "s.txt")
    try:
        _out, err = proc.communicate(timeout=60)
    finally:
        stop_process(proc)
    assert proc.returncode != 0 and err.strip().startswith("error:") and "Traceback" not in err
    assert wait_for(lambda: True)


def test_panel_sim_prints_screen_to_terminal(tmp_path: Path) -> None:
    """Without --quiet the simulator prints the 4x20 buffer in a frame on every change (here: boot, HOST LOST)."""
    import subprocess
    import sys

    pty = Pty()
    try:
        proc = subprocess.run([sys.executable, "-m", "bracketry", "panel", "simulate", "--link", pty.path,
                               "--duration", "3"], capture_output=True, text=True, timeout=60, stdin=subprocess.DEVNULL)
    finally:
        pty.close()
    assert proc.returncode == 0, proc.stderr
    assert "+--------------------+" in proc.stdout and "|bracketry panel     |" in proc.stdout
    assert "HOST LOST" in proc.stdout
    rows = [line for line in proc.stdout.splitlines() if line.startswith("|")]
    assert rows and all(len(line) == 22 for line in rows)
