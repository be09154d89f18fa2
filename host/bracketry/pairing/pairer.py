"""Match frames of both cameras and TRIGGER events by trigger sequence; count and log every problem.

Model: both cameras are armed before START, so the k-th frame since START on each camera belongs to pulse
``trigger_seq = k``. A camera's frame number is its unwrapped GVSP frame index (``Frame.frame_index``), which also
advances over frames the camera sent but we never received, so a lost frame does not shift later ones.

Cross-check with timestamps: on a camera, the camera-clock time between two frames must equal the device-clock time
between their pulses (within ``tolerance_fraction`` of the period). When it does not (a missed trigger, a camera
reset), the frame is re-assigned to the pulse whose time matches, later frames follow the new offset, and the frame
is noted ``timestamp_mismatch``; the skipped pulses then show up as drops.

A trigger_seq is emitted (``PairedSet``) as soon as the event and every camera's frame are there, or when it falls
``window`` pulses behind the newest one seen (then with what is missing counted), or at ``flush()``.
"""

from __future__ import annotations

import logging
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

from bracketry.events import TriggerEvent

log = logging.getLogger(__name__)


@dataclass
class PairedSet:
    """Everything received for one trigger_seq.

    Attributes:
        trigger_seq: the pulse number.
        event: the TRIGGER event, or None when it was lost.
        frames: side -> frame (``bracketry.cameras.camera.Frame`` or any object with the same fields) or None.
        stamp_ns: frame time = the event's host time (``t_start_host_ns``), else the earliest host receive time.
        notes: side -> remark (``timestamp_mismatch``, ``late``), empty when none.
    """

    trigger_seq: int
    event: TriggerEvent | None
    frames: dict[str, Any]
    stamp_ns: int
    notes: dict[str, str] = field(default_factory=dict)

    @property
    def complete(self) -> bool:
        return self.event is not None and all(f is not None for f in self.frames.values())


@dataclass
class SideCounters:
    frames: int = 0
    drops: int = 0
    incomplete: int = 0
    unpaired: int = 0
    timestamp_mismatches: int = 0
    missing_packets: int = 0
    late: int = 0


@dataclass
class _SideState:
    offset: int | None = None  # trigger_seq = frame_index + offset
    ref_seq: int | None = None
    ref_cam_ns: int | None = None


