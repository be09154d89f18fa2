"""Per-sensor states and the daemon's state snapshot (what the panel shows and `bracketry status` prints)."""

from __future__ import annotations

import enum
import threading
import time
from dataclasses import asdict, dataclass, field
from typing import Any


class SensorState(enum.IntEnum):
    """A sensor's state; the values are the wire protocol's PANEL_STATE codes."""

    OFF = 0
    IDLE = 1
    REC = 2
    ERR = 3
    CAL = 4


#: the panel's sensor slots, in PANEL_STATE order
SENSORS = ("cam_left", "cam_right", "trigger", "imu", "lidar", "gnss")


@dataclass
class RigSnapshot:
    """A consistent copy of the daemon's state.

    ``states`` maps each of :data:`SENSORS` to a :class:`SensorState`; ``fps`` per camera side (frames/s over the
    last second); ``free_disk_mb`` of the output directory's filesystem; ``rec_seconds`` since RECORD (0 when idle);
    ``message`` the panel's 20-character line; ``counters`` frames/drops/etc.; ``recording`` the open file or None.
    """

    states: dict[str, SensorState]
    fps: dict[str, float]
    free_disk_mb: int
    rec_seconds: int
    message: str
    counters: dict[str, int]
    recording: str | None
    errors: dict[str, str] = field(default_factory=dict)
    time_ns: int = 0

    def to_json(self) -> dict[str, Any]:
        """JSON-friendly dict (state names instead of numbers)."""
        d = asdict(self)
        d["states"] = {k: SensorState(v).name for k, v in self.states.items()}
        return d


class RigState:
    """Thread-safe state store shared by the daemon's threads."""

    def __init__(self) -> None:
        self._lock = threading.Lock()
        self._states = {name: SensorState.OFF for name in SENSORS}
        self._fps = {"left": 0.0, "right": 0.0}
        self._free_disk_mb = 0
        self._rec_started: float | None = None
        self._message = "READY"
        self._counters: dict[str, int] = {}
        self._recording: str | None = None
        self._errors: dict[str, str] = {}

    def set_state(self, sensor: str, state: SensorState, error: str | None = None) -> None:
        """Set one sensor's state; ``error`` (for ERR) is kept for ``bracketry status``."""
        if sensor not in self._states:
            raise KeyError(sensor)
        with self._lock:
            self._states[sensor] = state
            if state == SensorState.ERR and error:
                self._errors[sensor] = error
            elif state != SensorState.ERR:
                self._errors.pop(sensor, None)

    def state(self, sensor: str) -> SensorState:
        with self._lock:
            return self._states[sensor]

    def set_fps(self, side: str, fps: float) -> None:
        with self._lock:
            self._fps[side] = fps

    def set_free_disk_mb(self, mb: int) -> None:
        with self._lock:
            self._free_disk_mb = mb

    def set_message(self, text: str) -> None:
        """The panel's message line (truncated to 20 characters)."""
        with self._lock:
            self._message = text[:20]

    def set_recording(self, path: str | None) -> None:
        """Mark recording started (path) or stopped (None)."""
        with self._lock:
            self._recording = path
            self._rec_started = time.monotonic() if path else None

    def count(self, name: str, n: int = 1) -> None:
        with self._lock:
            self._counters[name] = self._counters.get(name, 0) + n

    def snapshot(self) -> RigSnapshot:
        with self._lock:
            rec_s = int(time.monotonic() - self._rec_started) if self._rec_started is not None else 0
            return RigSnapshot(dict(self._states), dict(self._fps), self._free_disk_mb, rec_s, self._message,
                               dict(self._counters), self._recording, dict(self._errors), time.time_ns())
