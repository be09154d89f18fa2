"""Pairing frames of two cameras with TRIGGER events: drops, missing events, missed triggers, id wrap."""

from __future__ import annotations

from bracketry_rig.events import TriggerEvent
from bracketry_rig.pairing.pairer import PairedSet, Pairer
from pairing_frames import PairingFrame

PERIOD_US = 45_454
BRACKETS = [1000, 2000, 4000, 8000, 16000, 32000]


def event(k: int) -> TriggerEvent:
    return TriggerEvent(1, k, k % 6, BRACKETS[k % 6], 1_000_000 + k * PERIOD_US, 5_000_000_000 + k * PERIOD_US * 1000)


def frame(side: str, index: int, pulse: int, status: str = "success") -> PairingFrame:
    cam_ns = {"left": 77_000_000, "right": 900_000_000}[side] + pulse * PERIOD_US * 1000 + 3000
    host_ns = 5_000_000_000 + pulse * 45_454_000
    return PairingFrame(side, (65400 + index) % 65535 or 65535, index, status, cam_ns, host_ns)


def run(n: int, *, lose_frame=(), lose_event=(), miss_trigger=(), incomplete=(), no_timestamp=(),
        window: int = 8) -> tuple[Pairer, list[PairedSet]]:
    """Simulate n pulses. lose_frame: (side, k) never received (the camera's id still advanced);
    miss_trigger: (side, k) the camera never saw the pulse (its ids do not advance); no_timestamp: (side, k)
    delivered incomplete with no timestamp (its leader packet was lost)."""
    sets: list[PairedSet] = []
    p = Pairer(("left", "right"), sets.append, window=window)
    index = {"left": 0, "right": 0}
    for k in range(n):
        if k not in lose_event:
            p.add_event(event(k))
        for side in ("left", "right"):
            if (side, k) in miss_trigger:
                continue
            if (side, k) not in lose_frame:
                bad = (side, k) in incomplete or (side, k) in no_timestamp
                f = frame(side, index[side], k, "missing_packets" if bad else "success")
                if (side, k) in no_timestamp:
                    f.cam_timestamp_ns = 0
                p.add_frame(f)
            index[side] += 1
    p.flush()
    return p, sets


def test_clean_run_pairs_everything() -> None:
    p, sets = run(200)
    assert [s.trigger_seq for s in sets] == list(range(200))
    assert all(s.complete for s in sets)
    for side in ("left", "right"):
        c = p.counters[side]
        assert (c.frames, c.drops, c.unpaired, c.incomplete, c.timestamp_mismatches) == (200, 0, 0, 0, 0)
    # frame time = the trigger's host time, shared by both frames
    assert sets[5].stamp_ns == event(5).t_start_host_ns


def test_lost_frames_events_and_incomplete_are_reported_with_their_seq() -> None:
    p, sets = run(100, lose_frame={("left", 10), ("right", 50)}, lose_event={30}, incomplete={("right", 70)})
    by_seq = {s.trigger_seq: s for s in sets}
    assert by_seq[10].frames["left"] is None and by_seq[10].frames["right"] is not None
    assert by_seq[50].frames["right"] is None
    assert by_seq[30].event is None and not by_seq[30].complete
    assert p.counters["left"].drops == 1 and p.counters["right"].drops == 1
    assert p.events_missing == 1
    assert p.counters["right"].incomplete == 1
    # the frames after a loss keep their trigger_seq (ids advanced)
    assert by_seq[11].frames["left"].frame_index == 11
    assert sum(s.complete for s in sets) == 100 - 3


def test_missed_trigger_is_resynced_by_timestamps() -> None:
    # the right camera never saw pulse 40: its 40th frame belongs to pulse 41
    p, sets = run(100, miss_trigger={("right", 40)})
    by_seq = {s.trigger_seq: s for s in sets}
    assert by_seq[40].frames["right"] is None
    assert by_seq[41].frames["right"] is not None and by_seq[41].notes.get("right") == "timestamp_mismatch"
    assert p.counters["right"].drops == 1
    assert p.counters["right"].timestamp_mismatches == 1
    assert all(by_seq[k].complete for k in range(42, 100))


