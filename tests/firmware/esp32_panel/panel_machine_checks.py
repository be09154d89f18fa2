"""The panel's machine layer (main.py, panel_hw.py, hd44780.py) running on a fake ``machine`` module, under
MicroPython (WebAssembly) and CPython: boot HELLO on the UART, PANEL_STATE shown on the LCD via the 4-bit driver,
a button press on the GPIO becomes a BUTTON frame. Prints ``PASS <name>``."""

import bproto
import machine
import main
import pins

machine.LCD_PINS.update({pins.LCD_RS: "RS", pins.LCD_E: "E", pins.LCD_D4: "D4", pins.LCD_D5: "D5",
                         pins.LCD_D6: "D6", pins.LCD_D7: "D7"})
STATE = {"cam_left": 2, "cam_right": 3, "trigger": 1, "imu": 4, "lidar": 0, "gnss": 1, "free_disk_mb": 9500,
         "fps_left_centi": 2190, "fps_right_centi": 0, "rec_seconds": 59, "message": "MACHINE LAYER"}


def frames_out():
    dec = bproto.Decoder()
    out = []
    for chunk in machine.UART_TX:
        for fr in dec.feed(chunk):
            out.append((fr.msg_type, bproto.unpack_payload(fr.msg_type, fr.payload)))
    return out


def check_machine_layer_main_loop():
    it = {"n": 0}
    seen = {}

    def should_stop():
        it["n"] += 1
        n = it["n"]
        if n % 2 == 1:  # the host keeps talking (the loop is slow under WebAssembly: sleep_us is coarse there)
            machine.UART_RX.append(bproto.encode_message(bproto.MSG_PANEL_STATE, n, STATE))
        if 10 <= n < 20:
            machine.INPUTS[pins.BTN_RECORD] = 0  # pressed (pull-up, button to GND)
        if n == 20:
            machine.INPUTS[pins.BTN_RECORD] = 1
        if n > 20 and any(t == bproto.MSG_BUTTON for t, _f in frames_out()):
            return True
        return n > 400

    def hook(app):
        seen["screen"] = app.screen

    app = main.run(transport="uart", should_stop=should_stop, idle_hook=hook)
    out = frames_out()
    types = [t for t, _f in out]
    assert types[0] == bproto.MSG_HELLO and out[0][1]["device_kind"] == 2, out[:2]
    assert bproto.MSG_ACK in types
    buttons = [f for t, f in out if t == bproto.MSG_BUTTON]
    assert buttons and buttons[0]["button"] == 2 and buttons[0]["action"] == 1, out
    lcd = machine.lines()
    assert lcd[3] == "MACHINE LAYER       ", lcd
    assert lcd[2] == "21.9/ 0.0 9.5G 00:59", lcd
    assert lcd[0].startswith("L:REC R:") and lcd[1:] == seen["screen"][1:], (lcd, seen)
    assert app.link.counters["frames_in"] >= 10 and machine.STATE["strobes"] > 100


check_machine_layer_main_loop()
print("PASS check_machine_layer_main_loop")
