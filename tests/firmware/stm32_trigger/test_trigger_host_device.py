"""The firmware's portable C core (trigger_core.c + bproto.c) as a Linux process on a pty, driven by the host client
through the same scenario as QEMU and the simulator (real-time pulses, no emulator)."""

from __future__ import annotations

import os
import shutil
import subprocess
from collections.abc import Iterator
from pathlib import Path

import pytest

from bracketry_base import paths
from bracketry_rig.trigger.client import TriggerClient
from bracketry_rig.trigger.simulator import open_pty
from bracketry_testkit import missing_component, stop_process
from trigger_scenario import run_scenario


@pytest.fixture(scope="module")
def host_device_binary(tmp_path_factory: pytest.TempPathFactory) -> Path:
    if shutil.which("gcc") is None or shutil.which("make") is None:
        missing_component("host gcc/make not found")
    out = tmp_path_factory.mktemp("stm32_host")
    proc = subprocess.run(["make", "-C", str(paths.firmware_dir() / "stm32_trigger"), f"BUILD_DIR={out}",
                           "host-device"], capture_output=True, text=True, timeout=300, check=False)
    assert proc.returncode == 0, proc.stdout[-2000:] + proc.stderr[-2000:]
    return out / "host_device"


@pytest.fixture
def host_device(host_device_binary: Path) -> Iterator[str]:
    master, slave, path = open_pty()
    proc = subprocess.Popen([str(host_device_binary), str(master)], pass_fds=(master,))
    try:
        yield path
    finally:
        stop_process(proc)
        os.close(master)
        os.close(slave)


def test_trigger_host_device_scenario(host_device: str) -> None:
    with TriggerClient.open(host_device, timeout_s=0.5) as client:
        run_scenario(client, client.link._write, quiet_s=0.5)
        assert client.counters.missed_events == 0
        assert client.device["uid"] == b"HOSTDEVICE01"
