"""Host-fired cameras whose frames carry their own trigger stamp: each frame is placed on the pulse its stamp shows,
however late the host fired it (the load-20 false drop: a late host trigger taken for a missed pulse)."""

from __future__ import annotations

from bracketry_rig.cameras.triggering import PRIMING_SEQ, SoftwareTrigger, TriggerStamps, frame_pulse
from bracketry_rig.events import TriggerEvent
from bracketry_rig.pairing.pairer import PairedSet, Pairer
from pairing_frames import PairingFrame

PERIOD_NS = 100_000_000  # 10 pulses per second, as the recording tests
BRACKETS = [1000, 2000, 4000, 8000, 16000, 32000]


class HostClock:
    """The host's ``time.time_ns`` as the trigger sees it: it moves only when the scripted GVCP traffic says so."""

    def __init__(self) -> None:
        self.t_ns = 1_000_000_000_000

    def __call__(self) -> int:
        return self.t_ns


class StampingCam:
    """A fake camera behind its relay: each TriggerSoftware is received ``receive_ns`` after it was sent (that is
    the frame's stamp) and acknowledged ``round_trip_ns`` after it was sent (the clock moves on by that much)."""

    def __init__(self, clock: HostClock) -> None:
        self.clock = clock
        self.trigger_stamps = TriggerStamps()
        self.received: list[int] = []
        self.round_trip_ns = 2_000_000

    def set_exposure_us(self, exposure_us: float) -> None:
        self.clock.t_ns += 300_000

    def software_trigger(self) -> None:
        self.received.append(self.clock.t_ns + 200_000)
        self.clock.t_ns += self.round_trip_ns


def test_trigger_stamps_tell_each_pulse_and_nothing_else() -> None:
    stamps = TriggerStamps()
    stamps.sent(PRIMING_SEQ, 100)
    stamps.acked(PRIMING_SEQ, 150)
    stamps.sent(0, 1000)
    stamps.sent(1, 2000)  # 0 not acknowledged yet when 1 went out: only a failed command, still taken as sent
    stamps.acked(1, 2500)
    assert [stamps.pulse_of(t) for t in (99, 120, 151, 1000, 1999, 2000, 2500, 2501)] == \
        [None, PRIMING_SEQ, None, 0, 0, 1, 1, None]
    assert frame_pulse(PairingFrame("left", 1, 0, "success", 0, 0), stamps) is None  # no timestamp
    stamps.sent(2, 50)  # the host clock stepped back: the older stamps are forgotten
    stamps.acked(2, 70)
    assert stamps.pulse_of(1500) is None and stamps.pulse_of(60) == 2 and len(stamps) == 1


def fire_run(n: int, stall_at: int, stall_pulses: int, slow: range, use_stamps: bool
             ) -> tuple[Pairer, list[PairedSet]]:
    """``n`` pulses of a device at ``PERIOD_NS``; the host fires each when its event comes, but is starved for
    ``stall_pulses`` periods at pulse ``stall_at`` (then fires the backlog back to back), and the left camera's
    GVCP round trip takes 1.3 periods for the pulses in ``slow`` (so the right camera is fired that much later).
    Every camera serves one frame per trigger, stamped with the trigger's receive time. Frames reach the pairer
    after the next pulse's event."""
    clock = HostClock()
    cams = {"left": StampingCam(clock), "right": StampingCam(clock)}
    trigger = SoftwareTrigger(cams, min_interval_s=0.0, clock_ns=clock)
    t0 = clock.t_ns + 10 * PERIOD_NS
    sets: list[PairedSet] = []
    pairer = Pairer(("left", "right"), sets.append, window=4, initial_alignment="host_time")
    pending: list[PairingFrame] = []
    for k in range(n):
        pulse_ns = t0 + k * PERIOD_NS
        clock.t_ns = max(clock.t_ns, pulse_ns + 1_000_000)
        if k == stall_at:
            clock.t_ns += stall_pulses * PERIOD_NS
        cams["left"].round_trip_ns = int(1.3 * PERIOD_NS) if k in slow else 2_000_000
        trigger.fire(TriggerEvent(1, k, k % 6, BRACKETS[k % 6], k * PERIOD_NS // 1000, pulse_ns))
        pairer.add_event(TriggerEvent(1, k, k % 6, BRACKETS[k % 6], k * PERIOD_NS // 1000, pulse_ns))
        for f in pending:
            pairer.add_frame(f)
        pending = []
        for side, cam in cams.items():
            stamp = cam.received[-1]
            f = PairingFrame(side, k + 1, k, "success", stamp, clock.t_ns + 5_000_000)
            if use_stamps:
                f.trigger_seq = frame_pulse(f, cam.trigger_stamps)
            pending.append(f)
    for f in pending:
        pairer.add_frame(f)
    pairer.flush()
    return pairer, sets


def test_a_late_host_trigger_is_its_own_pulse_not_a_missed_one() -> None:
    """The host starved for three periods, then its left camera's acknowledgements a period late for eight pulses in
    a row: from their timestamps alone the right camera's frames look a pulse late (a false re-sync, then drops and
    unpaired frames); from their own trigger stamps every frame is on its pulse."""
    args = dict(n=120, stall_at=30, stall_pulses=3, slow=range(60, 68))
    guessed, _ = fire_run(**args, use_stamps=False)  # type: ignore[arg-type]
    assert any(guessed.counters[s].timestamp_mismatches or guessed.counters[s].drops for s in ("left", "right"))
    pairer, sets = fire_run(**args, use_stamps=True)  # type: ignore[arg-type]
    assert [s.trigger_seq for s in sets] == list(range(120))
    assert all(s.complete and not s.notes for s in sets)
    for side in ("left", "right"):
        c = pairer.counters[side]
        assert (c.frames, c.drops, c.unpaired, c.timestamp_mismatches, c.late) == (120, 0, 0, 0, 0), side


def test_a_stamped_frame_of_the_priming_trigger_is_for_no_pulse() -> None:
    sets: list[PairedSet] = []
    pairer = Pairer(("left", "right"), sets.append, window=4, initial_alignment="host_time")
    for side in ("left", "right"):
        assert pairer.add_frame(PairingFrame(side, 9, 0, "success", 5, 5, trigger_seq=PRIMING_SEQ)) == -1
        assert pairer.add_frame(PairingFrame(side, 10, 1, "success", 7, 7, trigger_seq=0)) == 0
    pairer.add_event(TriggerEvent(1, 0, 0, 1000, 0, 6))
    pairer.flush()
    assert [s.trigger_seq for s in sets] == [0] and sets[0].complete
    assert pairer.counters["left"].before_start == 1 and pairer.counters["left"].frames == 1
