"""The real firmware ELF in QEMU netduinoplus2, driven by the host trigger client (no timing assertions)."""

from __future__ import annotations

import itertools
import subprocess
import sys
from pathlib import Path

import pytest

from bracketry_rig.trigger.client import TriggerClient
from bracketry_rig.trigger.qemu import QemuTrigger
from trigger_scenario import EXPOSURES_US, check_events, collect_events, run_scenario

pytestmark = pytest.mark.qemu
#: QEMU on a loaded 2-core machine answers slowly: generous per-attempt reply timeout
TIMEOUT_S = 1.0


def test_trigger_qemu_scenario(trigger_qemu: QemuTrigger) -> None:
    """HELLO, SET_BRACKETS, START, two bracket cycles, STOP, garbage, invalid tables: on the real ELF."""
    with TriggerClient.open(trigger_qemu.url, timeout_s=TIMEOUT_S) as client:
        client.link.peer_lost_after_s = 10.0
        events = run_scenario(client, client.link._write, quiet_s=1.0)  # raw bytes straight to the port
        # the 64-bit device clock (TIM5 extended) never goes backwards
        device_us = [int(client.ping()["device_time_us"]) for _ in range(5)]
        assert all(b > a for a, b in itertools.pairwise(device_us))
        assert client.counters.missed_events == 0
        assert client.link.counters["crc_errors"] == 0
        # capabilities: QEMU has no RCC/DMA: emulated, interrupt reload path, no PLL, exposure while low
        caps = client.device["capabilities"]
        assert caps & (1 << 2) and not caps & (1 << 0) and not caps & (1 << 1) and caps & (1 << 4)
        assert all(ev.t_start_host_ns is not None for ev in events)
        # a second session restarts trigger_seq at 0
        client.start(7)
        check_events(collect_events(client, 3), session_id=7)
        client.stop()


def test_trigger_qemu_pty_and_cli(trigger_elf: Path, tmp_path: Path) -> None:
    """`bracketry trigger qemu --serial pty` prints where to connect; `hello` and `monitor --start` use it."""
    proc = subprocess.Popen([sys.executable, "-m", "bracketry", "trigger", "qemu", "--elf", str(trigger_elf),
                             "--serial", "pty", "--duration-s", "60"],
                            stdout=subprocess.PIPE, stderr=subprocess.DEVNULL, text=True)
    try:
        assert proc.stdout is not None
        line = proc.stdout.readline()
        assert "connect to /dev/pts/" in line, line
        port = line.rsplit(" ", 1)[-1].strip()
        out = subprocess.run([sys.executable, "-m", "bracketry", "trigger", "hello", "--port", port, "--json",
                              "--timeout-s", str(TIMEOUT_S)], capture_output=True, text=True, timeout=60)
        assert out.returncode == 0, out.stderr
        assert '"device_kind": 1' in out.stdout
        out = subprocess.run([sys.executable, "-m", "bracketry", "trigger", "monitor", "--port", port, "--start",
                              "3", "--count", "7", "--timeout-s", str(TIMEOUT_S)],
                             capture_output=True, text=True, timeout=120)
        assert out.returncode == 0, out.stderr
        lines = [ln for ln in out.stdout.splitlines() if ln.startswith("session=3")]
        assert len(lines) == 7
        assert f"seq=6 bracket=0 exposure_us={EXPOSURES_US[0]}" in lines[-1]
    finally:
        proc.terminate()
        proc.wait(timeout=10)