def test_frame_ids_wrap_inside_a_run() -> None:
    # frame ids start at 65400 in `frame()`: 200 frames cross the 65535 -> 1 wrap
    p, sets = run(200)
    assert {s.frames["left"].frame_id for s in sets} >= {65535, 1}
    assert p.counters["left"].drops == 0


def test_counter_value_chunk_aligns_only_when_asked() -> None:
    """A CounterValue chunk is trusted only with initial_alignment="counter" (a camera counter that was never reset
    would otherwise shift every frame of a segment); by default the first frame is pulse 0."""
    for mode, expected in (("count", 0), ("counter", 4)):
        p = Pairer(("left",), window=8, initial_alignment=mode)
        for k in range(6):
            p.add_event(event(k))
        f = frame("left", 0, 4)
        f.counter_value = 5  # type: ignore[attr-defined]  (the 5th pulse since the counter's reset)
        assert p.add_frame(f) == expected, mode


def test_missed_trigger_followed_by_frames_without_timestamps_is_placed_exactly() -> None:
    """The right camera never saw pulse 50 and the next two frames lost their leader (no timestamp): they cannot
    be checked, but they move with the first frames whose timestamps show the shift, so the drop is at 50."""
    for window in (4, 8):
        p, sets = run(100, miss_trigger={("right", 50)}, no_timestamp={("right", 51), ("right", 52)}, window=window)
        by_seq = {s.trigger_seq: s for s in sets}
        assert [k for k, s in by_seq.items() if s.frames["right"] is None] == [50], window
        assert by_seq[51].frames["right"].frame_index == 50 and by_seq[52].frames["right"].frame_index == 51
        assert p.counters["right"].drops == 1 and p.counters["right"].unpaired == 0
        assert all(by_seq[k].complete for k in range(53, 100))


def test_a_late_buffer_is_paired_with_its_own_pulse_or_reported_late() -> None:
    """Aravis hands a timed-out buffer over after newer ones: it carries its own frame index, so the frames after
    it keep their pulses; if its set already left, it is recorded as a late, unpaired frame."""
    def feed(late_at: int) -> tuple[Pairer, list[PairedSet], int | None]:
        """60 pulses; right frame 20 arrives (timed out) right after pulse ``late_at``; returns its add_frame result."""
        sets: list[PairedSet] = []
        p = Pairer(("left", "right"), sets.append, window=8)
        placed = None
        for k in range(60):
            p.add_event(event(k))
            p.add_frame(frame("left", k, k))
            if k != 20:
                p.add_frame(frame("right", k, k))
            if k == late_at:
                placed = p.add_frame(frame("right", 20, 20, "timeout"))
        p.flush()
        return p, sets, placed

    p, sets, placed = feed(22)
    assert placed == 20  # two pulses late: still waiting in the window, paired
    by_seq = {s.trigger_seq: s for s in sets}
    assert by_seq[20].frames["right"] is not None and by_seq[20].frames["right"].frame_index == 20
    assert all(by_seq[k].complete for k in range(60) if k != 20)
    assert p.counters["right"].drops == 0
    p, sets, _ = feed(40)  # far too late: its set was given up on
    assert p.counters["right"].drops == 1 and p.counters["right"].late == 1
    assert all(s.complete for s in sets if s.trigger_seq != 20 and s.frames.get("right") is not None
               and s.frames.get("left") is not None)


def test_a_shift_to_before_pulse_zero_is_never_applied() -> None:
    """A first checked frame whose timestamp is 3 periods late sets a wrong reference; the frames after it then look
    shifted by -3 pulses. Moving them to pulses -2..-1 would record invalid trigger_seqs
    (stored unsigned: 4294967294...)."""
    sets: list[PairedSet] = []
    p = Pairer(("left", "right"), sets.append, window=8)
    for k in range(40):
        p.add_event(event(k))
        for side in ("left", "right"):
            f = frame(side, k, k)
            if side == "left" and k == 1:  # pulse 0 is never checked (no period yet)
                f.cam_timestamp_ns += 3 * PERIOD_US * 1000
            p.add_frame(f)
    p.flush()
    seqs = [s.trigger_seq for s in sets]
    assert seqs and min(seqs) >= 0
    assert sum(1 for s in sets if s.frames["left"] is not None) == 40  # every left frame recorded once


