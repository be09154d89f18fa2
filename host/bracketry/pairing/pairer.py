"""Match frames of both cameras and TRIGGER events by trigger sequence; count and log every problem.

Model: both cameras are armed before START, so the k-th frame since START on each camera belongs to pulse
``trigger_seq = k``. A camera's frame number is its unwrapped GVSP frame index (``Frame.frame_index``), which also
advances over frames the camera sent but we never received, so a lost frame does not shift later ones.

Cross-check with timestamps: on a camera, ``cam_timestamp - pulse device time`` is constant up to clock drift and
jitter. Its running median over the last accepted frames is the reference. A frame whose offset differs from it by a
whole number ``m != 0`` of periods (within ``tolerance_fraction`` of a period) is a candidate shift (the camera missed
or invented ``m`` pulses); once ``confirm_frames`` consecutive frames agree, those frames move to ``seq + m``, later
frames follow, the first moved frame is noted ``timestamp_mismatch`` and the skipped pulses show up as drops. A
single late frame (host scheduling, a jittery fake camera) never moves anything. Sets touched by an unconfirmed
candidate are held back until it is confirmed or dropped.

Cameras fired by the host (``initial_alignment="host_time"``: the fake camera, whose timestamps are host time) are
checked against host times instead. Such a camera gives one frame per trigger it takes, never before its pulse, but
as late as the host's scheduling makes it: on a loaded machine whole bursts of frames of both cameras come one to
many periods late, a session's first frames included, so lateness alone proves nothing (a running reference would
learn it and re-sync a whole camera wrongly). A frame stamped before its pulse proves a frame for no pulse
(``confirm_frames`` of them move back); a camera whose frames come whole periods later than the other cameras'
frames of the same pulses (twice ``confirm_frames`` in a row) missed a pulse. The smallest such ``m`` is the shift.

A trigger_seq is emitted (``PairedSet``) as soon as the event and every camera's frame are there, or when it falls
``window`` pulses behind the newest one seen (then with what is missing counted), or at ``flush()``.
"""

from __future__ import annotations

import logging
import math
import statistics
from collections import deque
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
    before_start: int = 0


@dataclass
class _SideState:
    offset: int | None = None  # trigger_seq = frame_index + offset
    offsets: deque = field(default_factory=lambda: deque(maxlen=15))  # cam ns - device ns of accepted frames
    candidate: list[int] = field(default_factory=list)  # seqs of frames agreeing on a shift
    candidate_shift: int = 0
    recent: dict[int, int] = field(default_factory=dict)  # seq -> offset of recent frames (accepted or not)
    waiting: list = field(default_factory=list)  # frames before any event (host_time alignment)
    last_ok_seq: int | None = None  # last frame whose timestamp agreed with its pulse
    stamps: dict[int, int] = field(default_factory=dict)  # seq -> camera timestamp (host-fired cameras)
    newest_seq: int = -1  # newest trigger_seq a frame of this side was assigned

    def drop_candidate(self, side: str | None = None, seq: int | None = None) -> None:
        """Forget the shift candidate; with ``side`` and ``seq``, log that a pending one was dropped at ``seq``."""
        if self.candidate and side is not None:
            log.info("camera %s: timestamp shift candidate dropped at trigger_seq %d", side, seq)
        self.candidate = []
        self.candidate_shift = 0


