"""``bracketry trigger``: talk to the STM32 trigger (real or emulated), boot its firmware in QEMU, or simulate it."""

from __future__ import annotations

import contextlib
import json
import signal
import time
from pathlib import Path
from typing import Any

import click

from bracketry_base.errors import BracketryError
from bracketry_base.options import SEED, Duration, Integer, count, finite, input_file, non_negative, option, positive
from bracketry_base.outputs import check_output

PORT_HELP = "Serial port of the trigger: /dev/ttyACM0, a pty path, or socket://127.0.0.1:PORT (QEMU)."


def _parse_exposures(text: str) -> list[int]:
    try:
        values = [int(v) for v in text.replace(" ", "").split(",") if v]
    except ValueError:
        raise BracketryError(f"--exposures-us must be comma-separated integers (us), got {text!r}") from None
    if not values:
        raise BracketryError("--exposures-us is empty")
    if any(not 0 <= v <= 0xFFFFFFFF for v in values):  # the wire's range; the trigger owns the value rules
        raise BracketryError(f"--exposures-us {text!r}: each exposure must be 0..4294967295 us")
    return values


def _client(port: str, timeout_s: float) -> Any:
    from bracketry_rig.trigger.client import TriggerClient

    return TriggerClient.open(port, timeout_s=timeout_s)


def _wait_forever(duration_s: float | None) -> bool:
    """Sleep until Ctrl-C / SIGTERM (returns False), or for ``duration_s`` (returns True)."""
    stop = {"flag": False}

    def handler(_signum: int, _frame: object) -> None:
        stop["flag"] = True

    previous = signal.signal(signal.SIGTERM, handler)
    deadline = None if duration_s is None else time.monotonic() + duration_s
    try:
        while not stop["flag"] and (deadline is None or time.monotonic() < deadline):
            time.sleep(0.1)
    except KeyboardInterrupt:
        return False
    finally:
        signal.signal(signal.SIGTERM, previous)
    return not stop["flag"]


@click.group("trigger")
def command() -> None:
    """STM32 trigger: talk to it, run its firmware in QEMU, or simulate it.

    The trigger pulses both cameras from one hardware timer (pulse width = exposure) and reports one TRIGGER event
    per pulse with its device time; see firmware/stm32_trigger/README.md.
    """


timeout_option = option("--timeout-s", "timeout_s", aliases=("--timeout",), type=positive(60.0), default=0.1,
                        show_default=True,
                        help="Reply timeout per attempt in seconds (3 retries); use 0.5 for QEMU on a busy machine.")
duration_option = option("--duration-s", "duration_s", aliases=("--duration",), type=Duration(), default=None,
                         help="Stop after this many seconds (default: run until Ctrl-C).")


@command.command("simulate")
@click.option("--link", "link_path", required=True, type=click.Path(path_type=Path),
              help="Symlink to create for the simulated port (must not exist; open it like a serial port).")
@click.option("--drift-ppm", type=finite(-1e5, 1e5), default=0.0, show_default=True,
              help="Device clock rate error (ppm).")
@click.option("--pulse-jitter-us", type=non_negative(1e6), default=0.0, show_default=True,
              help="Pulse start jitter, standard deviation (us).")
@click.option("--reply-jitter-us", type=non_negative(1e6), default=0.0, show_default=True,
              help="Mean extra reply latency (us).")
@click.option("--drop-prob", type=finite(0.0, 1.0), default=0.0, show_default=True,
              help="Probability of not sending a TRIGGER event.")
