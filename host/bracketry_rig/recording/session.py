"""A recording session: cameras -> pairing -> recorder, plus the 1 Hz rig status.

Threads: each camera's popping thread hands frames to a bounded inbox (overflow counted); one pairing thread feeds
the ``Pairer`` (frames and TRIGGER events) and queues complete or timed-out sets to the ``Recorder``. Trigger events
come from the trigger link's listener (``on_trigger_event``) once the host's side of the pulse
(``bracketry_rig.cameras.triggering.CameraTrigger``) reached the cameras.
"""

from __future__ import annotations

import contextlib
import logging
import math
import queue
import shutil
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from bracketry_base.errors import BracketryError
from bracketry_rig.cameras.triggering import PRIMING_EXPOSURE_US, ExposureReadbacks, TriggerStamps, frame_pulse
from bracketry_rig.events import TriggerEvent
from bracketry_rig.pairing.pairer import PairedSet, Pairer
from bracketry_rig.recording.recorder import Recorder

log = logging.getLogger(__name__)

__all__ = ["PRIMING_EXPOSURE_US", "DiscardSink", "RecordingSession", "SessionStartError"]


class SessionStartError(BracketryError):
    """A camera's stream could not start; ``side`` names the camera."""

    def __init__(self, side: str, message: str) -> None:
        super().__init__(message)
        self.side = side


@dataclass
class DiscardSummary:
    """What a :class:`DiscardSink` took (nothing was written)."""

    sets: int = 0
    events: int = 0
    statuses: int = 0


class DiscardSink:
    """Stands for the ``Recorder`` when nothing is recorded (the monitor's previews while the rig is idle): takes
    sets, events and statuses and writes nothing; a :class:`RecordingSession` with this sink and a ``tap`` feeds
    only the tap."""

    def __init__(self, out_dir: str | Path) -> None:
        self.out_dir = Path(out_dir)
        self.summary = DiscardSummary()
        self.error: str | None = None

    def put_set(self, pset: PairedSet) -> bool:
        self.summary.sets += 1
        return True

    def put_event(self, event: TriggerEvent) -> bool:
        self.summary.events += 1
        return True

    def put_status(self, status: dict[str, Any]) -> bool:
        self.summary.statuses += 1
        return True

    def stop(self) -> DiscardSummary:
        return self.summary


