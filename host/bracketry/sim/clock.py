"""The time the simulated rig's decisions are made on: the real monotonic clock, or, in tests, a clock that moves only
when the code under test waits on it (so a test drives time and asserts on decisions, never on how long it took)."""

from __future__ import annotations

import time
from typing import Protocol


class Clock(Protocol):
    """Seconds on a monotonic scale, and a wait of some seconds on that scale."""

    def now_s(self) -> float: ...

    def sleep(self, seconds: float) -> None: ...


class MonotonicClock:
    """The real clock: ``time.monotonic()`` and ``time.sleep``."""

    def now_s(self) -> float:
        return time.monotonic()

    def sleep(self, seconds: float) -> None:
        time.sleep(seconds)


#: the production clock
MONOTONIC: Clock = MonotonicClock()


class SteppedClock:
    """A clock that stands still until slept on: ``sleep(s)`` moves it ``s`` on at once (in whole microseconds, so a
    sum of steps is exact); ``slept`` lists the waits asked for."""

    def __init__(self, start_s: float = 0.0) -> None:
        self._us = round(start_s * 1e6)
        self.slept: list[float] = []

    def now_s(self) -> float:
        return self._us / 1e6

    def sleep(self, seconds: float) -> None:
        self.slept.append(seconds)
        self._us += max(0, round(seconds * 1e6))
