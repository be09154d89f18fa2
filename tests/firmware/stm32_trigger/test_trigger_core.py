"""The portable trigger core compiled for this machine (gcc, ASan/UBSan) with a fake HAL, and the firmware build."""

from __future__ import annotations

import shutil
import subprocess
from pathlib import Path

import pytest

from bracketry_base import paths
from bracketry_testkit import missing_component

FW_DIR = paths.firmware_dir() / "stm32_trigger"


def _make(args: list[str], timeout_s: float = 300.0) -> subprocess.CompletedProcess:
    return subprocess.run(["make", "-C", str(FW_DIR), *args], capture_output=True, text=True, timeout=timeout_s,
                          check=False)


def test_trigger_core_unit_tests_on_host(tmp_path: Path) -> None:
    """Validation bounds, scheduler cycling, time extension across overflow, every NACK path, STOP/START order."""
    if shutil.which("gcc") is None or shutil.which("make") is None:
        missing_component("host gcc/make not found")
    proc = _make([f"BUILD_DIR={tmp_path}", "host-test"])
    assert proc.returncode == 0, proc.stdout[-2000:] + proc.stderr[-2000:]
    assert "all checks passed" in proc.stdout


@pytest.mark.qemu
@pytest.mark.parametrize("polarity", ["low", "high"])
def test_trigger_firmware_builds_warning_free(tmp_path: Path, polarity: str) -> None:
    """`make` builds the ELF, .bin and .map with -Wall -Wextra -Werror and prints the size."""
    proc = _make([f"BUILD_DIR={tmp_path}", f"POLARITY={polarity}"])
    assert proc.returncode == 0, proc.stdout[-2000:] + proc.stderr[-2000:]
    for name in ("stm32_trigger.elf", "stm32_trigger.bin", "stm32_trigger.map"):
        assert (tmp_path / name).stat().st_size > 0
    assert "-Werror" in proc.stdout and "text" in proc.stdout and "stm32_trigger.elf" in proc.stdout
    # the binary starts with the vector table: initial SP at the end of SRAM, reset vector in flash (thumb bit)
    head = (tmp_path / "stm32_trigger.bin").read_bytes()[:8]
    sp, reset = int.from_bytes(head[:4], "little"), int.from_bytes(head[4:], "little")
    assert sp == 0x20020000
    assert 0x08000000 <= reset < 0x08100000 and reset & 1


def test_trigger_pins_header_declares_required_pins() -> None:
    """include/pins.h has the agreed format and the pins of the contract."""
    text = (FW_DIR / "include" / "pins.h").read_text()
    for signal, pin in (("USART2_TX", "PIN('A', 2)"), ("USART2_RX", "PIN('A', 3)")):
        assert f"#define PIN_{signal} {pin}" in text
    for signal in ("TRIG_LEFT", "TRIG_RIGHT", "STATUS_LED"):
        assert f"#define PIN_{signal} PIN(" in text
