"""USB device listing and udev rules, on recorded descriptor lists (no USB device exists in CI)."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from bracketry.cli import main
from bracketry_base.errors import BracketryError
from bracketry_rig.daemon import devices as dev

RECORDED = Path(__file__).with_name("usb_recorded.json")


def test_recorded_list_keeps_only_rig_bridges_mapped_to_ports() -> None:
    found = dev.load_recorded(RECORDED)
    assert [(d.role, d.usb_id, d.port) for d in found] == [
        ("panel", "10c4:ea60", "/dev/ttyUSB0"),
        ("trigger", "0483:374b", "/dev/ttyACM0"),
    ]
    assert found[1].serial == "066DFF535155878281122539"


def test_udev_rules_match_vendor_product_and_serial() -> None:
    text = dev.udev_rules(dev.load_recorded(RECORDED))
    rules = [line for line in text.splitlines() if line.startswith("SUBSYSTEM")]
    assert len(rules) == 2
    trig = next(r for r in rules if "bracketry-trigger" in r)
    assert 'ATTRS{idVendor}=="0483"' in trig and 'ATTRS{idProduct}=="374b"' in trig
    assert 'ATTRS{serial}=="066DFF535155878281122539"' in trig
    assert 'SYMLINK+="bracketry-panel"' in next(r for r in rules if "10c4" in r)


def test_role_override_and_conflict() -> None:
    found = dev.load_recorded(RECORDED)
    with pytest.raises(BracketryError, match="two devices for the trigger role"):
        dev.udev_rules(found, {"0001": "trigger"})
    text = dev.udev_rules(found, {"0001": "trigger", "066DFF535155878281122539": "panel"})
    assert 'ATTRS{serial}=="0001", SYMLINK+="bracketry-trigger"' in text


def test_cli_writes_rules_and_json(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    rules = tmp_path / "99-bracketry.rules"
    assert main(["devices", "--from-json", str(RECORDED), "--json", "--udev-rules", str(rules)]) == 0
    listed = json.loads(capsys.readouterr().out)
    assert {d["role"] for d in listed} == {"trigger", "panel"}
    assert "bracketry-trigger" in rules.read_text()


def test_cli_rejects_bad_inputs(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    bad = tmp_path / "bad.json"
    bad.write_text("{not json")
    assert main(["devices", "--from-json", str(bad)]) == 2
    assert "not a recorded descriptor list" in capsys.readouterr().err
    assert main(["devices", "--from-json", str(RECORDED), "--role", "0001=camera"]) == 2
