"""``bracketry panel``: run the real panel firmware on simulated hardware, or deploy it to an ESP32."""

from __future__ import annotations

import sys
from pathlib import Path

import click

from bracketry_base.options import Duration, option, output_file


@click.group()
def command() -> None:
    """ESP32 status panel: simulate it (the actual firmware files, on the host) or deploy its firmware."""


@command.command("simulate")
@click.option("--link", "link_path", required=True, help="Serial device or pty the simulated board talks on.")
@click.option("--screen-file", type=output_file(existing="replace"), default=None,
              help="Rewrite this file with the 4x20 screen (4 lines of 20 chars) on every change (its folder must "
                   "exist; an existing file is replaced: it is a live mirror).")
@option("--duration-s", "duration_s", aliases=("--duration",), type=Duration(), default=None,
        help="Stop after this many seconds (default: until `quit` on standard input).")
@click.option("--quiet", "-q", is_flag=True, help="Do not print the screen to the terminal.")
def simulate_cmd(link_path: str, screen_file: Path | None, duration_s: float | None, quiet: bool) -> int:
    """Run firmware/esp32_panel under CPython with a `machine` shim, connected over LINK.

    Buttons: type `sensors`, `record`, `sensors long` or `record long` (one per line) on standard input;
    `quit` stops. The LCD is printed to the terminal on every change.
    """
    from bracketry_rig.panel.sim import simulate

    return simulate(link_path, screen_file, duration_s, stdin=sys.stdin, out=None if quiet else sys.stdout)


@command.command("deploy")
@click.option("--port", required=True, help="Serial port of the ESP32 running MicroPython (e.g. /dev/ttyUSB0).")
@click.option("--dry-run", is_flag=True, help="Print the mpremote command instead of running it.")
def deploy_cmd(port: str, dry_run: bool) -> int:
    """Copy the firmware (and the wire codec bproto.py) to the board with mpremote, then reset it."""
    from bracketry_rig.panel.deploy import deploy

    cmd = deploy(port, dry_run=dry_run)
    if dry_run:
        click.echo(" ".join(cmd))
    else:
        click.echo(f"deployed {sum(1 for c in cmd if c.endswith('.py'))} files to {port}; the board was reset")
    return 0