def host_fired_run(n: int, late_ms: dict[tuple[str, int], float], miss_trigger: frozenset = frozenset(),
                   extra_frame: frozenset = frozenset()) -> tuple[Pairer, list[PairedSet]]:
    """n pulses to cameras fired by the host (``host_time`` alignment): each frame's timestamp is its pulse's host time
    + 2 ms + ``late_ms[(side, k)]``; miss_trigger: (side, k) the camera never fired; extra_frame: (side, k) a frame
    that belongs to no pulse, stamped half a period before pulse k."""
    sets: list[PairedSet] = []
    p = Pairer(("left", "right"), sets.append, window=8, initial_alignment="host_time")
    index = {"left": 0, "right": 0}
    p.add_event(event(0))
    for k in range(n):
        if k + 1 < n:  # the next pulse's event comes before this pulse's (late) frames
            p.add_event(event(k + 1))
        for side in ("left", "right"):
            host_ns = event(k).t_start_host_ns
            assert host_ns is not None
            if (side, k) in extra_frame:
                p.add_frame(PairingFrame(side, index[side] + 1, index[side], "success", host_ns - PERIOD_US * 500, 0))
                index[side] += 1
            if (side, k) in miss_trigger:
                continue
            stamp = host_ns + 2_000_000 + int(late_ms.get((side, k), 0.0) * 1e6)
            p.add_frame(PairingFrame(side, index[side] + 1, index[side], "success", stamp, stamp + 1_000_000))
            index[side] += 1
    p.flush()
    return p, sets


def test_host_fired_cameras_late_at_the_start_or_in_bursts_keep_their_pulses() -> None:
    """Frames of host-fired cameras are late by whatever the host's scheduling adds: the first frames of a session a
    period late (aligned to the second pulse, moved back by the frames after it), a burst that builds up
    to four periods and catches up, two seconds of both cameras more than a period late, one camera's thread alone
    late for four frames. Every frame keeps its pulse, every set is complete (a reference learnt from late first
    frames re-synced a whole camera by -1 pulse)."""
    period_ms = PERIOD_US / 1000
    late = {("right", 0): 1.1 * period_ms, ("right", 1): 1.05 * period_ms, ("left", 0): 1.2 * period_ms}
    for i, f in enumerate([0.6, 1.3, 2.2, 3.1, 4.0, 3.7, 3.0, 2.6, 1.9, 1.2, 0.5]):
        late[("left", 30 + i)] = late[("right", 30 + i)] = f * period_ms
    for k in range(60, 110):  # the host fires both cameras more than a period late for two seconds
        late[("left", k)], late[("right", k)] = 1.4 * period_ms, (1.4 + 0.1 * (k % 3)) * period_ms
    for k in range(112, 116):  # one camera's thread alone two periods late for four frames
        late[("left", k)] = 2.2 * period_ms
    p, sets = host_fired_run(120, late)
    assert [s.trigger_seq for s in sets] == list(range(120))
    assert all(s.complete for s in sets) and all(not s.notes for s in sets[1:])
    for side in ("left", "right"):
        c = p.counters[side]
        assert (c.drops, c.unpaired, c.timestamp_mismatches) == (0, 0, 1), side  # the first frame moved back


def test_host_fired_camera_that_missed_or_invented_a_pulse_is_resynced() -> None:
    """A camera whose frames come a period later than the other camera's frames of the same pulses missed one: its
    frames move on once ``2 * confirm_frames`` agree (the drop lands on the missed pulse). A frame stamped before its
    pulse proves a frame for no pulse: the frames move back within ``confirm_frames``."""
    p, sets = host_fired_run(120, {("right", 41): 60.0}, miss_trigger=frozenset({("right", 40)}))
    by_seq = {s.trigger_seq: s for s in sets if s.frames["left"] is not None}
    assert p.counters["right"].drops == 1 and by_seq[40].frames["right"] is None
    assert p.counters["right"].timestamp_mismatches == 1
    assert all(by_seq[k].complete for k in range(41, 120))
    p, sets = host_fired_run(60, {}, extra_frame=frozenset({("left", 20)}))
    assert p.counters["left"].timestamp_mismatches == 1
    by_seq = {s.trigger_seq: s for s in sets if s.frames["right"] is not None}
    assert all(by_seq[k].complete for k in range(21, 60)) and all(by_seq[k].complete for k in range(20))
