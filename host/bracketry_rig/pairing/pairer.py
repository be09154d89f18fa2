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

A frame that carries its pulse (``frame.trigger_seq``, not None: set by the recording session from the camera's own
trigger stamp, ``bracketry_rig.cameras.triggering.TriggerStamps``) is placed on that pulse as it is and is a reference
for the checks above; its camera's frames without one (a lost leader: no timestamp) follow it by frame index. A
trigger the host fired late is then still its pulse's, however late (a negative ``trigger_seq``: the priming
trigger's frame, for no pulse).

Bracket order: a frame that reports its exposure (``exposure_us_reported``, the ExposureTime chunk) is checked
against the exposure of its pulse (the TRIGGER events' cyclic bracket table, ``bracket_index`` -> ``exposure_us``). A
frame whose exposure is its pulse's is on its pulse (a reference, like an agreeing timestamp); one whose exposure is
pulse ``seq + m``'s (the ``m`` the timestamps show, else the smallest ``|m|``) is a shift candidate like a timestamp
one, timestamp or not. So the first moved frame of a confirmed shift is the first frame after the last one shown on
its pulse, by its exposure or its timestamp: the missed pulse is placed on its own seq whatever its neighbours carry.
Where the timestamp is clear it decides; exposures decide where it is missing or inconclusive, and only on a camera
whose last timed frame with an exposure agreed with its timestamp (a chunk one frame behind, Aravis #312, never does).
A host-fired camera's frame shows its pulse by time only when stamped before the next pulse (its event's host time,
less ``tolerance_fraction`` of a period): a frame is never stamped before its own pulse. A frame as late as the other
cameras' but after the next pulse shows nothing (all may be late, or all may have missed a pulse): a shift under
confirmation stays pending and its set waits (until given up on) for a frame that decides; a candidate frame later
than the other cameras' and stamped after the next pulse counts twice. Frames with neither an exposure nor a
timestamp move with their neighbours.

A trigger_seq is emitted (``PairedSet``) as soon as the event and every camera's frame are there (and no check above
still waits on it), else once it is given up on (then with what is missing counted), or at ``flush()``.

Giving up tells a source that is behind from one that missed the pulse. Each source (the TRIGGER events, each
camera) delivers in order, one camera's frames arriving whole periods late in bursts on a loaded host. A pulse is
lost for a source once that source delivered something ``window`` pulses after it (twice that while a shift under
confirmation may still move its frames): the ``confirm_frames`` frames a check waits for came, and nothing for it
can follow. A set is given up on once every source moved on that far; a source that delivered nothing that far
after it is only behind, and is waited for, up to the backstop: ``max_lag_s`` of pulses (at the events' period;
never less than twice ``window``) behind the newest pulse seen from any source. The backstop bounds the memory of
held sets and how long a dead camera holds the other camera's sets (a camera that delivers nothing for the daemon's
``camera_stall_s``, 2 s, leaves the acquisition: its session is flushed; the backstop is below that). It costs no
crash loss of its own: a set waits only for a camera whose frames have not reached the host, and a truncated
recording is whole only up to the last pulse every camera's frames were written for.
"""

from __future__ import annotations

import logging
import math
import statistics
from collections import deque
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

from bracketry_rig.events import TriggerEvent

log = logging.getLogger(__name__)

#: a reported exposure is a pulse's when within this fraction of it or this many microseconds (as ``verify``)
EXPOSURE_TOLERANCE_REL = 0.02
EXPOSURE_TOLERANCE_US = 20.0


@dataclass
class PairedSet:
    """Everything received for one trigger_seq.

    Attributes:
        trigger_seq: the pulse number.
        event: the TRIGGER event, or None when it was lost.
        frames: side -> frame (``bracketry_rig.cameras.camera.Frame`` or any object with the same fields) or None.
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
    stamped: int = 0  # frames placed by their own trigger stamp (``frame.trigger_seq``)


