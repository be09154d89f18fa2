"""Run the ACTUAL panel firmware files (firmware/esp32_panel/*.py) under CPython on simulated hardware.

The firmware's ``main.run`` executes unchanged with a ``machine`` shim (:mod:`bracketry_rig.panel.machine_shim`): its
HD44780 driver toggles pins that a pin-level controller emulator decodes into a 4x20 text buffer, its UART is the
serial device or pty at ``link_path`` (like the real board over USB), and buttons are pressed by text lines
(``sensors``, ``record``, ``sensors long``, ``record long``; ``quit`` stops). On every screen change the buffer is
printed to the terminal and, with ``screen_file``, that file is atomically rewritten as exactly 4 lines of 20
characters.
"""

from __future__ import annotations

import contextlib
import importlib
import os
import signal
import sys
import threading
import time
from collections.abc import Callable
from pathlib import Path
from typing import IO, Any

from bracketry_base import paths
from bracketry_base.errors import BracketryError
from bracketry_rig.panel.machine_shim import SimBoard

SHORT_PRESS_S = 0.15
LONG_PRESS_S = 1.5
#: longest a simulated press waits for the firmware to take it (or its release)
PRESS_TIMEOUT_S = 10.0
#: the firmware's ``PanelApp.buttons`` order
BUTTON_INDEX = {"sensors": 0, "record": 1}
FIRMWARE_MODULES = ("pins", "main", "panel_hw", "panel_app", "panel_link", "panel_layout", "panel_buttons",
                    "panel_clock", "hd44780", "bproto", "machine")


def firmware_dir() -> Path:
    """firmware/esp32_panel of the checkout."""
    return paths.firmware_dir() / "esp32_panel"


def bproto_dir() -> Path:
    """The folder holding the wire codec bproto.py (imported by the firmware as ``import bproto``)."""
    from bracketry_rig.wire import bproto

    return Path(bproto.__file__).resolve().parent


def write_screen_file(path: Path, lines: list[str]) -> None:
    """Atomically replace ``path`` with exactly 4 lines of 20 characters (newline terminated)."""
    text = "".join((line + " " * 20)[:20] + "\n" for line in lines[:4])
    tmp = path.with_name(path.name + ".tmp")
    tmp.write_text(text)
    os.replace(tmp, path)


def format_box(lines: list[str]) -> str:
    """The screen in a frame, for the terminal."""
    bar = "+" + "-" * 20 + "+"
    return "\n".join([bar, *("|" + line + "|" for line in lines), bar])


