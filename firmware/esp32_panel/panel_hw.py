"""The thin hardware layer of the panel: pins, LCD, buttons and the serial transport, on top of ``machine``.

Transports (both expose ``read() -> bytes`` (non-blocking, b"" when idle) and ``write(data)``):
- ``UsbConsole``: the board's USB serial console (sys.stdin/stdout); Ctrl-C handling is switched off so binary frames
  containing 0x03 do not interrupt the program.
- ``UartTransport``: ``machine.UART(pins.UART_ID)`` on pins.UART_TX/UART_RX (a USB-UART adapter, or the simulator's
  serial path).
"""

import machine
import pins
from hd44780 import HD44780


def make_lcd():
    """The 4x20 LCD on the pins of pins.py."""
    def out(n):
        return machine.Pin(n, machine.Pin.OUT, value=0)
    return HD44780(out(pins.LCD_RS), out(pins.LCD_E), out(pins.LCD_D4), out(pins.LCD_D5), out(pins.LCD_D6),
                   out(pins.LCD_D7))


class Buttons:
    """The two buttons (to GND, internal pull-ups): ``read() -> (sensors_pressed, record_pressed)``."""

    def __init__(self):
        self.sensors = machine.Pin(pins.BTN_SENSORS, machine.Pin.IN, machine.Pin.PULL_UP)
        self.record = machine.Pin(pins.BTN_RECORD, machine.Pin.IN, machine.Pin.PULL_UP)

    def read(self):
        return self.sensors.value() == 0, self.record.value() == 0


class UartTransport:
    """Serial link over machine.UART."""

    def __init__(self, baudrate=pins.UART_BAUDRATE):
        self.uart = machine.UART(pins.UART_ID, baudrate=baudrate, tx=pins.UART_TX, rx=pins.UART_RX, rxbuf=1024)

    def read(self):
        n = self.uart.any()
        if not n:
            return b""
        data = self.uart.read(n)
        return data or b""

    def write(self, data):
        self.uart.write(data)


class UsbConsole:
    """Serial link over the USB console (the REPL's stdin/stdout), non-blocking through select.poll."""

    def __init__(self):
        import select
        import sys

        import micropython
        micropython.kbd_intr(-1)  # 0x03 in a frame must not raise KeyboardInterrupt
        self._in = sys.stdin.buffer
        self._out = sys.stdout.buffer
        self._poll = select.poll()
        self._poll.register(sys.stdin, select.POLLIN)

    def read(self):
        data = b""
        while self._poll.poll(0) and len(data) < 256:
            data += self._in.read(1)
        return data

    def write(self, data):
        self._out.write(data)


def unique_id():
    """The board's id (ESP32: the 6-byte MAC)."""
    return machine.unique_id()
