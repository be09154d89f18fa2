"""``bracketry record --config F --duration 30s``: one recording without buttons, then a verification."""

from __future__ import annotations

import re
import time
from pathlib import Path

import click

from bracketry.daemon.config import load_config
from bracketry.errors import BracketryError


def parse_duration_s(text: str) -> float:
    """``30``, ``30s``, ``2m``, ``1h`` or ``1m30s`` -> seconds (> 0)."""
    total = 0.0
    pos = 0
    for m in re.finditer(r"(\d+(?:\.\d+)?)([hms]?)", text.strip()):
        if m.start() != pos:
            break
        total += float(m.group(1)) * {"h": 3600, "m": 60, "s": 1, "": 1}[m.group(2)]
        pos = m.end()
    if pos != len(text.strip()) or total <= 0:
        raise BracketryError(f"--duration {text!r}: expected e.g. 30s, 2m, 1h or 1m30s")
    return total


@click.command("record")
@click.option("--config", "config_path", required=True, type=click.Path(dir_okay=False, path_type=Path))
@click.option("--duration", required=True, help="How long to record: 30s, 2m, 1h.")
@click.option("--software-trigger", is_flag=True, hidden=True)
@click.option("--roi", default=None, hidden=True, help="WIDTHxHEIGHT region of interest (simulation).")
def command(config_path: Path, duration: str, software_trigger: bool, roi: str | None) -> int:
    """Bring the sensors up, record for DURATION, stop cleanly and verify the files (exit 1 if problems)."""
    duration_s = parse_duration_s(duration)
    config = load_config(config_path)
    from bracketry.daemon.logs import setup_logging
    from bracketry.daemon.rig import DaemonOptions, RigDaemon, install_signal_handlers
    from bracketry.recording.verify import format_report, verify_recording

    setup_logging("WARNING", json_lines=False)
    width = height = None
    if roi:
        w, _, h = roi.partition("x")
        width, height = int(w), int(h)
    daemon = RigDaemon(config, DaemonOptions(software_trigger=software_trigger, width=width, height=height))
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
    return 0 if ok else 1
