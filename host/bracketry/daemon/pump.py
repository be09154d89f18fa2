"""The daemon's event pump: TRIGGER events from the trigger link's listener thread to the open acquisition.

Threads: ``put`` runs on the trigger client's listener thread (never blocks: a full queue counts the event as
dropped); the pump's own thread calls ``deliver`` for each event, one at a time, holding the pump's lock. ``settle``
and ``hold`` are called by whoever closes an acquisition (under the daemon's action lock): ``hold`` returns once no
event is being delivered and keeps delivery paused while its block runs, so the closer can detach the acquisition
and hand it the events still queued itself (nothing is delivered to a half-closed acquisition, nothing is lost).
"""

from __future__ import annotations

import contextlib
import queue
import threading
import time
from collections.abc import Callable, Iterator

from bracketry.events import TriggerEvent

#: events the pump queues at most (about 7 minutes at 22 fps): beyond, each is counted as dropped
QUEUE_MAX_EVENTS = 10_000


class EventPump:
    """Calls ``deliver(event)`` on its own thread for every event ``put``; ``on_dropped()`` when the queue is full."""

    def __init__(self, deliver: Callable[[TriggerEvent], None], on_dropped: Callable[[], None], *,
                 max_events: int = QUEUE_MAX_EVENTS) -> None:
        self._deliver = deliver
        self._on_dropped = on_dropped
        self._events: queue.Queue[TriggerEvent | None] = queue.Queue(maxsize=max_events)
        self._lock = threading.Lock()  # held while one event is delivered
        self._paused = threading.Event()
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None

    def start(self) -> EventPump:
        self._thread = threading.Thread(target=self._run, name="event-pump", daemon=True)
        self._thread.start()
        return self

    def put(self, event: TriggerEvent) -> None:
        """Queue one event (any thread; never blocks)."""
        try:
            self._events.put_nowait(event)
        except queue.Full:
            self._on_dropped()

    def settle(self, timeout_s: float = 2.0) -> None:
        """Wait until the pump delivered every queued event (at most ``timeout_s``)."""
        deadline = time.monotonic() + timeout_s
        while not self._events.empty() and time.monotonic() < deadline:
            time.sleep(0.02)

    @contextlib.contextmanager
    def hold(self) -> Iterator[Callable[[], list[TriggerEvent]]]:
        """Pause delivery; inside the block no event is being delivered, and the yielded function takes the events
        still queued (to be handed over by the caller)."""
        self._paused.set()
        try:
            with self._lock:
                yield self._take_queued
        finally:
            self._paused.clear()

    def _take_queued(self) -> list[TriggerEvent]:
        out: list[TriggerEvent] = []
        while True:
            try:
                ev = self._events.get_nowait()
            except queue.Empty:
                return out
            if ev is not None:
                out.append(ev)

    def close(self, timeout_s: float = 5.0) -> None:
        """Stop the pump's thread (events still queued are not delivered)."""
        self._stop.set()
        with contextlib.suppress(queue.Full):
            self._events.put_nowait(None)
        if self._thread is not None:
            self._thread.join(timeout=timeout_s)
            self._thread = None

    def _run(self) -> None:
        while not self._stop.is_set():
            if self._paused.is_set():
                time.sleep(0.01)
                continue
            with self._lock:
                try:
                    ev = self._events.get(timeout=0.05)
                except queue.Empty:
                    continue
                if ev is None:
                    return
                self._deliver(ev)
