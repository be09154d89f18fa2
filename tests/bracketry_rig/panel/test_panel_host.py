"""Host-side pieces of the panel: PANEL_STATE fields from daemon state, the pin-level LCD emulator driven by the
firmware's own HD44780 driver, the deploy command, the CLI."""

from __future__ import annotations

import importlib
import sys
from pathlib import Path

import pytest

from bracketry.cli import main
from bracketry_rig.daemon.state import RigState, SensorState
from bracketry_rig.panel import deploy
from bracketry_rig.panel.client import panel_fields, snapshot_fields
from bracketry_rig.panel.lcd_emulator import HD44780Emulator
from bracketry_rig.panel.sim import firmware_dir, format_box, write_screen_file
from bracketry_rig.wire import bproto


def test_panel_fields_from_daemon_snapshot() -> None:
    rig = RigState()
    rig.set_state("cam_left", SensorState.REC)
    rig.set_state("lidar", SensorState.ERR, "no packets")
    rig.set_state("imu", SensorState.CAL)
    rig.set_fps("left", 21.94)
    rig.set_fps("right", 655.4)
    rig.set_free_disk_mb(931_000)
    rig.set_message("disk ok é\tlong message beyond twenty")
    fields = snapshot_fields(rig.snapshot())
    assert fields["cam_left"] == 2 and fields["lidar"] == 3 and fields["imu"] == 4 and fields["gnss"] == 0
    assert fields["fps_left_centi"] == 2194 and fields["fps_right_centi"] == 65535
    assert len(fields["message"]) <= 20 and fields["message"].isascii()
    bproto.pack_payload(bproto.MSG_PANEL_STATE, fields)  # encodable as-is
    clamped = panel_fields({"cam_left": 9}, -1.0, 1e9, -5, 2**40, "x")
    assert clamped["cam_left"] == 4 and clamped["fps_left_centi"] == 0 and clamped["fps_right_centi"] == 65535
    assert clamped["free_disk_mb"] == 0 and clamped["rec_seconds"] == 2**32 - 1


class _Pin:
    def __init__(self, lcd: HD44780Emulator, name: str) -> None:
        self.lcd, self.name = lcd, name

    def value(self, v: int) -> None:
        self.lcd.set_pin(self.name, v)


def test_panel_firmware_lcd_driver_on_emulator(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.syspath_prepend(str(firmware_dir()))
    for name in ("hd44780", "panel_clock"):
        sys.modules.pop(name, None)
    hd44780 = importlib.import_module("hd44780")
    try:
        lcd = HD44780Emulator()
        drv = hd44780.HD44780(*[_Pin(lcd, n) for n in ("RS", "E", "D4", "D5", "D6", "D7")])
        assert lcd.four_bit and lcd.display_on and lcd.lines() == [" " * 20] * 4
        screen = ["L:REC R:IDL TRIG:REC", "IM:CAL LI:OFF GN:ERR", "21.9/22.0 931G 12:34", "the last line  ~~~~"]
        drv.show(screen)
        assert lcd.lines() == [(s + " ")[:20] for s in screen]
        writes = lcd.writes
        drv.show([screen[0], screen[1], "21.9/22.0 931G 12:35", screen[3]])
        assert lcd.writes - writes == 1  # only the changed character is rewritten
        assert lcd.lines()[2] == "21.9/22.0 931G 12:35"
    finally:
        for name in ("hd44780", "panel_clock"):
            sys.modules.pop(name, None)


def test_panel_screen_file_and_box(tmp_path: Path) -> None:
    out = tmp_path / "screen.txt"
    write_screen_file(out, ["short", "x" * 30, "", "end"])
    lines = out.read_text().split("\n")
    assert lines[-1] == "" and [len(s) for s in lines[:-1]] == [20, 20, 20, 20]
    assert format_box(["a" * 20] * 4).count("\n") == 5


def test_panel_deploy_dry_run(capsys: pytest.CaptureFixture[str]) -> None:
    files = deploy.firmware_files()
    names = [f.name for f in files]
    assert names[-1] == "main.py" and "bproto.py" in names and "pins.py" in names and "hd44780.py" in names
    assert all(f.is_file() for f in files)
    assert main(["panel", "deploy", "--port", "/dev/ttyUSB9", "--dry-run"]) == 0
    out = capsys.readouterr().out
    assert "mpremote connect /dev/ttyUSB9 fs cp" in out and out.strip().endswith(": + reset")


def test_panel_deploy_bad_port(capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["panel", "deploy", "--port", "nonexistent-port"]) == 2
    err = capsys.readouterr().err
    assert err.startswith("error:") and "Traceback" not in err
