"""Entry point of the status panel firmware (MicroPython runs main.py at boot).

``run()`` is the main loop: 10 ms period, buttons scanned every iteration (debounce in panel_buttons), received bytes
fed to the protocol, the LCD refreshed (only changed characters). ``run`` takes arguments so that the host's simulator
can run this very file under CPython with a ``machine`` shim.
"""

import panel_clock
import panel_hw
from panel_app import PanelApp

LOOP_MS = 10
TRANSPORT = "usb"  # "usb": the USB console; "uart": machine.UART on pins.UART_TX/RX


def run(transport=TRANSPORT, should_stop=None, idle_hook=None):
    """Run the panel until ``should_stop()`` returns True (forever on the board).

    ``idle_hook(app)`` is called once per iteration after the LCD update (the simulator uses it to publish the screen).
    """
    lcd = panel_hw.make_lcd()
    buttons = panel_hw.Buttons()
    link = panel_hw.UartTransport() if transport == "uart" else panel_hw.UsbConsole()
    micros = panel_clock.MicrosClock()
    app = PanelApp(link.write, panel_hw.unique_id(), panel_clock.ticks_ms(), device_us=micros.now_us)
    while should_stop is None or not should_stop():
        now_ms = panel_clock.ticks_ms()
        micros.now_us()  # keeps the 64-bit clock extended
        sensors, record = buttons.read()
        app.step(now_ms, link.read(), sensors, record)
        lcd.show(app.screen)
        if idle_hook is not None:
            idle_hook(app)
        panel_clock.sleep_ms(LOOP_MS)
    return app


def safe_mode_requested():
    """True when SENSORS is held at boot: main.py then returns to the REPL (the link disables Ctrl-C)."""
    return panel_hw.Buttons().read()[0]


if __name__ == "__main__":
    if safe_mode_requested():
        print("bracketry panel: SENSORS held at boot -> safe mode (REPL)")
    else:
        run()
