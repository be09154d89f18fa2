"""The behavioural simulator with the real host client over a pty: the acceptance scenario (trigger_scenario.py),
drift and jitter through the clock model, dropped events, reboots, and the `bracketry trigger simulate` command."""

from __future__ import annotations

import json
import subprocess
import sys
import time
from collections.abc import Iterator
from pathlib import Path

import pytest

from bracketry_rig.trigger.client import TriggerClient
from bracketry_rig.trigger.simulator import SimConfig, TriggerSimulator, simulate_on_pty
from bracketry_rig.wire import bproto
from trigger_scenario import EXPOSURES_US, PERIOD_US, check_events, collect_events, run_scenario

TIMEOUT_S = 0.5


def _wait_until(cond, timeout_s: float = 10.0) -> bool:  # type: ignore[no-untyped-def]
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        if cond():
            return True
        time.sleep(0.02)
    return False


@pytest.fixture
def sim_factory() -> Iterator:
    sims: list[TriggerSimulator] = []
    clients: list[TriggerClient] = []

    def make(config: SimConfig | None = None, clock_sync_period_s: float = 0.0) -> tuple[TriggerSimulator,
                                                                                          TriggerClient]:
        sim, path = simulate_on_pty(None, config)
        sims.append(sim)
        client = TriggerClient.open(path, timeout_s=TIMEOUT_S, clock_sync_period_s=clock_sync_period_s)
        clients.append(client)
        return sim, client

    yield make
    for c in clients:
        c.close()
    for s in sims:
        s.close()


def test_trigger_simulator_scenario(sim_factory) -> None:  # type: ignore[no-untyped-def]
    """The same scenario as on the real ELF in QEMU."""
    sim, client = sim_factory()
    run_scenario(client, client.link._write, quiet_s=0.5)  # raw bytes straight to the port
    assert client.counters.missed_events == 0
    assert sim.counters["nacks"] >= 7


def test_trigger_simulator_drift_and_jitter_clock_model(sim_factory) -> None:  # type: ignore[no-untyped-def]
    """With 300 ppm drift, pulse jitter and jittery replies, host times of pulses follow the simulator's truth."""
    sim, client = sim_factory(SimConfig(drift_ppm=300.0, offset_us=5_000_000_000, pulse_jitter_us=20.0,
                                        reply_jitter_us=150.0, seed=3))
    client.hello()
    for _ in range(30):
        client.ping()
        time.sleep(0.03)
    client.configure(PERIOD_US, EXPOSURES_US)
    client.start(1)
    events = collect_events(client, 8)
    client.stop()
    check_events(events, session_id=1)
    # the simulator's device clock runs on time.monotonic_ns; the link's clock model on time.time_ns
    mono_to_epoch_ns = time.time_ns() - time.monotonic_ns()
    errors_us = []
    for ev in events:
        assert ev.t_start_host_ns is not None
        true_ns = sim._mono_ns_of_device_us(ev.t_start_device_us) + mono_to_epoch_ns
        errors_us.append(abs(ev.t_start_host_ns - true_ns) / 1000.0)
    # generous bound (shared, noisy machine): the offset alone is 5000 s, the drift 300 ppm
    assert max(errors_us) < 5000.0, errors_us
    assert client.clock.n_samples >= 30


def test_trigger_simulator_dropped_events_are_counted(sim_factory) -> None:  # type: ignore[no-untyped-def]
    """Events lost on the way show up as trigger_seq gaps, with the exact missing numbers."""
    sim, client = sim_factory(SimConfig(drop_seqs=frozenset({2, 7, 8})))
    client.configure(PERIOD_US, EXPOSURES_US)
    client.start(9)
    events = collect_events(client, 10)
    client.stop()
    assert [ev.trigger_seq for ev in events[:4]] == [0, 1, 3, 4]
    assert client.counters.missed_events >= 3
    assert client.counters.gaps[:2] == [(2, 3), (7, 9)]
    assert sim.counters["events_dropped"] >= 3


def test_trigger_simulator_reboot_detected(sim_factory) -> None:  # type: ignore[no-untyped-def]
    """A reboot mid-session: detected (unsolicited HELLO), pulses stop, clock model reset, a new session works."""
    reboots: list[int] = []
    sim, client = sim_factory()
    client.on_reboot = lambda: reboots.append(1)
    client.hello()
    client.sync_clock(4)
    client.start(11)
    collect_events(client, 3)
    sim.reboot()
    assert _wait_until(lambda: client.counters.reboots == 1)
    assert reboots == [1]
    assert not client.running
    assert client.clock.n_samples == 0
    client.drain_events()
    assert client.get_event(0.5) is None  # the rebooted device is idle
    assert client.hello()["device_kind"] == bproto.DEVICE_TRIGGER
    client.start(12)
    check_events(collect_events(client, 2)[:2], session_id=12)
    client.stop()
    assert client.counters.reboots == 1