@click.option("--seed", type=SEED, default=0, show_default=True, help="Seed of the simulated jitter and drops.")
@click.option("--reboot-every-s", type=positive(86400.0), default=None, help="Simulate a device reset this often (s).")
@duration_option
def simulate(link_path: Path, drift_ppm: float, pulse_jitter_us: float, reply_jitter_us: float, drop_prob: float,
             seed: int, reboot_every_s: float | None, duration_s: float | None) -> int:
    """Run the behavioural trigger simulator on a pty linked at --link (SIGUSR1: 256 bytes of seeded line noise on
    the wire, a serial-garbage fault)."""
    from bracketry_rig.trigger.simulator import SimConfig, simulate_on_pty

    check_output(link_path, "file", what="--link")
    config = SimConfig(drift_ppm=drift_ppm, pulse_jitter_us=pulse_jitter_us, reply_jitter_us=reply_jitter_us,
                       drop_prob=drop_prob, seed=seed)
    try:
        sim, path = simulate_on_pty(link_path, config)
    except (OSError, FileExistsError) as exc:
        raise BracketryError(f"cannot create the simulated port at {link_path}: {exc}") from None
    click.echo(f"trigger simulator running: connect to {path}", err=False)
    signal.signal(signal.SIGUSR1, lambda _signum, _frame: sim.send_garbage())
    try:
        if reboot_every_s is not None and reboot_every_s > 0:
            deadline = None if duration_s is None else time.monotonic() + duration_s
            while deadline is None or time.monotonic() < deadline:
                step = reboot_every_s if deadline is None else min(reboot_every_s, deadline - time.monotonic())
                if not _wait_forever(max(0.0, step)):
                    break
                if deadline is None or time.monotonic() < deadline:
                    sim.reboot()
                    click.echo("simulated reboot", err=True)
        else:
            _wait_forever(duration_s)
    finally:
        sim.close()
        with contextlib.suppress(OSError):
            if link_path.is_symlink():
                link_path.unlink()
    click.echo("counters: " + " ".join(f"{k}={v}" for k, v in sim.counters.items()))
    return 0


@command.command("qemu")
@click.option("--elf", type=input_file(), default=None,
              help="Firmware ELF (default: firmware/stm32_trigger/build/stm32_trigger.elf, built if missing).")
@click.option("--build/--no-build", default=False, help="Rebuild the firmware first.")
@click.option("--serial", type=click.Choice(["tcp", "pty"]), default="tcp", show_default=True,
              help="Expose USART2 as a loopback TCP server or a pty.")
@click.option("--tcp-port", type=Integer(1024, 65535), default=None,
              help="TCP port on 127.0.0.1 (default: a free one).")
@duration_option
def qemu(elf: Path | None, build: bool, serial: str, tcp_port: int | None, duration_s: float | None) -> int:
    """Boot the real trigger firmware in qemu-system-arm -M netduinoplus2 and print where to connect."""
    from bracketry_rig.trigger.qemu import QemuTrigger, build_firmware, default_elf

    if elf is None:
        elf = default_elf()
        if build or not elf.is_file():
            click.echo("building the firmware ...", err=True)
            elf = build_firmware()
    elif build:
        raise BracketryError("--build only applies to the default ELF (omit --elf)")
    runner = QemuTrigger(elf, serial=serial, port=tcp_port).start()
    try:
        click.echo(f"trigger firmware running in QEMU (pid {runner.proc.pid if runner.proc else '?'}): "
                   f"connect to {runner.url}")
        click.echo(f"e.g. bracketry trigger hello --port {runner.url} --timeout-s 0.5", err=True)
        _wait_forever(duration_s)
    finally:
        runner.stop()
    return 0


@command.command("hello")
@click.option("--port", required=True, help=PORT_HELP)
@timeout_option
@click.option("--json", "as_json", is_flag=True, help="Print JSON instead of text.")
def hello(port: str, timeout_s: float, as_json: bool) -> int:
    """Ask the trigger who it is (HELLO)."""
    with _client(port, timeout_s) as client:
        fields = client.hello()
    fields = {k: (v.hex() if isinstance(v, bytes) else v) for k, v in fields.items()}
    if as_json:
        click.echo(json.dumps(fields))
    else:
        click.echo(f"trigger fw {fields['fw_major']}.{fields['fw_minor']}.{fields['fw_patch']} "
                   f"proto 1.{fields['proto_minor']} uid {fields['uid']} capabilities 0x{fields['capabilities']:x}")
    return 0


