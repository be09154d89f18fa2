"""HD44780 / ST7066U character LCD driver, 4-bit parallel, write only (R/W tied to GND). For the NHD-0420H1Z 4x20.

``pins`` are objects with ``.value(v)`` (machine.Pin in output mode). Only the characters that changed since the last
``show`` are rewritten (each write: set DDRAM address, then data), so a 5 Hz refresh costs little bus time.
"""

from panel_clock import sleep_ms, sleep_us

ROW_OFFSETS = (0x00, 0x40, 0x14, 0x54)  # DDRAM address of each row's first column on a 4x20 module
CMD_CLEAR = 0x01
CMD_ENTRY_MODE_INC = 0x06
CMD_DISPLAY_ON = 0x0C
CMD_DISPLAY_OFF = 0x08
CMD_FUNCTION_4BIT_2LINE = 0x28
CMD_SET_DDRAM = 0x80


class HD44780:
    """4-bit HD44780 driver. ``show(lines)`` puts a list of ``rows`` strings of ``cols`` chars on the display."""

    def __init__(self, rs, e, d4, d5, d6, d7, cols=20, rows=4):
        self.rs = rs
        self.e = e
        self.data = (d4, d5, d6, d7)
        self.cols = cols
        self.rows = rows
        self._shadow = None
        self.init()

    def _pulse(self, wait_us):
        self.e.value(1)
        sleep_us(1)  # E high >= 230 ns
        self.e.value(0)
        sleep_us(wait_us)

    def _nibble(self, nib, wait_us=50):
        for i in range(4):
            self.data[i].value((nib >> i) & 1)
        self._pulse(wait_us)

    def _byte(self, value, rs):
        self.rs.value(rs)
        self._nibble(value >> 4, 1)  # the controller only executes after the second nibble
        self._nibble(value & 0x0F, 50)  # most instructions and data writes need 37 us

    def command(self, cmd):
        """Send an instruction byte (RS = 0); waits 2 ms after clear/home."""
        self._byte(cmd, 0)
        if cmd <= 0x03:
            sleep_ms(2)

    def write_char(self, code):
        """Write one character code (RS = 1) at the cursor."""
        self._byte(code, 1)

    def init(self):
        """Power-on initialisation by instruction (datasheet sequence: 3x 0x3, then 0x2 -> 4-bit)."""
        self.e.value(0)
        self.rs.value(0)
        sleep_ms(50)
        self._nibble(0x03)
        sleep_ms(5)
        self._nibble(0x03)
        sleep_us(150)
        self._nibble(0x03)
        self._nibble(0x02)
        self.command(CMD_FUNCTION_4BIT_2LINE)
        self.command(CMD_DISPLAY_OFF)
        self.command(CMD_CLEAR)
        self.command(CMD_ENTRY_MODE_INC)
        self.command(CMD_DISPLAY_ON)
        self._shadow = [" " * self.cols for _ in range(self.rows)]

    def show(self, lines):
        """Display ``lines`` (rows x cols, ASCII); rewrites only the runs of characters that changed."""
        for row in range(self.rows):
            new = lines[row] if row < len(lines) else ""
            new = (new + " " * self.cols)[:self.cols]
            old = self._shadow[row]
            col = 0
            while col < self.cols:
                if new[col] == old[col]:
                    col += 1
                    continue
                self.command(CMD_SET_DDRAM | (ROW_OFFSETS[row] + col))
                while col < self.cols and new[col] != old[col]:
                    code = ord(new[col])
                    self.write_char(code if 32 <= code < 127 else 63)
                    col += 1
            self._shadow[row] = new
