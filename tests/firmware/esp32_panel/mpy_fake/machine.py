"""A minimal fake ``machine`` module for running the panel's machine layer under the MicroPython WebAssembly
runtime (which has no ``machine``): Pins drive a tiny HD44780 decoder, the UART is an in-memory byte queue."""

LCD = {"RS": 0, "E": 0, "D4": 0, "D5": 0, "D6": 0, "D7": 0}
LCD_PINS = {}  # gpio -> name, set by the test script from pins.py
INPUTS = {}  # gpio -> level (1 = released)
DDRAM = bytearray(b" " * 0x68)
STATE = {"four_bit": False, "high": None, "addr": 0, "strobes": 0}
UART_RX = []  # byte strings the "host" sends
UART_TX = []  # byte strings the firmware wrote


def _byte(value, rs):
    if rs:
        DDRAM[STATE["addr"]] = value
        STATE["addr"] = {0x27: 0x40, 0x67: 0x00}.get(STATE["addr"], STATE["addr"] + 1)
    elif value & 0x80:
        STATE["addr"] = value & 0x7F
    elif value & 0x20:
        STATE["four_bit"] = not (value & 0x10)
        STATE["high"] = None
    elif value == 0x01:
        for i in range(len(DDRAM)):
            DDRAM[i] = 32
        STATE["addr"] = 0


def _strobe():
    STATE["strobes"] += 1
    nib = LCD["D4"] | LCD["D5"] << 1 | LCD["D6"] << 2 | LCD["D7"] << 3
    if not STATE["four_bit"]:
        _byte(nib << 4, LCD["RS"])
    elif STATE["high"] is None:
        STATE["high"] = nib
    else:
        v = STATE["high"] << 4 | nib
        STATE["high"] = None
        _byte(v, LCD["RS"])


def lines():
    out = []
    for off in (0x00, 0x40, 0x14, 0x54):
        out.append("".join([chr(b) for b in DDRAM[off:off + 20]]))
    return out


class Pin:
    IN = 1
    OUT = 3
    PULL_UP = 1

    def __init__(self, gpio, mode=-1, pull=None, value=None):
        self.gpio = gpio
        if value is not None:
            self.value(value)

    def value(self, v=None):
        if v is None:
            return INPUTS.get(self.gpio, 1)
        name = LCD_PINS.get(self.gpio)
        if name is not None:
            old = LCD[name]
            LCD[name] = 1 if v else 0
            if name == "E" and old == 1 and LCD[name] == 0:
                _strobe()
        return None


class UART:
    def __init__(self, uart_id, baudrate=115200, **kw):
        self.id = uart_id

    def any(self):
        return sum([len(b) for b in UART_RX])

    def read(self, n=256):
        if not UART_RX:
            return None
        data = b"".join(UART_RX)
        del UART_RX[:]
        return data

    def write(self, data):
        UART_TX.append(bytes(data))
        return len(data)


def unique_id():
    return b"\x24\x6f\x28\xa1\xb2\xc3"