class Pairer:
    """Pairs frames of ``sides`` with TRIGGER events. Not thread-safe: feed it from one thread.

    Args:
        sides: camera names.
        on_set: called with each emitted ``PairedSet`` (in trigger_seq order per call of ``add_*``/``flush``).
        window: a trigger_seq is emitted incomplete once it is this many pulses behind the newest seen.
        tolerance_fraction: allowed timestamp disagreement as a fraction of the pulse period.
        confirm_frames: consecutive frames that must agree on a shift before frames are moved.
        initial_alignment: ``count`` (first frame = pulse 0), ``counter`` or ``host_time`` (see ``_initial_seq``).
    """

    def __init__(self, sides: tuple[str, ...] = ("left", "right"), on_set: Callable[[PairedSet], None] | None = None,
                 *, window: int = 16, tolerance_fraction: float = 0.3, confirm_frames: int = 3,
                 initial_alignment: str = "count") -> None:
        self.sides = sides
        self.on_set = on_set or (lambda _s: None)
        self.window = window
        self.tolerance_fraction = tolerance_fraction
        self.confirm_frames = confirm_frames
        self.initial_alignment = initial_alignment
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
        for st in self._state.values():
            waiting, st.waiting = st.waiting, []
            for frame in waiting:
                self.add_frame(frame)

    def add_frame(self, frame: Any) -> int:
        """A camera frame; returns the trigger_seq it was assigned to (may move later on a confirmed shift)."""
        side = frame.side
        st = self._state[side]
        c = self.counters[side]
        if st.offset is None and self.initial_alignment == "host_time" and not self._events:
            st.waiting.append(frame)  # aligned when the first TRIGGER event arrives
            return -1
        c.frames += 1
        c.missing_packets += int(getattr(frame, "missing_packets", 0) or 0)
        if frame.status != "success":
            c.incomplete += 1
        if st.offset is None:
            first = self._initial_seq(frame)
            if first is None:
                c.frames -= 1
                c.before_start += 1
                log.warning("camera %s: frame id %d precedes every trigger pulse: ignored", side, frame.frame_id)
                return -1
            st.offset = first - frame.frame_index
        seq = frame.frame_index + st.offset
        if frame.status != "success":
            log.warning("camera %s: frame for trigger_seq %d (frame id %d) incomplete (%s)", side, seq,
                        frame.frame_id, frame.status)
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
        seq = self._check_time(side, seq, frame)
        st.newest_seq = max(st.newest_seq, seq)
        self._touch(seq)
        return seq

    def _initial_seq(self, frame: Any) -> int | None:
        """trigger_seq of a camera's first frame.

        With ``initial_alignment="counter"`` the CounterValue chunk is authoritative (for cameras whose Counter1 is
        configured to count trigger pulses and reset at START, first pulse = 1; the shipped camera profiles do not
        configure it, so the chunk is only recorded by default). With ``initial_alignment="host_time"`` (cameras
        whose timestamps are host time, like the Aravis fake camera) it is the latest pulse that started before the
        frame's timestamp (a first frame late by whole periods is moved back by the frames after it, stamped before
        their pulses), and None (frame ignored: the priming trigger's) when none did. Otherwise the first frame is
        pulse 0 (k-th frame since START).
        """
        counter = getattr(frame, "counter_value", None)
        if self.initial_alignment == "counter" and counter is not None and counter > 0:
            return int(counter) - 1
        if self.initial_alignment == "host_time":
            started = [e.trigger_seq for e in self._events.values()
                       if e.t_start_host_ns is not None and e.t_start_host_ns <= frame.cam_timestamp_ns]
            return max(started) if started else None
        return 0

    def _check_time(self, side: str, seq: int, frame: Any) -> int:
        """Timestamp cross-check (see module doc); returns the frame's (possibly moved) trigger_seq."""
        st = self._state[side]
        if self._period_us is None or not self._events or not frame.cam_timestamp_ns:
            return seq  # an incomplete buffer whose leader was lost carries no timestamp
        period_ns = self._period_us * 1000.0
        if self.initial_alignment == "host_time":
            host_ns = self._pulse_host_ns(seq)
            if host_ns is not None:
                return self._check_host_time(side, seq, frame.cam_timestamp_ns, host_ns, period_ns)
        offset = frame.cam_timestamp_ns - self._pulse_device_ns(seq)
        st.recent[seq] = offset
        if len(st.recent) > 64:
            del st.recent[min(st.recent)]
        if not st.offsets:
            st.offsets.append(offset)
            st.last_ok_seq = seq
            return seq
        deviation = offset - statistics.median(st.offsets)
        m = round(deviation / period_ns)
        if abs(deviation - m * period_ns) > self.tolerance_fraction * period_ns:
            return seq  # an outlier (late frame): neither accepted as reference nor a shift
        if m == 0:
            st.offsets.append(offset)
            st.last_ok_seq = seq
            st.drop_candidate(side, seq)
            return seq
        if m != st.candidate_shift:
            st.candidate = []
            st.candidate_shift = m
        st.candidate.append(seq)
        if len(st.candidate) < self.confirm_frames:
            return seq
        return self._apply_shift(side, seq)

    def _check_host_time(self, side: str, seq: int, cam_ns: int, host_ns: float, period_ns: float) -> int:
        """The check of a host-fired camera's frame stamped ``cam_ns``, assigned the pulse of host time ``host_ns``
        (see the module doc)."""
        st = self._state[side]
        st.stamps[seq] = cam_ns
        if len(st.stamps) > 256:
            del st.stamps[min(st.stamps)]
        tol = self.tolerance_fraction * period_ns
        late_ns = cam_ns - host_ns
        if late_ns < -tol:  # before its pulse: the frame belongs to an earlier one, by at least m pulses
            m = -math.ceil((-late_ns - tol) / period_ns)
        else:  # later than another camera's frame of the same pulse by m whole periods (0: the host's lateness)
            others = [self._state[o].stamps.get(seq) for o in self.sides if o != side]
            known = [o_ns for o_ns in others if o_ns is not None]
            m = max(0, math.floor((cam_ns - min(known) + tol) / period_ns)) if known else 0
            for other in self.sides:  # and this frame may show that another camera's candidate is only host lag
                o_st = self._state[other]
                o_ns = o_st.stamps.get(seq)
                if (other != side and o_st.candidate_shift > 0 and seq in o_st.candidate and o_ns is not None
                        and o_ns - cam_ns < o_st.candidate_shift * period_ns - tol):
                    o_st.drop_candidate(other, seq)
        if m == 0:
            if len(st.stamps) > 1:  # (a late first frame may have been aligned to a later pulse: not a reference)
                st.last_ok_seq = seq
            st.drop_candidate(side, seq)
            return seq
        if st.candidate and (m > 0) != (st.candidate_shift > 0):
            st.candidate = []
        # lateness only shortens an early frame's lead and lengthens a late one's lag: the smallest m is the shift
        st.candidate_shift = m if not st.candidate else min(st.candidate_shift, m)
        st.candidate.append(seq)
        if len(st.candidate) < self.confirm_frames * (1 if m < 0 else 2):
            return seq
        return self._apply_shift(side, seq)

    def _pulse_host_ns(self, seq: int) -> float | None:
        """Host time of pulse ``seq``: its event's, else extrapolated from the nearest earlier event with a host time
        (None when there is none)."""
        ev = self._events.get(seq)
        if ev is not None and ev.t_start_host_ns is not None:
            return float(ev.t_start_host_ns)
        before = [k for k, e in self._events.items() if k < seq and e.t_start_host_ns is not None]
        if not before:
            return None
        ref = self._events[max(before)]
        assert ref.t_start_host_ns is not None
        return ref.t_start_host_ns + (seq - ref.trigger_seq) * (self._period_us or 0.0) * 1000.0

    def _pulse_device_ns(self, seq: int) -> float:
        """Device time of pulse ``seq``: its event's, else extrapolated from the nearest event with the period."""
        ev = self._events.get(seq)
        if ev is not None:
            return ev.t_start_device_us * 1000.0
        before = [k for k in self._events if k < seq]
        ref = self._events[max(before)] if before else self._events[min(self._events)]
        return (ref.t_start_device_us + (seq - ref.trigger_seq) * (self._period_us or 0.0)) * 1000.0

    def _apply_shift(self, side: str, seq: int) -> int:
        st = self._state[side]
        m = st.candidate_shift
        # every frame of this side after the last frame whose timestamp agreed (incomplete frames carry none,
        # outliers were not decided) moves too: the shift happened somewhere after that frame
        first = min(st.candidate)
        # (no frame of this side agreed yet: every earlier frame of it is as unconfirmed as the candidates)
        start = st.last_ok_seq + 1 if st.last_ok_seq is not None else max(self._emitted_upto + 1, 0)
        for seq_before in range(start, first):
            if seq_before > self._emitted_upto and side in self._pending.get(seq_before, {}):
                st.candidate.append(seq_before)
        # and the undecided frames between the candidates (incomplete ones carry no timestamp): they shifted too
        for seq_between in range(first + 1, max(st.candidate)):
            if seq_between not in st.candidate and side in self._pending.get(seq_between, {}):
                st.candidate.append(seq_between)
        if min(st.candidate) + m < 0:
            # a shift to before the first pulse is no shift (timestamps of frames that came before START)
            log.info("camera %s: timestamp shift of %+d pulses at trigger_seq %d dropped (before pulse 0)",
                     side, m, min(st.candidate))
            st.drop_candidate()
            return seq
        moved_seq = seq
        first_moved = min(st.candidate)
        first = True
        for old in (sorted(st.candidate, reverse=m > 0)):
            frame = self._pending.get(old, {}).pop(side, None)
            if frame is None:
                continue
            new = old + m
            if new <= self._emitted_upto or side in self._pending.get(new, {}):
                self.counters[side].unpaired += 1
                self._emit_single(new, side, frame, "timestamp_mismatch")
                continue
            self._pending.setdefault(new, {})[side] = frame
            if old in st.stamps:
                st.stamps[new] = st.stamps.pop(old)
            self._newest = max(self._newest, new)
            if old == first_moved:
                self._notes.setdefault(new, {})[side] = "timestamp_mismatch"
            if old == seq:
                moved_seq = new
            first = False
        if not first:
            log.warning("camera %s: timestamps show a shift of %+d pulses from trigger_seq %d: re-synced",
                        side, m, first_moved)
        self.counters[side].timestamp_mismatches += 1
        st.offset = (st.offset or 0) + m
        st.drop_candidate()
        return moved_seq

    # -- output ---------------------------------------------------------------------------------------------------
    def _touch(self, seq: int) -> None:
        self._newest = max(self._newest, seq)
        self._pending.setdefault(seq, {})
        self._release()

    def _ready(self, seq: int) -> bool:
        slot = self._pending.get(seq, {})
        if self._shift_may_move(seq):
            return False
        # a frame not yet confirmed by a timestamp check (an incomplete frame carries none) may still move: wait until
        # its own camera has confirm_frames frames after it (the window still gives up on a silent camera)
        if any(st.last_ok_seq is not None and seq > st.last_ok_seq and st.newest_seq < seq + self.confirm_frames
               for st in self._state.values()):
            return False
        return seq in self._events and all(s in slot for s in self.sides)

    def _shift_may_move(self, seq: int) -> bool:
        """True while a timestamp shift under confirmation could still move this seq's frames: the candidates and
        every frame after the last frame whose timestamp agreed (see ``_apply_shift``)."""
        for st in self._state.values():
            if st.candidate and (st.last_ok_seq is None or seq >= min(st.last_ok_seq + 1, min(st.candidate))):
                return True
        return False

    def _release(self, everything: bool = False) -> None:
        while True:
            nxt = self._emitted_upto + 1
            if nxt > self._newest:
                return
            # a set is given up on ``window`` pulses behind the newest; twice that while a shift under confirmation
            # may still move its frames (an incomplete frame in the middle needs one more pulse to confirm)
            hopeless = nxt <= self._newest - self.window * (2 if self._shift_may_move(nxt) else 1)
            if not (everything or self._ready(nxt) or hopeless):
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
        for seq in [s for s in self._events if s < keep_from]:
            del self._events[seq]

    def flush(self) -> None:
        """Emit everything pending (call at STOP)."""
        for side, st in self._state.items():
            self.counters[side].before_start += len(st.waiting)
            st.waiting = []
        self._release(everything=True)

    def summary(self) -> dict[str, Any]:
        return {"events_received": self.events_received, "events_missing": self.events_missing,
                "sets_emitted": self.sets_emitted, "sets_complete": self.sets_complete,
                "sides": {s: vars(c).copy() for s, c in self.counters.items()}}
