"""Millisecond/microsecond tick helpers with MicroPython semantics, also under CPython.

On MicroPython this re-exports ``time.ticks_ms`` & co. Under CPython (simulator, tests) it provides equivalents with
the same wrap-around period (2**30 ms), so the core modules can use ``ticks_diff`` everywhere.
"""

import time as _time

TICKS_PERIOD = 1 << 30
_TICKS_HALF = TICKS_PERIOD // 2

try:
    ticks_ms = _time.ticks_ms  # type: ignore[attr-defined]
    ticks_us = _time.ticks_us  # type: ignore[attr-defined]
    ticks_diff = _time.ticks_diff  # type: ignore[attr-defined]
    ticks_add = _time.ticks_add  # type: ignore[attr-defined]
    sleep_ms = _time.sleep_ms  # type: ignore[attr-defined]
    sleep_us = _time.sleep_us  # type: ignore[attr-defined]
except AttributeError:
    _T0 = _time.monotonic()

    def ticks_ms():
        """Milliseconds since start, wrapping at 2**30 (int)."""
        return int((_time.monotonic() - _T0) * 1000) & (TICKS_PERIOD - 1)

    def ticks_us():
        """Microseconds since start, wrapping at 2**30 (int)."""
        return int((_time.monotonic() - _T0) * 1000000) & (TICKS_PERIOD - 1)

    def ticks_diff(a, b):
        """Signed difference a - b of two tick values, correct across one wrap (int)."""
        return ((a - b + _TICKS_HALF) & (TICKS_PERIOD - 1)) - _TICKS_HALF

    def ticks_add(a, delta):
        """Tick value ``a`` advanced by ``delta`` (wrapping)."""
        return (a + delta) & (TICKS_PERIOD - 1)

    def sleep_ms(n):
        """Sleep ``n`` milliseconds."""
        _time.sleep(n / 1000.0)

    def sleep_us(n):
        """Sleep ``n`` microseconds (CPython: at least that long, usually more)."""
        if n >= 1000:
            _time.sleep(n / 1000000.0)


class MicrosClock:
    """A 64-bit microsecond clock built from the wrapping ``ticks_us``: call ``now_us()`` at least every 8 minutes."""

    def __init__(self, ticks_us_fn=None):
        self._ticks_us = ticks_us_fn if ticks_us_fn is not None else ticks_us
        self._last = self._ticks_us()
        self._total_us = 0

    def now_us(self):
        """Microseconds since this clock was created (int, never wraps)."""
        t = self._ticks_us()
        self._total_us += ticks_diff(t, self._last)
        self._last = t
        return self._total_us
