"""``bracketry daemon --config rig.toml``: the rig service (buttons, panel, cameras, trigger, recording)."""

from __future__ import annotations

from pathlib import Path

import click

from bracketry_base.options import EXIT_OK, input_file
from bracketry_base.outputs import check_output
from bracketry_rig.daemon.config import load_config


@click.command("daemon")
@click.option("--config", "config_path", required=True, type=input_file(),
              help="Rig configuration (TOML); see host/deploy/rig.example.toml.")
@click.option("--check", is_flag=True,
              help="Only validate the configuration (and that its output_dir is a writable folder) and exit.")
@click.option("--log-level", default="info", show_default=True,
              type=click.Choice(["debug", "info", "warning", "error"], case_sensitive=False),
              help="Lowest level of the log lines written.")
@click.option("--plain-logs", is_flag=True, help="Human-readable log lines instead of JSON lines.")
@click.option("--software-trigger", is_flag=True, hidden=True,
              help="No effect (kept for old command lines): cameras whose profile has no trigger line, such as "
                   "aravis_fake, are fired in software at every TRIGGER event.")
@click.option("--roi", default=None, hidden=True, help="WIDTHxHEIGHT region of interest (simulation).")
def command(config_path: Path, check: bool, log_level: str, plain_logs: bool, software_trigger: bool,
            roi: str | None) -> int:
    """Run the rig daemon until SIGTERM: SENSORS brings up cameras and trigger, RECORD starts/stops recording."""
    config = load_config(config_path)
    check_output(config.output_dir, "dir", existing="resume", what="output_dir", parents=True)
    if check:
        click.echo(f"{config_path}: ok ({len(config.cameras)} cameras, brackets {list(config.brackets_ms)} ms "
                   f"at {config.fps:g} fps, output {config.output_dir})")
        return 0
    from bracketry_rig.daemon.logs import setup_logging
    from bracketry_rig.daemon.rig import DaemonOptions, RigDaemon, install_signal_handlers

    setup_logging(log_level.upper(), json_lines=not plain_logs)
    width = height = None
    if roi:
        w, _, h = roi.partition("x")
        width, height = int(w), int(h)
    daemon = RigDaemon(config, DaemonOptions(width=width, height=height))
    restore = install_signal_handlers(daemon)
    try:
        daemon.start()
        daemon.wait()
    finally:
        daemon.close()
        restore()
    return EXIT_OK