@dataclass
class _SideState:
    offset: int | None = None  # trigger_seq = frame_index + offset
    offsets: deque = field(default_factory=lambda: deque(maxlen=15))  # cam ns - device ns of accepted frames
    candidate: list[int] = field(default_factory=list)  # seqs of frames agreeing on a shift
    candidate_shift: int = 0
    candidate_weight: int = 0  # evidence of the candidates: one per frame, two for a frame that proves its shift
    recent: dict[int, int] = field(default_factory=dict)  # seq -> offset of recent frames (accepted or not)
    waiting: list = field(default_factory=list)  # frames before any event (host_time alignment)
    last_ok_seq: int | None = None  # last frame whose timestamp or exposure agreed with its pulse
    stamps: dict[int, int] = field(default_factory=dict)  # seq -> camera timestamp (host-fired cameras)
    newest_seq: int = -1  # newest trigger_seq a frame of this side was assigned
    suspect: set[int] = field(default_factory=set)  # seqs of frames stamped after the next pulse, undecided
    exposures_agree: int = 0  # timed frames in a row whose reported exposure agreed with their timestamp's pulse

    def drop_candidate(self, side: str | None = None, seq: int | None = None) -> None:
        """Forget the shift candidate; with ``side`` and ``seq``, log that a pending one was dropped at ``seq``."""
        if self.candidate and side is not None:
            log.info("camera %s: timestamp shift candidate dropped at trigger_seq %d", side, seq)
        self.candidate = []
        self.candidate_shift = 0
        self.candidate_weight = 0


