"""``bracketry daemon --config rig.toml``: the rig service (buttons, panel, cameras, trigger, recording)."""

from __future__ import annotations

from pathlib import Path

import click

from bracketry.daemon.config import load_config


@click.command("daemon")
@click.option("--config", "config_path", required=True, type=click.Path(dir_okay=False, path_type=Path),
              help="Rig configuration (TOML); see host/deploy/rig.example.toml.")
@click.option("--check", is_flag=True, help="Only validate the configuration and exit.")
@click.option("--log-level", default="INFO", show_default=True,
              type=click.Choice(["DEBUG", "INFO", "WARNING", "ERROR"], case_sensitive=False))
@click.option("--plain-logs", is_flag=True, help="Human-readable log lines instead of JSON lines.")
@click.option("--software-trigger", is_flag=True, hidden=True,
              help="Fire TriggerSoftware on every TRIGGER event (simulated rig with fake cameras).")
@click.option("--roi", default=None, hidden=True, help="WIDTHxHEIGHT region of interest (simulation).")
def command(config_path: Path, check: bool, log_level: str, plain_logs: bool, software_trigger: bool,
            roi: str | None) -> int:
    """Run the rig daemon until SIGTERM: SENSORS brings up cameras and trigger, RECORD starts/stops recording."""
    config = load_config(config_path)
    if check:
        click.echo(f"{config_path}: ok ({len(config.cameras)} cameras, brackets {list(config.brackets_ms)} ms "
                   f"at {config.fps:g} fps, output {config.output_dir})")
        return 0
    from bracketry.daemon.logs import setup_logging
    from bracketry.daemon.rig import DaemonOptions, RigDaemon, install_signal_handlers

    setup_logging(log_level, json_lines=not plain_logs)
    width = height = None
    if roi:
        w, _, h = roi.partition("x")
        width, height = int(w), int(h)
    daemon = RigDaemon(config, DaemonOptions(software_trigger=software_trigger, width=width, height=height))
    restore = install_signal_handlers(daemon)
    try:
        daemon.start()
        daemon.wait()
    finally:
        daemon.close()
        restore()
    return 0