def test_trigger_simulator_silent_reboot_detected_from_heartbeat(sim_factory) -> None:  # type: ignore[no-untyped-def]
    """A reboot whose HELLO is lost: the heartbeat uptime going backwards tells."""
    sim, client = sim_factory()
    assert _wait_until(lambda: client.last_heartbeat is not None and client.last_heartbeat["uptime_ms"] >= 1000)
    sim.reboot(announce=False)
    assert _wait_until(lambda: client.counters.reboots == 1)
    assert client.link.counters["unsolicited_hellos"] == 0


def test_trigger_simulate_command(tmp_path: Path) -> None:
    """`bracketry trigger simulate --link PATH` serves the protocol at PATH; `start`/`stop` commands drive it."""
    link = tmp_path / "ttyTRIGGER"
    proc = subprocess.Popen([sys.executable, "-m", "bracketry", "trigger", "simulate", "--link", str(link),
                             "--duration-s", "60"], stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    try:
        assert proc.stdout is not None
        assert f"connect to {link}" in proc.stdout.readline()
        out = subprocess.run([sys.executable, "-m", "bracketry", "trigger", "start", "--port", str(link), "--session",
                              "4", "--period-us", "2000", "--exposures-us", "100,200,300", "--timeout-s", "0.5"],
                             capture_output=True, text=True, timeout=60)
        assert out.returncode == 0 and "started session 4" in out.stdout, out.stderr
        out = subprocess.run([sys.executable, "-m", "bracketry", "trigger", "start", "--port", str(link), "--session",
                              "5", "--timeout-s", "0.5"], capture_output=True, text=True, timeout=60)
        assert out.returncode != 0 and "BAD_STATE" in out.stderr and "Traceback" not in out.stderr
        out = subprocess.run([sys.executable, "-m", "bracketry", "trigger", "status", "--port", str(link), "--json",
                              "--timeout-s", "0.5"], capture_output=True, text=True, timeout=60)
        assert out.returncode == 0, out.stderr
        status = json.loads(out.stdout)
        assert status["heartbeat"]["state"] == 1 and status["device"]["device_kind"] == 1
        out = subprocess.run([sys.executable, "-m", "bracketry", "trigger", "status", "--port", str(link),
                              "--timeout-s", "0.5"], capture_output=True, text=True, timeout=60)
        assert out.returncode == 0 and "state: running" in out.stdout and " us  error bound " in out.stdout, out
        out = subprocess.run([sys.executable, "-m", "bracketry", "trigger", "stop", "--port", str(link),
                              "--timeout-s", "0.5"], capture_output=True, text=True, timeout=60)
        assert out.returncode == 0, out.stderr
        out = subprocess.run([sys.executable, "-m", "bracketry", "trigger", "start", "--port", str(link), "--session",
                              "6", "--period-us", "500", "--exposures-us", "100"], capture_output=True, text=True,
                             timeout=60)
        assert out.returncode != 0 and out.stderr.startswith("error:") and "BAD_VALUE" in out.stderr
    finally:
        proc.terminate()
        proc.wait(timeout=10)
    assert not link.exists()


def test_trigger_qemu_runner_reports_missing_pieces(tmp_path: Path) -> None:
    """A missing ELF or a bad serial mode is one clear BracketryError, never a traceback or a hang."""
    from bracketry_base.errors import BracketryError
    from bracketry_rig.trigger.qemu import QemuTrigger

    with pytest.raises(BracketryError, match="ELF not found"):
        QemuTrigger(tmp_path / "missing.elf").start()
    with pytest.raises(BracketryError, match="tcp or pty"):
        QemuTrigger(tmp_path / "missing.elf", serial="udp")


def test_trigger_client_background_clock_sync(sim_factory) -> None:  # type: ignore[no-untyped-def]
    """The background clock sync keeps the clock model fed (TriggerClient.open: one PING per second)."""
    _sim, client = sim_factory(clock_sync_period_s=0.2)
    assert _wait_until(lambda: client.clock.n_samples >= 2, timeout_s=15.0)
    assert client.status()["clock"]["samples"] >= 2