class Pairer:
    """Pairs frames of ``sides`` with TRIGGER events. Not thread-safe: feed it from one thread.

    Args:
        sides: camera names.
        on_set: called with each emitted ``PairedSet`` (in trigger_seq order per call of ``add_*``/``flush``).
        window: a trigger_seq is emitted incomplete once every source delivered something this many pulses after it
            (see the module doc).
        max_lag_s: the backstop: a trigger_seq is emitted incomplete once it is this long (in pulses at the events'
            period, at least ``2 * window``) behind the newest pulse seen, however far behind a camera is.
        tolerance_fraction: allowed timestamp disagreement as a fraction of the pulse period.
        confirm_frames: consecutive frames that must agree on a shift before frames are moved.
        initial_alignment: ``count`` (first frame = pulse 0), ``counter`` or ``host_time`` (see ``_initial_seq``).
    """

    def __init__(self, sides: tuple[str, ...] = ("left", "right"), on_set: Callable[[PairedSet], None] | None = None,
                 *, window: int = 16, max_lag_s: float = 1.0, tolerance_fraction: float = 0.3,
                 confirm_frames: int = 3, initial_alignment: str = "count") -> None:
        self.sides = sides
        self.on_set = on_set or (lambda _s: None)
        self.window = window
        self.max_lag_s = max_lag_s
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
        self._brackets: dict[int, int] = {}  # bracket_index -> exposure_us, from the events
        self._cycle: int | None = None  # bracket table length, once a full cycle of events was seen
        self._bracket_repeated = False

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
        self._learn_bracket(event)
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
        stamped = getattr(frame, "trigger_seq", None)  # the pulse its own trigger stamp shows (module doc)
        if stamped is None and st.offset is None and self.initial_alignment == "host_time" and not self._events:
            st.waiting.append(frame)  # aligned when the first TRIGGER event arrives
            return -1
        c.frames += 1
        c.missing_packets += int(getattr(frame, "missing_packets", 0) or 0)
        if frame.status != "success":
            c.incomplete += 1
        if stamped is not None:
            if stamped < 0:  # the priming trigger's frame: for no pulse
                c.frames -= 1
                c.before_start += 1
                return -1
            c.stamped += 1
            st.offset = int(stamped) - frame.frame_index  # frames without a stamp of their own follow it
        elif st.offset is None:
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
        seq = self._check_time(side, seq, frame) if stamped is None else self._on_stamped_pulse(side, seq, frame)
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
        their pulses; a frame without a timestamp: the latest pulse of its reported exposure that started before it
        was received), and None (frame ignored: the priming trigger's) when none did. Otherwise the first frame is
        pulse 0 (k-th frame since START).
        """
        counter = getattr(frame, "counter_value", None)
        if self.initial_alignment == "counter" and counter is not None and counter > 0:
            return int(counter) - 1
        if self.initial_alignment == "host_time":
            if not frame.cam_timestamp_ns:  # no timestamp (lost leader): the latest pulse received with its exposure
                reported = self._frame_exposure_us(frame)
                started = [e.trigger_seq for e in self._events.values()
                           if e.t_start_host_ns is not None and e.t_start_host_ns <= frame.host_receive_ns
                           and reported is not None and self._exposure_is(reported, e.exposure_us)]
                return max(started) if started else None
            started = [e.trigger_seq for e in self._events.values()
                       if e.t_start_host_ns is not None and e.t_start_host_ns <= frame.cam_timestamp_ns]
            return max(started) if started else None
        return 0

    # -- bracket order ----------------------------------------------------------------------------------------------
    def _learn_bracket(self, event: TriggerEvent) -> None:
        """Learn the bracket table; its length is known once every index up to the largest seen is in it and every
        stored event agrees with it (a lost event with the last index would otherwise make the cycle one short)."""
        index = int(event.bracket_index)
        if index < 0:
            return
        self._bracket_repeated = self._bracket_repeated or index in self._brackets  # a whole cycle went by
        self._brackets[index] = int(event.exposure_us)
        n = max(self._brackets) + 1
        phases = {(int(e.bracket_index) - e.trigger_seq) % n for e in self._events.values()}
        self._cycle = n if self._bracket_repeated and len(self._brackets) == n and len(phases) == 1 else None

    def _pulse_exposure_us(self, seq: int) -> int | None:
        """Exposure of pulse ``seq``: its event's, else from the bracket table and the nearest event (None: unknown)."""
        ev = self._events.get(seq)
        if ev is not None:
            return int(ev.exposure_us)
        if self._cycle is None or not self._events:
            return None
        ref = self._events[min(self._events, key=lambda k: abs(k - seq))]
        return self._brackets.get((int(ref.bracket_index) + seq - ref.trigger_seq) % self._cycle)

    @staticmethod
    def _frame_exposure_us(frame: Any) -> float | None:
        value = getattr(frame, "exposure_us_reported", None)
        if value is None or not math.isfinite(float(value)) or float(value) <= 0:
            return None
        return float(value)

    @staticmethod
    def _exposure_is(reported: float, want: int | None) -> bool:
        return want is not None and abs(reported - want) <= max(EXPOSURE_TOLERANCE_REL * want, EXPOSURE_TOLERANCE_US)

    def _exposure_shift(self, seq: int, frame: Any, hint: int | None = None) -> int | None:
        """Bracket-order check: 0 when the frame's exposure is its pulse's, else the shift ``m`` whose pulse
        ``seq + m`` has it (``hint`` when it fits, else the smallest ``|m|`` within one cycle, positive first);
        None when the frame reports no exposure, the pulses' exposures are unknown or nothing matches."""
        reported = self._frame_exposure_us(frame)
        if reported is None:
            return None
        want = self._pulse_exposure_us(seq)
        if want is None:
            return None
        if self._exposure_is(reported, want):
            return 0
        if self._cycle is None:
            return None
        if hint and self._exposure_is(reported, self._pulse_exposure_us(seq + hint)):
            return hint
        for k in range(1, self._cycle):
            for m in (k, -k):
                if seq + m >= 0 and self._exposure_is(reported, self._pulse_exposure_us(seq + m)):
                    return m
        return None

    # -- timestamps -------------------------------------------------------------------------------------------------
    def _on_stamped_pulse(self, side: str, seq: int, frame: Any) -> int:
        """A frame whose own trigger stamp shows its pulse ``seq``: on its pulse, a reference for the checks of
        the frames without one (no inference from lateness)."""
        st = self._state[side]
        if frame.cam_timestamp_ns:
            st.stamps[seq] = int(frame.cam_timestamp_ns)
            if len(st.stamps) > 256:
                del st.stamps[min(st.stamps)]
        self._compare_exposure(side, seq, frame, 0)
        st.last_ok_seq = seq if st.last_ok_seq is None else max(st.last_ok_seq, seq)
        st.suspect = {k for k in st.suspect if k > seq}
        st.drop_candidate(side, seq)
        return seq

    def _check_time(self, side: str, seq: int, frame: Any) -> int:
        """Timestamp and bracket-order cross-check (see module doc); returns the frame's (possibly moved)
        trigger_seq."""
        st = self._state[side]
        if not self._events:
            return seq
        has_time = self._period_us is not None and bool(frame.cam_timestamp_ns)
        if not has_time:  # an incomplete buffer whose leader was lost carries no timestamp: its exposure may tell
            em = self._trusted_exposure_shift(side, seq, frame, st.candidate_shift or None)
            return seq if em is None else self._decide(side, seq, em)
        assert self._period_us is not None
        period_ns = self._period_us * 1000.0
        if self.initial_alignment == "host_time":
            host_ns = self._pulse_host_ns(seq)
            if host_ns is not None:
                return self._check_host_time(side, seq, frame, host_ns, period_ns)
        offset = frame.cam_timestamp_ns - self._pulse_device_ns(seq)
        st.recent[seq] = offset
        if len(st.recent) > 64:
            del st.recent[min(st.recent)]
        if not st.offsets:  # the first timed frame: the reference
            self._compare_exposure(side, seq, frame, 0)
            st.offsets.append(offset)
            st.last_ok_seq = seq
            return seq
        deviation = offset - statistics.median(st.offsets)
        m = round(deviation / period_ns)
        if abs(deviation - m * period_ns) > self.tolerance_fraction * period_ns:
            # an outlier (late frame): neither accepted as reference nor a shift, unless its exposure tells
            em = self._trusted_exposure_shift(side, seq, frame, st.candidate_shift or None)
            return seq if em is None else self._decide(side, seq, em)
        self._compare_exposure(side, seq, frame, m)
        if m == 0:
            st.offsets.append(offset)
        return self._decide(side, seq, m)

    def _compare_exposure(self, side: str, seq: int, frame: Any, m: int) -> None:
        """A frame whose timestamp shows its pulse ``seq + m``: does its reported exposure say the same? (A camera
        whose chunk lags a frame, Aravis #312, never agrees: its exposures are never used to place frames.)"""
        em = self._exposure_shift(seq, frame, m or None)
        if em is not None:
            st = self._state[side]
            st.exposures_agree = st.exposures_agree + 1 if em == m else 0

    def _trusted_exposure_shift(self, side: str, seq: int, frame: Any, hint: int | None = None) -> int | None:
        """``_exposure_shift`` of a camera whose last timed frame with an exposure agreed with its timestamp."""
        return self._exposure_shift(seq, frame, hint) if self._state[side].exposures_agree > 0 else None

    def _decide(self, side: str, seq: int, m: int) -> int:
        """The frame at ``seq`` is on its pulse (``m == 0``) or shows a shift of ``m``: note it as a reference or a
        shift candidate, and apply the shift once ``confirm_frames`` frames agree."""
        st = self._state[side]
        if m == 0:
            st.last_ok_seq = seq if st.last_ok_seq is None else max(st.last_ok_seq, seq)
            st.suspect = {k for k in st.suspect if k > seq}  # frames before one on its pulse are on theirs
            st.drop_candidate(side, seq)
            return seq
        if m != st.candidate_shift:
            st.drop_candidate()
            st.candidate_shift = m
        st.candidate.append(seq)
        st.candidate_weight += 1
        if st.candidate_weight < self.confirm_frames:
            return seq
        return self._apply_shift(side, seq)

    def _check_host_time(self, side: str, seq: int, frame: Any, host_ns: float, period_ns: float) -> int:
        """The check of a host-fired camera's frame, assigned the pulse of host time ``host_ns`` (see the module
        doc)."""
        st = self._state[side]
        cam_ns = int(frame.cam_timestamp_ns)
        st.stamps[seq] = cam_ns
        if len(st.stamps) > 256:
            del st.stamps[min(st.stamps)]
        tol = self.tolerance_fraction * period_ns
        late_ns = cam_ns - host_ns
        known: list[int] = []  # the other cameras' stamps of this seq
        if late_ns < -tol:  # before its pulse: the frame belongs to an earlier one, by at least m pulses
            m = -math.ceil((-late_ns - tol) / period_ns)
        else:  # later than another camera's frame of the same pulse by m whole periods (0: the host's lateness)
            others = [self._state[o].stamps.get(seq) for o in self.sides if o != side]
            known = [o_ns for o_ns in others if o_ns is not None]
            m = max(0, math.floor((cam_ns - min(known) + tol) / period_ns)) if known else 0
            if not known and 0 < st.candidate_shift <= math.floor((late_ns + tol) / period_ns):
                m = st.candidate_shift  # no other frame to compare with: as late as the pending shift says, it agrees
            # and this frame, when on its pulse (stamped before the next one, or of its exposure: a frame as late as
            # another camera's shifted one proves nothing), may show that another camera's candidate is only host lag
            on_time = cam_ns < self._next_pulse_host_ns(seq, host_ns, period_ns) - tol
            if on_time:  # stamped after its pulse and before the next one: the timestamp shows its pulse
                self._compare_exposure(side, seq, frame, 0)
            on_time = on_time or self._trusted_exposure_shift(side, seq, frame) == 0
            for other in self.sides:
                o_st = self._state[other]
                o_ns = o_st.stamps.get(seq)
                if (other != side and on_time and o_st.candidate_shift > 0 and seq in o_st.candidate
                        and o_ns is not None and o_ns - cam_ns < o_st.candidate_shift * period_ns - tol):
                    o_st.drop_candidate(other, seq)
        em = self._trusted_exposure_shift(side, seq, frame, m or st.candidate_shift or None)
        if em is not None:  # the bracket order is exact: it decides
            if em == 0 and len(st.stamps) <= 1:
                return seq  # (a late first frame may have been aligned to a later pulse: not a reference)
            if em != 0 and st.candidate and em != st.candidate_shift:
                st.drop_candidate()
            return self._decide(side, seq, em)
        if m == 0:
            if cam_ns >= self._next_pulse_host_ns(seq, host_ns, period_ns) - tol:
                # as late as the other cameras but not before the next pulse (whose host time, when its event came,
                # is its own: a pulse fired late by the host leaves less than a period to the next): they may all be
                # late, or all have missed a pulse: proves nothing (a shift under confirmation stays pending); its
                # set waits (until given up on) for a frame that decides
                st.suspect.add(seq)
                return seq
            if len(st.stamps) > 1:  # (a late first frame may have been aligned to a later pulse: not a reference)
                st.last_ok_seq = seq if st.last_ok_seq is None else max(st.last_ok_seq, seq)
                st.suspect = {k for k in st.suspect if k > seq}
            st.drop_candidate(side, seq)
            return seq
        if st.candidate and (m > 0) != (st.candidate_shift > 0):
            st.drop_candidate()
        # lateness only shortens an early frame's lead and lengthens a late one's lag: the smallest m is the shift
        st.candidate_shift = m if not st.candidate else min(st.candidate_shift, m)
        st.candidate.append(seq)
        # a frame later than the other cameras' and stamped after the next pulse's own host time (its event came)
        # counts twice: a frame of its own pulse would have to be late by a whole pulse gap while theirs were not
        next_ns = self._pulse_host_ns(seq + 1, exact=True) if m > 0 and known else None
        st.candidate_weight += 2 if next_ns is not None and cam_ns >= next_ns else 1
        if st.candidate_weight < self.confirm_frames * (1 if m < 0 else 2):
            return seq
        return self._apply_shift(side, seq)

    def _pulse_host_ns(self, seq: int, exact: bool = False) -> float | None:
        """Host time of pulse ``seq``: its event's, else (unless ``exact``) extrapolated from the nearest earlier
        event with a host time (None when there is none)."""
        ev = self._events.get(seq)
        if ev is not None and ev.t_start_host_ns is not None:
            return float(ev.t_start_host_ns)
        if exact:
            return None
        before = [k for k, e in self._events.items() if k < seq and e.t_start_host_ns is not None]
        if not before:
            return None
        ref = self._events[max(before)]
        assert ref.t_start_host_ns is not None
        return ref.t_start_host_ns + (seq - ref.trigger_seq) * (self._period_us or 0.0) * 1000.0

    def _next_pulse_host_ns(self, seq: int, host_ns: float, period_ns: float) -> float:
        """Host time of pulse ``seq + 1`` (of host time ``host_ns``): its event's (a pulse the host fired late leaves
        less than a period to the next), else one period later."""
        next_ns = self._pulse_host_ns(seq + 1, exact=True)
        return host_ns + period_ns if next_ns is None else next_ns

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
        if m < 0:  # its frames moved back (later ones follow): so did how far it delivered
            st.newest_seq = max(st.newest_seq + m, moved_seq)
        st.suspect = set()
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
        # its own camera has confirm_frames frames after it (the backstop still gives up on a silent camera)
        if any(st.last_ok_seq is not None and seq > st.last_ok_seq and st.newest_seq < seq + self.confirm_frames
               for st in self._state.values()):
            return False
        # a host-fired camera's frame stamped after the next pulse may be that pulse's: wait for one that decides
        if any(seq in st.suspect for st in self._state.values()):
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
            if not (everything or self._ready(nxt) or self._given_up(nxt)):
                # complete sets further on wait for this one (ordered output), unless it is hopeless
                return
            self._emit(nxt)

    def backstop_pulses(self) -> int:
        """The backstop in pulses: ``max_lag_s`` at the events' period, at least twice the window (the window alone
        until the period is known)."""
        if not self._period_us:
            return 2 * self.window
        return max(2 * self.window, round(self.max_lag_s * 1e6 / self._period_us))

    def _given_up(self, seq: int) -> bool:
        """Whether ``seq`` is given up on (see the module doc): every source moved ``window`` pulses past it (twice
        that while a shift under confirmation may still move its frames: an incomplete frame in the middle needs one
        more pulse to confirm), or it is the backstop behind the newest pulse seen."""
        if seq <= self._newest - self.backstop_pulses():
            return True
        reach = seq + self.window * (2 if self._shift_may_move(seq) else 1)
        events = self._last_event_seq if self._last_event_seq is not None else -1
        return events >= reach and all(st.newest_seq >= reach for st in self._state.values())

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
        for st in self._state.values():
            st.suspect.discard(seq)
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