@command.command("status")
@click.option("--port", required=True, help=PORT_HELP)
@timeout_option
@click.option("--json", "as_json", is_flag=True, help="Print JSON instead of text.")
def status(port: str, timeout_s: float, as_json: bool) -> int:
    """HELLO, a clock sync (PING/PONG) and the next heartbeat: device, state, clock offset quality."""
    with _client(port, timeout_s) as client:
        client.hello()
        client.sync_clock(8)
        deadline = time.monotonic() + 1.5
        while client.last_heartbeat is None and time.monotonic() < deadline:
            time.sleep(0.05)
        st = client.status()
        st["counters"]["link"] = client.link.counters
    st["device"] = {k: (v.hex() if isinstance(v, bytes) else v) for k, v in st["device"].items()}
    if as_json:
        click.echo(json.dumps(st, default=str))
        return 0
    hb = st["heartbeat"]
    state = "unknown (no heartbeat)" if hb is None else ("running" if hb["state"] else "idle")
    clock = st["clock"]
    click.echo(f"state: {state}" + ("" if hb is None else f"  uptime {hb['uptime_ms'] / 1000:.1f} s"))
    click.echo(f"clock: residual {clock['residual_us']:.1f} us  drift {clock['drift_ppm']:.1f} ppm  "
               f"min rtt {clock['min_rtt_us']:.0f} us  error bound {clock['error_bound_us']:.0f} us  "
               f"({clock['samples']} samples)")
    click.echo(f"capabilities: 0x{st['device']['capabilities']:x}")
    return 0


@command.command("start")
@click.option("--port", required=True, help=PORT_HELP)
@click.option("--session", "session_id", type=click.IntRange(0, 2**32 - 1), required=True, help="Session id.")
@click.option("--period-us", type=Integer(0, 0xFFFFFFFF), default=None,
              help="Pulse period in us (e.g. 45454 for 22 fps; the trigger accepts 1000..1000000); with "
                   "--exposures-us.")
@click.option("--exposures-us", default=None,
              help="Bracket table in us, e.g. 1000,2000,4000,8000,16000,32000; with --period-us.")
@timeout_option
def start(port: str, session_id: int, period_us: int | None, exposures_us: str | None, timeout_s: float) -> int:
    """Optionally SET_BRACKETS, then START a session."""
    if (period_us is None) != (exposures_us is None):
        raise BracketryError("--period-us and --exposures-us go together")
    with _client(port, timeout_s) as client:
        if period_us is not None and exposures_us is not None:
            client.configure(period_us, _parse_exposures(exposures_us))
        client.start(session_id)
    click.echo(f"started session {session_id}")
    return 0


@command.command("stop")
@click.option("--port", required=True, help=PORT_HELP)
@timeout_option
def stop(port: str, timeout_s: float) -> int:
    """STOP the pulses (idempotent)."""
    with _client(port, timeout_s) as client:
        client.stop()
    click.echo("stopped")
    return 0


@command.command("monitor")
@click.option("--port", required=True, help=PORT_HELP)
@click.option("--start", "session_id", type=click.IntRange(0, 2**32 - 1), default=None,
              help="START this session first (and STOP it at the end).")
@click.option("--count", type=count(1), default=None, help="Stop after this many events.")
@duration_option
@timeout_option
def monitor(port: str, session_id: int | None, count: int | None, duration_s: float | None,
            timeout_s: float) -> int:
    """Print TRIGGER events (device time and host time through the clock model), gaps and reboots."""
    with _client(port, timeout_s) as client:
        client.hello()
        client.sync_clock(8)
        if session_id is not None:
            client.start(session_id)
        n = 0
        deadline = None if duration_s is None else time.monotonic() + duration_s
        try:
            while (count is None or n < count) and (deadline is None or time.monotonic() < deadline):
                ev = client.get_event(0.2)
                if ev is None:
                    continue
                n += 1
                host = "-" if ev.t_start_host_ns is None else f"{ev.t_start_host_ns / 1e9:.6f}"
                click.echo(f"session={ev.session_id} seq={ev.trigger_seq} bracket={ev.bracket_index} "
                           f"exposure_us={ev.exposure_us} t_device_us={ev.t_start_device_us} t_host_s={host}")
        except KeyboardInterrupt:
            pass
        finally:
            if session_id is not None:
                with contextlib.suppress(BracketryError):
                    client.stop()
        c = client.counters
        click.echo(f"events={c.events} missed={c.missed_events} reboots={c.reboots}", err=True)
    return 0
