"""An HD44780 controller emulated at the pin level, so the simulator exercises the firmware's real LCD driver.

It watches RS, E and D4-D7 (DB0-DB3 read as 0, R/W tied low): on each falling edge of E it latches the data lines.
After power-up the controller is in 8-bit mode (every strobe is a whole instruction, low nibble 0); the function set
0x2_ switches it to 4-bit mode, where bytes arrive as high then low nibble. Supported: clear, home, entry mode
(increment/decrement), display on/off, function set, set DDRAM/CGRAM address, data write. DDRAM follows the 2-line
map (0x00-0x27, 0x40-0x67); a 4x20 module shows rows at 0x00, 0x40, 0x14, 0x54.
"""

from __future__ import annotations

import threading

ROW_OFFSETS = (0x00, 0x40, 0x14, 0x54)


class HD44780Emulator:
    """Pin-level HD44780. Call ``set_pin(name, level)`` with name in RS, E, D4..D7; read ``lines()``."""

    def __init__(self, cols: int = 20, rows: int = 4) -> None:
        self.cols = cols
        self.rows = rows
        self._lock = threading.Lock()
        self.levels = {"RS": 0, "E": 0, "D4": 0, "D5": 0, "D6": 0, "D7": 0}
        self.ddram = bytearray(b" " * 0x68)
        self.addr = 0
        self.increment = True
        self.display_on = False
        self.four_bit = False
        self._high: int | None = None  # pending high nibble in 4-bit mode
        self._cgram_mode = False
        self.writes = 0  # data bytes written
        self.commands = 0  # instruction bytes executed
        self.version = 0  # bumps on every visible change

    def set_pin(self, name: str, level: int) -> None:
        """Drive one input pin; a falling edge of E latches the bus."""
        with self._lock:
            old = self.levels[name]
            self.levels[name] = 1 if level else 0
            if name == "E" and old == 1 and self.levels["E"] == 0:
                self._strobe()

    def _strobe(self) -> None:
        nib = self.levels["D4"] | self.levels["D5"] << 1 | self.levels["D6"] << 2 | self.levels["D7"] << 3
        rs = self.levels["RS"]
        if not self.four_bit:
            self._byte(nib << 4, rs)
            return
        if self._high is None:
            self._high = nib
        else:
            value = self._high << 4 | nib
            self._high = None
            self._byte(value, rs)

    def _advance(self) -> None:
        if self.increment:
            self.addr = {0x27: 0x40, 0x67: 0x00}.get(self.addr, self.addr + 1)
        else:
            self.addr = {0x40: 0x27, 0x00: 0x67}.get(self.addr, self.addr - 1)

    def _byte(self, value: int, rs: int) -> None:
        if rs:
            self.writes += 1
            if not self._cgram_mode:
                self.ddram[self.addr] = value
                self.version += 1
                self._advance()
            return
        self.commands += 1
        if value & 0x80:
            self.addr = value & 0x7F
            if self.addr > 0x67 or 0x27 < self.addr < 0x40:
                self.addr = 0
            self._cgram_mode = False
        elif value & 0x40:
            self._cgram_mode = True
        elif value & 0x20:
            self.four_bit = not (value & 0x10)
            self._high = None
        elif value & 0x10:
            pass  # cursor/display shift: not used by the firmware
        elif value & 0x08:
            self.display_on = bool(value & 0x04)
            self.version += 1
        elif value & 0x04:
            self.increment = bool(value & 0x02)
        elif value & 0x02:
            self.addr = 0
        elif value & 0x01:
            self.ddram[:] = b" " * len(self.ddram)
            self.addr = 0
            self.increment = True
            self.version += 1

    def lines(self) -> list[str]:
        """What the display shows: ``rows`` strings of ``cols`` characters (blank while the display is off)."""
        with self._lock:
            if not self.display_on:
                return [" " * self.cols for _ in range(self.rows)]
            out = []
            for r in range(self.rows):
                raw = self.ddram[ROW_OFFSETS[r]:ROW_OFFSETS[r] + self.cols]
                out.append("".join(chr(b) if 32 <= b < 127 else "?" for b in raw))
            return out
