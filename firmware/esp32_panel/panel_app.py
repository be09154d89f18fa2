"""The panel application core: buttons + link + layout -> the 4x20 screen buffer (hardware independent).

``PanelApp.step(now_ms, rx_bytes, sensors_pressed, record_pressed)`` does one main-loop iteration and returns the
screen (list of 4 strings of 20 chars). Screens: boot (until the first PANEL_STATE), status, HOST LOST (after 1.5 s
without host frames, until frames return).
"""

import panel_layout
from panel_buttons import BUTTON_RECORD, BUTTON_SENSORS, Button
from panel_link import PanelLink

FW_VERSION = (1, 0, 0)

SCREEN_BOOT = "boot"
SCREEN_STATUS = "status"
SCREEN_HOST_LOST = "host_lost"


class PanelApp:
    """Ties the protocol, the two buttons and the layouts together. ``write`` sends bytes to the host."""

    def __init__(self, write, uid, now_ms, device_us=None):
        self.link = PanelLink(write, FW_VERSION, uid, now_ms, device_us=device_us)
        self.buttons = (Button(BUTTON_SENSORS), Button(BUTTON_RECORD))
        self.screen_name = SCREEN_BOOT
        self.screen = panel_layout.render_boot(FW_VERSION, self.link.uid)
        self.events = []  # (button, action, event_seq or None) emitted, newest last (kept short)
        self._render_key = None

    def step(self, now_ms, rx=b"", sensors_pressed=False, record_pressed=False):
        """One iteration: feed received bytes, scan buttons, run timers, render. Returns the screen lines."""
        if rx:
            self.link.feed(rx, now_ms)
        for button, pressed in ((self.buttons[0], sensors_pressed), (self.buttons[1], record_pressed)):
            action = button.update(pressed, now_ms)
            if action is not None:
                event_seq = self.link.queue_button(button.button_id, action, now_ms)
                self.events.append((button.button_id, action, event_seq))
                if len(self.events) > 16:
                    self.events.pop(0)
        self.link.poll(now_ms)
        # re-render only when something visible may have changed (state, link status, blink phase, lost seconds)
        lost = self.link.host_lost
        key = (self.link.state_count, lost, self.link.state is None, panel_layout.blink_phase(now_ms),
               self.link.host_silent_ms(now_ms) // 1000 if lost else 0)
        if key != self._render_key:
            self._render_key = key
            self.screen = self.render(now_ms)
        return self.screen

    def render(self, now_ms):
        """The screen for the current state (also sets ``screen_name``)."""
        blink_on = panel_layout.blink_phase(now_ms)
        if self.link.host_lost:
            self.screen_name = SCREEN_HOST_LOST
            return panel_layout.render_host_lost(self.link.host_silent_ms(now_ms), FW_VERSION, blink_on)
        if self.link.state is None:
            self.screen_name = SCREEN_BOOT
            return panel_layout.render_boot(FW_VERSION, self.link.uid)
        self.screen_name = SCREEN_STATUS
        return panel_layout.render_status(self.link.state, blink_on)