class PanelSimulator:
    """The simulated board running the firmware. ``run()`` blocks until ``stop()`` (or ``quit`` on stdin)."""

    def __init__(self, link_path: str, screen_file: Path | None = None, out: IO[str] | None = None) -> None:
        if not os.path.exists(link_path):
            raise BracketryError(f"link path {link_path} does not exist (a serial device or pty)")
        self.link_path = link_path
        self.screen_file = screen_file
        self.out = out
        self._stop = threading.Event()
        self._main: Any = None
        self._pins: Any = None
        self.board: SimBoard | None = None
        self._last_lines: list[str] | None = None
        self._drawn = False
        self.app: Any = None
        self._load_firmware()

    def _load_firmware(self) -> None:
        fw = firmware_dir()
        if not (fw / "main.py").is_file():
            raise BracketryError(f"panel firmware not found at {fw}")
        for name in FIRMWARE_MODULES:
            sys.modules.pop(name, None)
        for d in (str(bproto_dir()), str(fw)):
            if d in sys.path:
                sys.path.remove(d)
            sys.path.insert(0, d)
        self._pins = importlib.import_module("pins")
        self.board = SimBoard(self._pins, self.link_path)
        sys.modules["machine"] = self.board.module()
        self._main = importlib.import_module("main")

    def press(self, button: str, long: bool = False) -> None:
        """Hold ``button`` ("sensors"/"record") for a short (0.15 s) or long (1.5 s) press; blocks meanwhile.

        Like a person who holds a button until the board reacts, the button stays down at least that long AND until
        the firmware's debounce has taken the press (for a long press: until it sent its LONG event), then stays up
        until the firmware has seen the release, each at most ``PRESS_TIMEOUT_S``. A firmware loop slowed down by
        a busy machine (tens of ms between scans) thus still sees every press instead of a 0.15 s blip it
        sampled once or never."""
        assert self.board is not None
        self.board.set_button(button, True)
        self._stop.wait(LONG_PRESS_S if long else SHORT_PRESS_S)
        self._wait_for_firmware(button, lambda b: b.pressed and (b._long_sent or not long))
        self.board.set_button(button, False)
        self._wait_for_firmware(button, lambda b: not b.pressed)

    def _wait_for_firmware(self, button: str, taken: Callable[[Any], bool]) -> None:
        """Wait (at most ``PRESS_TIMEOUT_S``, or until stopped) until ``taken(firmware's Button object)``; returns
        at once before the firmware's first screen (no application object to look at yet)."""
        deadline = time.monotonic() + PRESS_TIMEOUT_S
        index = BUTTON_INDEX[button]
        while not self._stop.is_set() and time.monotonic() < deadline:
            app = self.app
            if app is None or taken(app.buttons[index]):
                return
            self._stop.wait(0.005)

    def handle_command(self, line: str) -> bool:
        """Execute one stdin command; returns False on ``quit``. Unknown commands are reported on stderr."""
        words = line.strip().lower().split()
        if not words:
            return True
        if words == ["quit"] or words == ["exit"]:
            self.stop()
            return False
        if words[0] in ("sensors", "record") and (len(words) == 1 or words[1:] in (["long"], ["short"])):
            self.press(words[0], long=words[1:] == ["long"])
            return True
        print(f"unknown command {line.strip()!r} (sensors, record, sensors long, record long, quit)", file=sys.stderr)
        return True

    def _stdin_loop(self, stream: IO[str]) -> None:
        for line in stream:
            if not self.handle_command(line) or self._stop.is_set():
                return

    def _publish(self, app: Any) -> None:
        self.app = app
        assert self.board is not None
        lines = self.board.lcd.lines()
        if lines == self._last_lines:
            return
        self._last_lines = lines
        if self.screen_file is not None:
            write_screen_file(self.screen_file, lines)
        if self.out is not None:
            if self._drawn and self.out.isatty():
                self.out.write("\x1b[6A")
            self.out.write(format_box(lines) + "\n")
            self.out.flush()
            self._drawn = True

    def stop(self) -> None:
        self._stop.set()

    def run(self, stdin: IO[str] | None = None, duration_s: float | None = None,
            on_start: Callable[[], None] | None = None) -> Any:
        """Run the firmware's main loop; returns the firmware's PanelApp when stopped."""
        if stdin is not None:
            threading.Thread(target=self._stdin_loop, args=(stdin,), daemon=True, name="panel-stdin").start()
        deadline = None if duration_s is None else time.monotonic() + duration_s

        def should_stop() -> bool:
            return self._stop.is_set() or (deadline is not None and time.monotonic() >= deadline)

        if on_start is not None:
            on_start()
        try:
            return self._main.run(transport="uart", should_stop=should_stop, idle_hook=self._publish)
        finally:
            if self.board is not None and self.board.serial is not None:
                self.board.serial.close()


def simulate(link_path: str, screen_file: Path | None = None, duration_s: float | None = None,
             stdin: IO[str] | None = None, out: IO[str] | None = None) -> int:
    """CLI entry: run until SIGTERM/SIGINT, ``quit`` on stdin, or ``duration_s``. Returns 0."""
    sim = PanelSimulator(link_path, screen_file, out)
    if threading.current_thread() is threading.main_thread():
        signal.signal(signal.SIGTERM, lambda *_a: sim.stop())
    with contextlib.suppress(KeyboardInterrupt):
        sim.run(stdin=stdin, duration_s=duration_s)
    return 0
