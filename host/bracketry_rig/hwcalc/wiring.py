"""``hw/wiring.yaml`` and the firmware pin definitions it must agree with.

- STM32: ``firmware/stm32_trigger/include/pins.h``, lines ``#define PIN_<SIGNAL> PIN('<PORT>', <N>)`` and
  ``#define PIN_<SIGNAL>_AF <n>``.
- ESP32 panel: ``firmware/esp32_panel/pins.py``, module-level integer assignments (read with ``ast``, not imported).
"""

from __future__ import annotations

import ast
import re
from pathlib import Path
from typing import Any

import yaml

from bracketry_base import paths
from bracketry_base.errors import BracketryError

_PIN_RE = re.compile(r"^\s*#define\s+PIN_(\w+)\s+PIN\(\s*'([A-K])'\s*,\s*(\d+)\s*\)", re.M)
_AF_RE = re.compile(r"^\s*#define\s+PIN_(\w+)_AF\s+(\d+)\b", re.M)
#: ESP32 GPIOs that must not carry panel signals: flash (6-11), and 34-39 are input only without pull-ups
ESP32_FORBIDDEN = frozenset(range(6, 12))
ESP32_INPUT_ONLY = frozenset(range(34, 40))
ESP32_PIN_NAMES = ("LCD_RS", "LCD_E", "LCD_D4", "LCD_D5", "LCD_D6", "LCD_D7", "BTN_SENSORS", "BTN_RECORD")


def default_wiring_path() -> Path:
    return paths.hw_dir() / "wiring.yaml"


def stm32_pins_path() -> Path:
    return paths.firmware_dir() / "stm32_trigger" / "include" / "pins.h"


def panel_pins_path() -> Path:
    return paths.firmware_dir() / "esp32_panel" / "pins.py"


def load_wiring(path: Path | None = None) -> dict[str, Any]:
    """The parsed wiring YAML (dict with ``pins``, ``nodes``, ``rails``, ``connections``)."""
    path = path or default_wiring_path()
    try:
        data = yaml.safe_load(path.read_text())
    except OSError as exc:
        raise BracketryError(f"cannot read {path}: {exc.strerror}") from None
    except yaml.YAMLError as exc:
        raise BracketryError(f"{path}: invalid YAML ({exc})") from None
    if not isinstance(data, dict) or not all(k in data for k in ("pins", "nodes", "rails", "connections")):
        raise BracketryError(f"{path}: needs the keys pins, nodes, rails, connections")
    return data


def parse_stm32_pins(text: str) -> dict[str, dict[str, Any]]:
    """``{signal: {"pin": "PA2", "af": 7}}`` from pins.h text (``af`` only where defined)."""
    pins: dict[str, dict[str, Any]] = {}
    for name, port, num in _PIN_RE.findall(text):
        pins[name] = {"pin": f"P{port}{int(num)}"}
    for name, af in _AF_RE.findall(text):
        if name in pins:
            pins[name]["af"] = int(af)
    return pins


def parse_panel_pins(text: str) -> dict[str, int]:
    """``{NAME: int}`` of the module-level integer constants of pins.py."""
    out: dict[str, int] = {}
    for node in ast.parse(text).body:
        if (isinstance(node, ast.Assign) and len(node.targets) == 1 and isinstance(node.targets[0], ast.Name)
                and isinstance(node.value, ast.Constant) and isinstance(node.value.value, int)):
            out[node.targets[0].id] = node.value.value
    return out


def _norm_stm32(spec: Any) -> dict[str, Any]:
    if isinstance(spec, str):
        return {"pin": spec}
    return {k: v for k, v in dict(spec).items() if k in ("pin", "af")}


