"""hw/wiring.yaml agrees with the firmware pin files (STM32 pins.h, panel pins.py); the diagram is up to date."""

from __future__ import annotations

from pathlib import Path

import pytest

from bracketry.cli import main
from bracketry_base import paths
from bracketry_rig.hwcalc import diagram, wiring


def test_hw_wiring_matches_firmware_pins() -> None:
    assert wiring.stm32_pins_path().is_file(), "firmware/stm32_trigger/include/pins.h is missing"
    assert wiring.panel_pins_path().is_file()
    assert wiring.check_all() == []


def test_hw_wiring_required_signals_present() -> None:
    w = wiring.load_wiring()
    stm = wiring.parse_stm32_pins(wiring.stm32_pins_path().read_text())
    assert stm["USART2_TX"] == {"pin": "PA2", "af": 7} and stm["USART2_RX"]["pin"] == "PA3"
    for sig in ("TRIG_LEFT", "TRIG_RIGHT", "STATUS_LED"):
        assert sig in stm and sig in w["pins"]["stm32"]
    panel = wiring.parse_panel_pins(wiring.panel_pins_path().read_text())
    for name in wiring.ESP32_PIN_NAMES:
        assert name in panel and name in w["pins"]["esp32"]
    # every trigger line is documented with level, polarity and protection
    trig = [c for c in w["connections"] if str(c["from"]).startswith("stm32.TRIG_")]
    assert {c["to"] for c in trig} == {"cam_left.Line3", "cam_right.Line3"}
    for c in trig:
        assert c["level"] and "FallingEdge" in c["polarity"] and c["protection"]
        assert "pull-up to 3.3 V" in c["pull"]  # the lines float from reset until the firmware drives them
    assert wiring.check_connections(w) == []
    w["connections"] = [{k: v for k, v in c.items() if k != "pull"} for c in w["connections"]]
    problems = wiring.check_connections(w)  # exactly one problem per trigger line, and nothing else
    assert sorted(problems) == sorted(f"connection {c['id']}: a trigger line needs its pull resistor (pull:), else it "
                                      "floats from reset until the firmware drives it" for c in trig)
    bom = (paths.hw_dir() / "bom.csv").read_text()
    assert "trigger_pullup,harness,10 kOhm" in bom


def test_hw_wiring_detects_disagreement(tmp_path: Path) -> None:
    header = wiring.stm32_pins_path().read_text().replace("PIN('B', 0)", "PIN('B', 4)")
    h = tmp_path / "pins.h"
    h.write_text(header + "\n#define PIN_EXTRA PIN('C', 7)\n")
    pins_py = wiring.panel_pins_path().read_text().replace("LCD_E = 18", "LCD_E = 7").replace("BTN_RECORD = 27",
                                                                                                "BTN_RECORD = 26")
    p = tmp_path / "pins.py"
    p.write_text(pins_py)
    problems = wiring.check_all(stm32_header=h, panel_pins=p)
    text = "\n".join(problems)
    assert "stm32 TRIG_LEFT" in text and "stm32 EXTRA" in text
    assert "esp32 LCD_E" in text and "flash pin" in text and "GPIO26 assigned twice" in text
    assert main(["hw", "check"]) == 0


def test_hw_diagram_is_generated_and_current(tmp_path: Path) -> None:
    w = wiring.load_wiring()
    svg = diagram.to_svg(w)
    assert svg.startswith("<svg") and svg.rstrip().endswith("</svg>")
    for node in w["nodes"].values():
        assert node[0].replace("&", "&amp;").replace(">", "&gt;") in svg
    committed = paths.hw_dir() / "wiring.svg"
    assert committed.read_text() == svg, "hw/wiring.svg is stale: run `bracketry hw diagram --out hw/wiring.svg`"
    out = tmp_path / "w.dot"
    assert main(["hw", "diagram", "--out", str(out)]) == 0
    dot = out.read_text()
    assert dot.startswith("graph bracketry") and "stm32 -- cam_left" in dot


@pytest.mark.parametrize(("kind", "must_have"), [
    ("ethernet", {("cam_left", "switch"), ("cam_right", "switch"), ("switch", "computer")}),
    ("power", {("battery", "fuse"), ("dcdc_12v", "cam_left"), ("dcdc_12v", "cam_right")}),
    ("usb", {("usb_uart", "computer"), ("esp32", "computer")}),
    ("signal", {("stm32", "cam_left"), ("stm32", "cam_right")}),
])
def test_hw_diagram_has_edges_of_each_kind(kind: str, must_have: set[tuple[str, str]]) -> None:
    w = wiring.load_wiring()
    got = {(a, b): n for a, b, k, n in diagram.edges(w) if k == kind}
    assert must_have <= set(got)
    # the wire counts add up to the rails (power) plus the connections of that kind between two different nodes
    expected = sum(len(r["to"]) for r in w["rails"]) if kind == "power" else 0
    expected += sum(1 for c in w["connections"] if c.get("kind", "signal") == kind
                    and str(c["from"]).split(".")[0] != str(c["to"]).split(".")[0])
    assert sum(got.values()) == expected
