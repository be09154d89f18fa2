"""Push-button debounce and long-press detection (pure logic; time is passed in as tick milliseconds).

A raw level change is accepted once it has been stable for ``debounce_ms`` (20-50 ms). An accepted press held for
``long_ms`` emits one LONG event while still held; releasing before that emits one SHORT event on release; releasing
after a LONG emits nothing.
"""

from panel_clock import ticks_diff

BUTTON_SENSORS = 1
BUTTON_RECORD = 2
ACTION_SHORT = 1
ACTION_LONG = 2
DEBOUNCE_MS = 30
LONG_MS = 1000


class Button:
    """One debounced button. ``update(pressed, now_ms)`` returns ACTION_SHORT, ACTION_LONG or None."""

    def __init__(self, button_id, debounce_ms=DEBOUNCE_MS, long_ms=LONG_MS):
        self.button_id = button_id
        self.debounce_ms = debounce_ms
        self.long_ms = long_ms
        self.pressed = False  # debounced level
        self._raw = False
        self._raw_since_ms = None
        self._press_ms = 0
        self._long_sent = False

    def update(self, raw_pressed, now_ms):
        """Feed the current raw level (True = pressed) at ``now_ms``; returns the action emitted now, or None."""
        raw_pressed = bool(raw_pressed)
        if self._raw_since_ms is None or raw_pressed != self._raw:
            self._raw = raw_pressed
            self._raw_since_ms = now_ms
        stable = ticks_diff(now_ms, self._raw_since_ms) >= self.debounce_ms
        if stable and self._raw != self.pressed:
            self.pressed = self._raw
            if self.pressed:
                self._press_ms = now_ms
                self._long_sent = False
            else:
                if not self._long_sent:
                    return ACTION_SHORT
                return None
        if self.pressed and not self._long_sent and ticks_diff(now_ms, self._press_ms) >= self.long_ms:
            self._long_sent = True
            return ACTION_LONG
        return None