class RecordingSession:
    """Record ``cameras`` (side -> ``GigECamera``, already configured) through ``recorder`` (a ``Recorder``, or a
    :class:`DiscardSink` when the session only feeds its ``tap``).

    Args:
        window: pairing window in pulses (see ``Pairer``); it delays writing after a drop, so it counts in the
            crash-loss budget: 8 pulses = 0.36 s at 22 fps (+ the open chunk, 0.4 s). A camera that is only behind
            (it delivered nothing ``window`` pulses after the set) is waited for up to the Pairer's backstop
            (``max_lag_s``, 1 s): no crash loss of its own, as that camera's frames are not here yet.
        initial_alignment: how the first frame finds its pulse (see ``Pairer``); ``host_time`` for fake cameras.
        status_period_s: rig status period.
        disk_path: folder whose free space goes into the status.
        tap: called on the pairing thread with every paired set after the recorder took it (must not block: the
            monitor's ``PreviewHub.offer``).
    """

    def __init__(self, cameras: dict[str, Any], recorder: Recorder | DiscardSink, *, window: int = 8,
                 status_period_s: float = 1.0, disk_path: str | Path | None = None, inbox_max_items: int = 256,
                 initial_alignment: str = "count", tap: Callable[[PairedSet], None] | None = None) -> None:
        self.cameras = cameras
        self._cameras_at_start = dict(cameras)  # a camera that leaves (daemon) still gets its last frames' read-backs
        self.recorder = recorder
        self.pairer = Pairer(tuple(cameras), self._on_set, window=window, initial_alignment=initial_alignment)
        self.status_period_s = status_period_s
        self.disk_path = Path(disk_path) if disk_path else recorder.out_dir
        self.inbox_overflows = 0
        self._inbox: queue.Queue[tuple[str, Any]] = queue.Queue(maxsize=inbox_max_items)
        self._thread: threading.Thread | None = None
        self._fps_marks: dict[str, tuple[float, int]] = {}
        self.frames_received: dict[str, int] = {}
        self._lock = threading.Lock()
        self._frame_arrived = threading.Condition(self._lock)  # notified with every frame (stop's drain waits on it)
        self.tap = tap
        #: the latest rig status (RigStatus fields), for readers outside the pairing thread
        self.last_status: dict[str, Any] = {}
        self._lost_at_start: dict[str, int | None] = {}  # each camera's lost-trigger count when the session started

    def start(self) -> RecordingSession:
        """Start pairing and every camera's stream.

        Raises:
            SessionStartError: a camera could not stream (``.side`` names it); the cameras already started are
                stopped again and the pairing thread ends; the recorder is left to the caller.
        """
        self._thread = threading.Thread(target=self._run, name="pairing", daemon=True)
        self._thread.start()
        started: list[Any] = []
        for side, cam in self.cameras.items():
            try:
                cam.start(self._on_frame)
            except Exception as exc:
                for other in started:
                    with contextlib.suppress(Exception):
                        other.stop()
                self._inbox.put(("stop", None))
                self._thread.join(timeout=30)
                self._thread = None
                raise SessionStartError(side, str(exc)) from exc
            started.append(cam)
        self._lost_at_start = {side: self._read_lost_triggers(cam) for side, cam in self.cameras.items()}
        return self

    @staticmethod
    def _read_lost_triggers(cam: Any) -> int | None:
        """The camera's count of software triggers it lost (``GigECamera.read_lost_triggers``), None without one."""
        read = getattr(cam, "read_lost_triggers", None)
        return read() if read is not None else None

    def _on_frame(self, frame: Any) -> None:
        with self._lock:
            self.frames_received[frame.side] = self.frames_received.get(frame.side, 0) + 1
            self._frame_arrived.notify_all()
        try:
            self._inbox.put_nowait(("frame", frame))
        except queue.Full:
            with self._lock:
                self.inbox_overflows += 1
            log.error("pairing inbox full: frame id %d of camera %s dropped", frame.frame_id, frame.side)

    def received(self) -> dict[str, int]:
        """Frames each camera delivered so far (counted on arrival, before pairing; priming frames included)."""
        with self._lock:
            return {side: self.frames_received.get(side, 0) for side in self._cameras_at_start}

    def on_trigger_event(self, event: TriggerEvent) -> None:
        """A TRIGGER event from the trigger device (any thread)."""
        self.recorder.put_event(event)
        try:
            self._inbox.put_nowait(("event", event))
        except queue.Full:
            with self._lock:
                self.inbox_overflows += 1
            log.error("pairing inbox full: trigger event %d dropped", event.trigger_seq)

    def _on_set(self, pset: PairedSet) -> None:
        self._attach_register_exposures(pset)
        self.recorder.put_set(pset)
        if self.tap is not None:  # after the recorder: a monitor sees frames already received, never first
            try:
                self.tap(pset)
            except Exception:
                log.exception("session tap failed")

    def _attach_register_exposures(self, pset: PairedSet) -> None:
        """Each frame of ``pset`` gets its camera's exposure register as read back at this pulse's software trigger
        (``frame.exposure_us_register``, from the camera's ``exposure_readbacks``, empty for cameras on trigger
        lines): the recorder writes it as the frame's read-back exposure when the camera sent no chunk."""
        for side, frame in pset.frames.items():
            readbacks = getattr(self._cameras_at_start.get(side), "exposure_readbacks", None)
            if frame is None or not isinstance(readbacks, ExposureReadbacks):
                continue
            value = readbacks.get(pset.trigger_seq)
            if value is not None:
                try:
                    frame.exposure_us_register = value
                except AttributeError:  # a frame type without the field: no read-back for it
                    continue

    def _mark_pulse(self, frame: Any) -> None:
        """``frame.trigger_seq`` from its own trigger stamp, when its camera keeps ``trigger_stamps`` and the stamp
        shows one (``bracketry_rig.cameras.triggering.frame_pulse``): the pairer then takes that pulse as it is."""
        stamps = getattr(self._cameras_at_start.get(frame.side), "trigger_stamps", None)
        if not isinstance(stamps, TriggerStamps):
            return
        seq = frame_pulse(frame, stamps)
        if seq is not None:
            with contextlib.suppress(AttributeError):  # a frame type without the field: placed by the pairer's checks
                frame.trigger_seq = seq

    def _run(self) -> None:
        next_status = time.monotonic() + self.status_period_s
        while True:
            try:
                kind, item = self._inbox.get(timeout=0.05)
            except queue.Empty:
                kind, item = "idle", None
            if kind == "frame":
                self._mark_pulse(item)
                self.pairer.add_frame(item)
            elif kind == "event":
                self.pairer.add_event(item)
            elif kind == "stop":
                self.pairer.flush()
                return
            if time.monotonic() >= next_status:
                next_status += self.status_period_s
                self.recorder.put_status(self.status())

    def status(self) -> dict[str, Any]:
        """The rig status (RigStatus fields)."""
        now = time.monotonic()
        out: dict[str, Any] = {"t_ns": time.time_ns()}
        unpaired = 0
        for side, cam in self.cameras.items():
            c = self.pairer.counters[side]
            t0, n0 = self._fps_marks.get(side, (now, c.frames))
            out[f"fps_{side}"] = (c.frames - n0) / (now - t0) if now > t0 else math.nan
            self._fps_marks[side] = (now, c.frames)
            out[f"frames_{side}"] = c.frames
            out[f"drops_{side}"] = c.drops
            out[f"incomplete_{side}"] = c.incomplete
            out[f"missing_packets_{side}"] = c.missing_packets
            lost, lost_then = self._read_lost_triggers(cam), self._lost_at_start.get(side)
            out[f"lost_triggers_{side}"] = max(0, lost - lost_then) if lost is not None and lost_then is not None else 0
            temperature = cam.read_temperature_c() if hasattr(cam, "read_temperature_c") else None
            out[f"temperature_{side}_c"] = math.nan if temperature is None else temperature
            unpaired += c.unpaired
        out["unpaired"] = unpaired
        try:
            out["free_disk_mb"] = shutil.disk_usage(self.disk_path).free // (1 << 20)
        except OSError:
            out["free_disk_mb"] = 0
        self.last_status = out
        return out

    def stop(self, drain_s: float = 0.5, expect_frames: int | dict[str, int] | None = None) -> dict[str, Any]:
        """Let in-flight frames arrive, stop cameras, flush pairing, finish the recording.

        Waits ``drain_s``, or, with ``expect_frames`` (buffers each camera will deliver: one number, or one per side,
        e.g. pulses fired plus a priming frame), until every camera delivered that many or ``drain_s`` passed
        without any new one.
        """
        deadline = time.monotonic() + drain_s
        last = -1
        want = (expect_frames if isinstance(expect_frames, dict) else dict.fromkeys(self.cameras, expect_frames)
                if expect_frames is not None else None)
        with self._frame_arrived:  # woken by every frame, not polled
            while True:
                counts = [self.frames_received.get(s, 0) for s in self.cameras]
                if want is not None and all(self.frames_received.get(s, 0) >= want.get(s, 0) for s in self.cameras):
                    break
                now = time.monotonic()
                if sum(counts) != last:
                    last = sum(counts)
                    deadline = now + drain_s if expect_frames is not None else deadline
                if now >= deadline:
                    break
                self._frame_arrived.wait(deadline - now)
        for cam in self.cameras.values():
            cam.stop()
        if self._thread is not None:
            self._inbox.put(("stop", None))
            self._thread.join(timeout=30)
            self._thread = None
        status = self.status()
        self.recorder.put_status(status)
        summary = self.recorder.stop()
        return {"pairing": self.pairer.summary(), "inbox_overflows": self.inbox_overflows,
                "lost_triggers": {s: int(status.get(f"lost_triggers_{s}", 0)) for s in self.cameras},
                "recorder": vars(summary), "streams": {s: c.stats().as_dict() for s, c in self.cameras.items()}}
