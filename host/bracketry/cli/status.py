"""``bracketry status``: ask the running daemon for its state over its local UNIX socket."""

from __future__ import annotations

import json
from pathlib import Path

import click

from bracketry_base.options import input_file
from bracketry_rig.daemon.status import query

DEFAULT_SOCKET = Path("/run/bracketry/status.sock")


@click.command("status")
@click.option("--socket", "socket_path", type=click.Path(path_type=Path), default=None,
              help=f"The daemon's status socket [default: rig.status_socket of --config, else {DEFAULT_SOCKET}].")
@click.option("--config", "config_path", type=input_file(), default=None,
              help="The daemon's config file: its rig.status_socket is used.")
@click.option("--json", "as_json", is_flag=True, help="Print the raw JSON state.")
def command(socket_path: Path | None, config_path: Path | None, as_json: bool) -> int:
    """Ask the running daemon for every sensor's state, FPS, free disk and recording."""
    if socket_path is None:
        if config_path is not None:
            from bracketry_rig.daemon.config import load_config

            socket_path = load_config(config_path).status_socket
        else:
            socket_path = DEFAULT_SOCKET
    reply = query(socket_path, {"cmd": "status"})
    if as_json:
        click.echo(json.dumps(reply, indent=2))
        return 0
    state = reply.get("state", {})
    states = state.get("states", {})
    click.echo("  ".join(f"{k}={v}" for k, v in states.items()))
    fps = state.get("fps", {})
    click.echo(f"fps left={fps.get('left', 0):.1f} right={fps.get('right', 0):.1f}  "
               f"free disk={state.get('free_disk_mb', 0) / 1024:.1f} GB  rec={state.get('rec_seconds', 0)} s")
    if state.get("recording"):
        click.echo(f"recording: {state['recording']}")
    for sensor, err in state.get("errors", {}).items():
        click.echo(f"error {sensor}: {err}")
    counters = state.get("counters", {})
    if counters:
        click.echo("counters: " + " ".join(f"{k}={v}" for k, v in sorted(counters.items())))
    click.echo(f"message: {state.get('message', '')}")
    return 0
