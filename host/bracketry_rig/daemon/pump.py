"""The daemon's event pump: TRIGGER events from the trigger link's listener thread to the open acquisition.

Threads: ``put`` runs on the trigger client's listener thread (never blocks: a full queue counts the event as
dropped); the pump's own thread calls ``deliver`` for each event, one at a time (no lock held while it runs). ``settle``
and ``hold`` are called by whoever closes an acquisition (under the daemon's action lock): ``hold`` returns once no
event is being delivered and keeps delivery paused while its block runs, so the closer can detach the acquisition
and hand it the events still queued itself (nothing is delivered to a half-closed acquisition, nothing is lost).
"""

from __future__ import annotations

import contextlib
import threading
from collections import deque
from collections.abc import Callable, Iterator

from bracketry_rig.events import TriggerEvent

#: events the pump queues at most (about 7 minutes at 22 fps): beyond, each is counted as dropped
QUEUE_MAX_EVENTS = 10_000
#: the longest any of the pump's waits sleeps without looking again (a safety net: every change notifies)
SAFETY_WAKE_S = 1.0


class EventPump:
    """Calls ``deliver(event)`` on its own thread for every event ``put``; ``on_dropped()`` when the queue is full.

    One condition guards the queue and the pump's state (delivering, held, stopped); whoever changes them notifies
    it, so every wait wakes on the change it waits for."""

    def __init__(self, deliver: Callable[[TriggerEvent], None], on_dropped: Callable[[], None], *,
                 max_events: int = QUEUE_MAX_EVENTS) -> None:
        self._deliver = deliver
        self._on_dropped = on_dropped
        self._max_events = max_events
        self._events: deque[TriggerEvent] = deque()
        self._changed = threading.Condition()
        self._delivering = False  # one event is being delivered (outside the condition's lock)
        self._held = False
        self._stop = False
        self._thread: threading.Thread | None = None

    def start(self) -> EventPump:
        self._thread = threading.Thread(target=self._run, name="event-pump", daemon=True)
        self._thread.start()
        return self

    def put(self, event: TriggerEvent) -> None:
        """Queue one event (any thread; never blocks on the pump)."""
        with self._changed:
            full = len(self._events) >= self._max_events
            if not full:
                self._events.append(event)
                self._changed.notify_all()
        if full:
            self._on_dropped()

    def settle(self, timeout_s: float = 2.0) -> None:
        """Wait until the pump delivered every queued event (at most ``timeout_s``)."""
        with self._changed:
            self._changed.wait_for(lambda: not self._events and not self._delivering, timeout=timeout_s)

    @contextlib.contextmanager
    def hold(self) -> Iterator[Callable[[], list[TriggerEvent]]]:
        """Pause delivery; inside the block no event is being delivered, and the yielded function takes the events
        still queued (to be handed over by the caller)."""
        with self._changed:
            while self._delivering or self._held:
                self._changed.wait(SAFETY_WAKE_S)
            self._held = True
        try:
            yield self._take_queued
        finally:
            with self._changed:
                self._held = False
                self._changed.notify_all()

    def _take_queued(self) -> list[TriggerEvent]:
        with self._changed:
            out = list(self._events)
            self._events.clear()
            self._changed.notify_all()
        return out

    def close(self, timeout_s: float = 5.0) -> None:
        """Stop the pump's thread (events still queued are not delivered)."""
        with self._changed:
            self._stop = True
            self._changed.notify_all()
        if self._thread is not None:
            self._thread.join(timeout=timeout_s)
            self._thread = None

    def _run(self) -> None:
        while True:
            with self._changed:
                while not self._stop and (self._held or not self._events):
                    self._changed.wait(SAFETY_WAKE_S)
                if self._stop:
                    return
                ev = self._events.popleft()
                self._delivering = True
            try:
                self._deliver(ev)
            finally:
                with self._changed:
                    self._delivering = False
                    self._changed.notify_all()
