"""Copy the panel firmware onto an ESP32 running MicroPython with ``mpremote`` (PyPI), then reset the board.

Files: every ``*.py`` of firmware/esp32_panel plus the wire codec ``bproto.py`` from its package location (the
firmware imports it as ``import bproto``); all land in the board's root folder, ``main.py`` runs at boot.
"""

from __future__ import annotations

import importlib.util
import shutil
import subprocess
import sys
from pathlib import Path

from bracketry_base.errors import BracketryError, MissingComponentError
from bracketry_rig.panel.sim import bproto_dir, firmware_dir


def firmware_files() -> list[Path]:
    """The files copied to the board (sorted; main.py last so a half-finished copy never boots)."""
    files = sorted(p for p in firmware_dir().glob("*.py") if p.name != "main.py")
    return [*files, bproto_dir() / "bproto.py", firmware_dir() / "main.py"]


def mpremote_command(port: str, files: list[Path] | None = None) -> list[str]:
    """The mpremote invocation: connect, copy every file to ``:``, reset."""
    files = files if files is not None else firmware_files()
    return [sys.executable, "-m", "mpremote", "connect", port, "fs", "cp", *[str(f) for f in files], ":",
            "+", "reset"]


def deploy(port: str, dry_run: bool = False, timeout_s: float = 120.0) -> list[str]:
    """Run (or with ``dry_run`` only return) the mpremote command. Raises BracketryError on failure."""
    cmd = mpremote_command(port)
    for f in firmware_files():
        if not f.is_file():
            raise BracketryError(f"firmware file missing: {f}")
    if dry_run:
        return cmd
    if importlib.util.find_spec("mpremote") is None:
        raise MissingComponentError("mpremote is not installed (pip install -e '.[host]')")
    if not port.startswith(("/dev/", "COM", "socket://", "rfc2217://")) and shutil.which(port) is None \
            and not Path(port).exists():
        raise BracketryError(f"serial port {port} not found")
    try:
        proc = subprocess.run(cmd, capture_output=True, text=True, timeout=timeout_s)
    except subprocess.TimeoutExpired:
        raise BracketryError(f"mpremote timed out after {timeout_s:.0f} s on {port}") from None
    if proc.returncode != 0:
        last = (proc.stderr.strip() or proc.stdout.strip() or "no output").splitlines()[-1]
        raise BracketryError(f"mpremote failed on {port}: {last} (if the panel firmware is running, hold SENSORS "
                             "while resetting the board to start it in safe mode, then deploy again)")
    return cmd