def check_stm32(wiring: dict[str, Any], header_text: str) -> list[str]:
    """Disagreements between wiring.yaml ``pins.stm32`` and pins.h (empty list = consistent)."""
    yaml_pins = {k: _norm_stm32(v) for k, v in (wiring["pins"].get("stm32") or {}).items()}
    fw = parse_stm32_pins(header_text)
    problems = []
    if not fw:
        problems.append("pins.h: no `#define PIN_<SIGNAL> PIN('<P>', <n>)` line found")
    for name in sorted(set(fw) | set(yaml_pins)):
        if name not in fw:
            problems.append(f"stm32 {name}: in wiring.yaml but not in pins.h")
        elif name not in yaml_pins:
            problems.append(f"stm32 {name}: in pins.h ({fw[name]['pin']}) but not in wiring.yaml")
        elif fw[name] != yaml_pins[name]:
            problems.append(f"stm32 {name}: pins.h {fw[name]} != wiring.yaml {yaml_pins[name]}")
    used = [v["pin"] for v in fw.values()]
    for pin in sorted({p for p in used if used.count(p) > 1}):
        problems.append(f"stm32 pin {pin} assigned twice in pins.h")
    return problems


def check_panel(wiring: dict[str, Any], pins_text: str) -> list[str]:
    """Disagreements between wiring.yaml ``pins.esp32`` and pins.py, plus unusable ESP32 GPIOs."""
    yaml_pins = {k: int(v) for k, v in (wiring["pins"].get("esp32") or {}).items()}
    fw = {k: v for k, v in parse_panel_pins(pins_text).items() if k in ESP32_PIN_NAMES or k in ("UART_TX", "UART_RX")}
    problems = []
    for name in ESP32_PIN_NAMES:
        if name not in fw:
            problems.append(f"esp32 {name}: missing in pins.py")
    for name in sorted(set(fw) | set(yaml_pins)):
        if name not in fw:
            problems.append(f"esp32 {name}: in wiring.yaml but not in pins.py")
        elif name not in yaml_pins:
            problems.append(f"esp32 {name}: in pins.py (GPIO{fw[name]}) but not in wiring.yaml")
        elif fw[name] != yaml_pins[name]:
            problems.append(f"esp32 {name}: pins.py GPIO{fw[name]} != wiring.yaml GPIO{yaml_pins[name]}")
    used = list(fw.values())
    for gpio in sorted({g for g in used if used.count(g) > 1}):
        problems.append(f"esp32 GPIO{gpio} assigned twice in pins.py")
    for name, gpio in fw.items():
        if gpio in ESP32_FORBIDDEN:
            problems.append(f"esp32 {name}: GPIO{gpio} is a flash pin")
        if gpio in ESP32_INPUT_ONLY and (name.startswith("LCD_") or name.startswith("BTN_") or name == "UART_TX"):
            problems.append(f"esp32 {name}: GPIO{gpio} is input-only / has no pull-up")
    return problems


def check_connections(wiring: dict[str, Any]) -> list[str]:
    """Connection endpoints must name known nodes, MCU pin endpoints must be signals of ``pins``, and each camera
    trigger line names its pull resistor."""
    nodes = set(wiring["nodes"])
    problems = []
    mcu_extra = {"GND", "USB", "3V3", "LD4"}
    for conn in wiring["connections"]:
        for end in (conn["from"], conn["to"]):
            node, _, port = str(end).partition(".")
            if node not in nodes:
                problems.append(f"connection {conn['id']}: unknown node {node!r}")
            elif node in ("stm32", "esp32") and port not in wiring["pins"].get(node, {}) and port not in mcu_extra:
                problems.append(f"connection {conn['id']}: {node} has no pin signal {port!r}")
        if str(conn["from"]).startswith("stm32.TRIG_") and not conn.get("pull"):
            problems.append(f"connection {conn['id']}: a trigger line needs its pull resistor (pull:), else it floats "
                            "from reset until the firmware drives it")
    for rail in wiring["rails"]:
        for n in [rail["from"], *rail["to"]]:
            if n not in nodes:
                problems.append(f"rail {rail['name']}: unknown node {n!r}")
    return problems


def check_all(wiring_path: Path | None = None, stm32_header: Path | None = None,
              panel_pins: Path | None = None) -> list[str]:
    """Every disagreement between hw/wiring.yaml and the firmware pin files (empty list = consistent)."""
    wiring = load_wiring(wiring_path)
    header = stm32_header or stm32_pins_path()
    pins_py = panel_pins or panel_pins_path()
    problems = check_connections(wiring)
    for path, check in ((header, check_stm32), (pins_py, check_panel)):
        try:
            problems += check(wiring, path.read_text())
        except OSError as exc:
            problems.append(f"cannot read {path}: {exc.strerror}")
    return problems
