"""``bracketry devices``: list the rig's USB serial devices and write udev rules giving them stable names."""

from __future__ import annotations

import json
from pathlib import Path

import click

from bracketry_base.errors import BracketryError
from bracketry_base.options import input_file, output_file, overwrite_option
from bracketry_rig.daemon import devices as dev


@click.command("devices")
@click.option("--json", "as_json", is_flag=True, help="Print the devices as JSON.")
@click.option("--udev-rules", "rules_path", type=output_file(dash_stdout=True),
              help="Write udev rules naming the trigger and panel ports to this file ('-' for stdout).")
@overwrite_option()
@click.option("--role", "roles", multiple=True, metavar="SERIAL=ROLE",
              help="Assign a role (trigger or panel) to the device with this USB serial number.")
@click.option("--from-json", "recorded", type=input_file(),
              help="Use a recorded descriptor list instead of scanning USB.")
def command(as_json: bool, rules_path: Path | None, overwrite: bool, roles: tuple[str, ...],
            recorded: Path | None) -> int:
    """List the rig's USB serial devices (ST-LINK/STM32 VCP, FTDI, CP210x, CH340) and their ports."""
    role_map = {}
    for item in roles:
        serial, _, role = item.partition("=")
        if role not in dev.ROLE_SYMLINKS or not serial:
            raise BracketryError(f"--role {item!r}: expected SERIAL=trigger or SERIAL=panel")
        role_map[serial] = role
    found = dev.load_recorded(recorded) if recorded else dev.scan()
    if as_json:
        click.echo(json.dumps(dev.as_dicts(found), indent=2))
    elif not found:
        click.echo("no trigger or panel USB device found")
    else:
        for d in found:
            role = role_map.get(d.serial or "", d.role) or "-"
            click.echo(f"{role:<8} {d.usb_id}  {d.bridge:<40} serial={d.serial or '-':<24} port={d.port or '-'}")
    if rules_path is not None:
        text = dev.udev_rules(found, role_map)
        if str(rules_path) == "-":
            click.echo(text, nl=False)
        else:
            rules_path.write_text(text)
            click.echo(f"wrote {rules_path}", err=True)
    return 0
