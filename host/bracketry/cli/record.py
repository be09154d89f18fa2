"""``bracketry record --config F --duration 30s``: one recording without buttons, then a verification."""

from __future__ import annotations

import time
from pathlib import Path

import click

from bracketry_base.errors import BracketryError
from bracketry_base.options import EXIT_OK, EXIT_PROBLEMS, Duration, input_file, option
from bracketry_base.outputs import check_output
from bracketry_rig.daemon.config import load_config


@click.command("record")
@click.option("--config", "config_path", required=True, type=input_file(),
              help="Rig configuration (TOML, as for the daemon); the recording goes to its output_dir.")
@option("--duration-s", "duration_s", aliases=("--duration",), required=True, type=Duration(),
        help="How long to record: seconds, or with a unit: 30s, 2m, 1h, 1m30s (at most a week).")
@click.option("--software-trigger", is_flag=True, hidden=True,
              help="No effect (kept for old command lines): cameras whose profile has no trigger line, such as "
                   "aravis_fake, are fired in software at every TRIGGER event.")
@click.option("--roi", default=None, hidden=True, help="WIDTHxHEIGHT region of interest (simulation).")
def command(config_path: Path, duration_s: float, software_trigger: bool, roi: str | None) -> int:
    """Bring the sensors up, record for --duration-s, stop cleanly and verify the files (exit 1 if problems)."""
    config = load_config(config_path)
    check_output(config.output_dir, "dir", existing="resume", what="output_dir", parents=True)
    from bracketry_base.recording.verify import format_report, verify_recording
    from bracketry_rig.daemon.logs import setup_logging
    from bracketry_rig.daemon.rig import DaemonOptions, RigDaemon, install_signal_handlers

    setup_logging("WARNING", json_lines=False)
    width = height = None
    if roi:
        w, _, h = roi.partition("x")
        width, height = int(w), int(h)
    daemon = RigDaemon(config, DaemonOptions(width=width, height=height))
    daemon.config = config.__class__(**{**config.__dict__, "panel": config.panel.__class__(enabled=False)})
    restore = install_signal_handlers(daemon)
    try:
        daemon.start()
        if not daemon.sensors_up():
            snap = daemon.state.snapshot()
            raise BracketryError("sensors not ready: " + "; ".join(f"{k}: {v}" for k, v in snap.errors.items()))
        if not daemon.start_recording():
            raise BracketryError(f"recording did not start: {daemon.state.snapshot().message}")
        click.echo(f"recording {duration_s:g} s to {config.output_dir / str(daemon.rec_name)}", err=True)
        deadline = time.monotonic() + duration_s
        while time.monotonic() < deadline and not daemon.wait(min(1.0, deadline - time.monotonic())):
            pass
        daemon.stop_recording()
    finally:
        daemon.close()
        restore()
    seg_dirs = [seg["dir"] for seg in daemon.segments if seg["files"]]
    if not seg_dirs:
        raise BracketryError("nothing was recorded")
    ok = True
    for seg_dir in seg_dirs:
        report = verify_recording(seg_dir)
        click.echo(format_report(report))
        ok = ok and report.ok
    return EXIT_OK if ok else EXIT_PROBLEMS
