"""A ``machine`` module for CPython that lets the panel firmware run unchanged on the host.

``SimBoard`` owns the simulated hardware: the pin-level HD44780 emulator wired to the LCD pins of the firmware's
pins.py, button inputs (pulled up: 1 = released), and the serial link (a pty or serial device path) behind
``machine.UART``. ``SimBoard.module()`` returns the module object to install as ``sys.modules["machine"]``.
"""

from __future__ import annotations

import contextlib
import errno
import fcntl
import os
import select
import struct
import termios
import threading
import tty
import types
from typing import Any

from bracketry_rig.panel.lcd_emulator import HD44780Emulator

SIM_UID = b"\x02\xb5\x1d\x5a\x00\x01"  # locally administered MAC-like id of the simulated board


class SimSerial:
    """Non-blocking byte pipe over a path (pty, serial device): ``any()``, ``read(n)``, ``write(data)``."""

    def __init__(self, path: str) -> None:
        self.path = path
        self.fd = os.open(path, os.O_RDWR | os.O_NOCTTY | os.O_NONBLOCK)
        if os.isatty(self.fd):
            with contextlib.suppress(termios.error):
                tty.setraw(self.fd, termios.TCSANOW)
        self.bytes_in = 0
        self.bytes_out = 0

    def any(self) -> int:
        try:
            r, _w, _x = select.select([self.fd], [], [], 0)
        except (OSError, ValueError):
            return 0
        if not r:
            return 0
        try:
            n = struct.unpack("i", fcntl.ioctl(self.fd, termios.FIONREAD, b"\0\0\0\0"))[0]
        except OSError:
            n = 1
        return max(int(n), 1)

    def read(self, n: int = 256) -> bytes | None:
        try:
            data = os.read(self.fd, n)
        except BlockingIOError:
            return None
        except OSError as exc:  # EIO: the other side of a pty went away
            if exc.errno == errno.EIO:
                return None
            raise
        self.bytes_in += len(data)
        return data or None

    def write(self, data: bytes) -> int:
        view = memoryview(bytes(data))
        while view:
            try:
                n = os.write(self.fd, view)
            except BlockingIOError:
                select.select([], [self.fd], [], 0.05)
                continue
            except OSError as exc:
                if exc.errno == errno.EIO:  # nobody on the other end: drop, like an unplugged cable
                    return len(data)
                raise
            view = view[n:]
        self.bytes_out += len(data)
        return len(data)

    def close(self) -> None:
        with contextlib.suppress(OSError):
            os.close(self.fd)


class SimBoard:
    """Simulated ESP32 panel hardware. ``pins`` is the firmware's pins module (for the pin numbers)."""

    def __init__(self, pins: Any, link_path: str) -> None:
        self.lcd = HD44780Emulator()
        self.lcd_pins = {pins.LCD_RS: "RS", pins.LCD_E: "E", pins.LCD_D4: "D4", pins.LCD_D5: "D5",
                         pins.LCD_D6: "D6", pins.LCD_D7: "D7"}
        self.button_pins = {"sensors": pins.BTN_SENSORS, "record": pins.BTN_RECORD}
        self._inputs: dict[int, int] = {}
        self._lock = threading.Lock()
        self.link_path = link_path
        self.serial: SimSerial | None = None

    # -- what the tests / stdin drive
    def set_button(self, name: str, pressed: bool) -> None:
        """Press (True) or release a button by name ("sensors", "record")."""
        with self._lock:
            self._inputs[self.button_pins[name]] = 0 if pressed else 1

    def read_input(self, gpio: int) -> int:
        with self._lock:
            return self._inputs.get(gpio, 1)

    def module(self) -> types.ModuleType:
        """The ``machine`` module bound to this board."""
        board = self
        mod = types.ModuleType("machine")

        class Pin:
            IN = 1
            OUT = 3
            PULL_UP = 1
            PULL_DOWN = 2

            def __init__(self, gpio: int, mode: int = -1, pull: int | None = None, value: int | None = None):
                self.gpio = gpio
                self.mode = mode
                if value is not None:
                    self.value(value)

            def value(self, v: int | None = None) -> int | None:
                if v is None:
                    return board.read_input(self.gpio)
                name = board.lcd_pins.get(self.gpio)
                if name is not None:
                    board.lcd.set_pin(name, int(bool(v)))
                return None

            def __call__(self, v: int | None = None) -> int | None:
                return self.value(v)

            def on(self) -> None:
                self.value(1)

            def off(self) -> None:
                self.value(0)

        class UART:
            def __init__(self, uart_id: int, baudrate: int = 115200, **_kwargs: Any) -> None:
                self.id = uart_id
                self.baudrate = baudrate
                board.serial = SimSerial(board.link_path)
                self._s = board.serial

            def any(self) -> int:
                return self._s.any()

            def read(self, n: int = 256) -> bytes | None:
                return self._s.read(n)

            def write(self, data: bytes) -> int:
                return self._s.write(data)

        def unique_id() -> bytes:
            return SIM_UID

        mod.Pin = Pin  # type: ignore[attr-defined]
        mod.UART = UART  # type: ignore[attr-defined]
        mod.unique_id = unique_id  # type: ignore[attr-defined]
        return mod