class Pairer:
    """Pairs frames of ``sides`` with TRIGGER events. Not thread-safe: feed it from one thread.

    Args:
        sides: camera names.
        on_set: called with each emitted ``PairedSet`` (in trigger_seq order per call of ``add_*``/``flush``).
        window: a trigger_seq is emitted incomplete once it is this many pulses behind the newest seen.
        tolerance_fraction: allowed timestamp disagreement as a fraction of the pulse period.
    """

    def __init__(self, sides: tuple[str, ...] = ("left", "right"), on_set: Callable[[PairedSet], None] | None = None,
                 *, window: int = 16, tolerance_fraction: float = 0.4) -> None:
        self.sides = sides
        self.on_set = on_set or (lambda _s: None)
        self.window = window
        self.tolerance_fraction = tolerance_fraction
        self.counters = {s: SideCounters() for s in sides}
        self.events_received = 0
        self.events_missing = 0
        self.sets_emitted = 0
        self.sets_complete = 0
        self._events: dict[int, TriggerEvent] = {}
        self._pending: dict[int, dict[str, Any]] = {}
        self._notes: dict[int, dict[str, str]] = {}
        self._emitted_upto = -1  # every seq <= this is emitted
        self._newest = -1
        self._last_event_seq: int | None = None
        self._state = {s: _SideState() for s in sides}
        self._period_us: float | None = None

    # -- input ----------------------------------------------------------------------------------------------------
    def add_event(self, event: TriggerEvent) -> None:
        """A TRIGGER event (in any order; duplicates are ignored)."""
        seq = event.trigger_seq
        if seq in self._events or (seq <= self._emitted_upto and seq not in self._pending):
            return
        self.events_received += 1
        if self._last_event_seq is not None:
            if seq > self._last_event_seq + 1:
                gap = seq - self._last_event_seq - 1
                self.events_missing += gap
                log.warning("trigger events %d..%d missing (%d)", self._last_event_seq + 1, seq - 1, gap)
            prev = self._events.get(self._last_event_seq)
            if prev is not None and seq > prev.trigger_seq:
                period = (event.t_start_device_us - prev.t_start_device_us) / (seq - prev.trigger_seq)
                if period > 0:
                    self._period_us = period if self._period_us is None else 0.9 * self._period_us + 0.1 * period
        self._last_event_seq = max(seq, self._last_event_seq or 0)
        self._events[seq] = event
        self._touch(seq)

    def add_frame(self, frame: Any) -> int:
        """A camera frame; returns the trigger_seq it was assigned to."""
        side = frame.side
        st = self._state[side]
        c = self.counters[side]
        c.frames += 1
        c.missing_packets += int(getattr(frame, "missing_packets", 0) or 0)
        if frame.status != "success":
            c.incomplete += 1
            log.warning("camera %s: frame id %d incomplete (%s)", side, frame.frame_id, frame.status)
        if st.offset is None:
            st.offset = -frame.frame_index
        seq = frame.frame_index + st.offset
        note = ""
        checked = self._check_time(side, seq, frame)
        if checked is not None and checked != seq:
            log.warning("camera %s: frame id %d timestamps say trigger_seq %d, frame count says %d: re-synced",
                        side, frame.frame_id, checked, seq)
            st.offset += checked - seq
            seq = checked
            c.timestamp_mismatches += 1
            note = "timestamp_mismatch"
        if seq in self._events:
            st.ref_seq, st.ref_cam_ns = seq, frame.cam_timestamp_ns
        if seq <= self._emitted_upto and seq not in self._pending:
            c.late += 1
            c.unpaired += 1
            log.warning("camera %s: frame for trigger_seq %d arrived after its set was emitted", side, seq)
            self._emit_single(seq, side, frame, "late")
            return seq
        slot = self._pending.setdefault(seq, {})
        if side in slot:
            log.warning("camera %s: second frame for trigger_seq %d (frame id %d)", side, seq, frame.frame_id)
            c.unpaired += 1
            self._emit_single(seq, side, frame, "duplicate")
            return seq
        slot[side] = frame
        if note:
            self._notes.setdefault(seq, {})[side] = note
        self._touch(seq)
        return seq

    def _check_time(self, side: str, seq: int, frame: Any) -> int | None:
        """The trigger_seq the camera timestamp points at, or None when it cannot be checked."""
        st = self._state[side]
        if st.ref_seq is None or st.ref_cam_ns is None or self._period_us is None:
            return None
        ref_ev = self._events.get(st.ref_seq)
        if ref_ev is None:
            return None
        dt_us = (frame.cam_timestamp_ns - st.ref_cam_ns) / 1000.0
        target_us = ref_ev.t_start_device_us + dt_us
        tol_us = self.tolerance_fraction * self._period_us
        ev = self._events.get(seq)
        if ev is not None:
            if abs(ev.t_start_device_us - target_us) <= tol_us:
                return seq
        else:
            predicted = st.ref_seq + dt_us / self._period_us
            if abs(predicted - seq) <= self.tolerance_fraction:
                return seq
        best = min(self._events.values(), key=lambda e: abs(e.t_start_device_us - target_us))
        if abs(best.t_start_device_us - target_us) <= tol_us:
            return best.trigger_seq
        return None

    # -- output ---------------------------------------------------------------------------------------------------
    def _touch(self, seq: int) -> None:
        self._newest = max(self._newest, seq)
        self._pending.setdefault(seq, {})
        self._release()

    def _ready(self, seq: int) -> bool:
        slot = self._pending.get(seq, {})
        return seq in self._events and all(s in slot for s in self.sides)

    def _release(self, everything: bool = False) -> None:
        while True:
            nxt = self._emitted_upto + 1
            if nxt > self._newest:
                return
            if not (everything or self._ready(nxt) or nxt <= self._newest - self.window):
                # complete sets further on wait for this one (ordered output), unless it is hopeless
                return
            self._emit(nxt)

    def _emit(self, seq: int) -> None:
        slot = self._pending.pop(seq, {})
        event = self._events.get(seq)
        frames = {s: slot.get(s) for s in self.sides}
        notes = self._notes.pop(seq, {})
        self._emitted_upto = seq
        received = [f for f in frames.values() if f is not None]
        if event is None and not received:
            return  # nothing at all for this seq (e.g. before the first event): not a set
        for s, f in frames.items():
            if f is None:
                self.counters[s].drops += 1
                log.warning("camera %s: no frame for trigger_seq %d", s, seq)
            elif event is None or len(received) < len(self.sides):
                self.counters[s].unpaired += 1
        if event is None:
            log.warning("trigger_seq %d: frames without a TRIGGER event", seq)
        stamp = event.t_start_host_ns if event is not None and event.t_start_host_ns is not None else \
            min((f.host_receive_ns for f in received), default=0)
        pset = PairedSet(seq, event, frames, stamp, notes)
        self.sets_emitted += 1
        self.sets_complete += pset.complete
        self._forget_old()
        self.on_set(pset)

    def _emit_single(self, seq: int, side: str, frame: Any, note: str) -> None:
        event = self._events.get(seq)
        frames = {s: (frame if s == side else None) for s in self.sides}
        stamp = event.t_start_host_ns if event is not None and event.t_start_host_ns is not None else \
            frame.host_receive_ns
        self.on_set(PairedSet(seq, event, frames, stamp, {side: note}))

    def _forget_old(self) -> None:
        keep_from = self._emitted_upto - 4 * self.window
        refs = {st.ref_seq for st in self._state.values()}
        for seq in [s for s in self._events if s < keep_from and s not in refs]:
            del self._events[seq]

    def flush(self) -> None:
        """Emit everything pending (call at STOP)."""
        self._release(everything=True)

    def summary(self) -> dict[str, Any]:
        return {"events_received": self.events_received, "events_missing": self.events_missing,
                "sets_emitted": self.sets_emitted, "sets_complete": self.sets_complete,
                "sides": {s: vars(c).copy() for s, c in self.counters.items()}}
