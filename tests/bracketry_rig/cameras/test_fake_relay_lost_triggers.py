"""The fake camera's relay counts the software triggers the fake lost (injected clock, no sockets): a trigger waiting
behind a fill lasting seconds is not lost; one the idle fake leaves unfilled is, and is counted (the priming trigger
aside); clients read the count in the relay's register; the recording carries it and ``verify`` reports it as its own
kind."""

from __future__ import annotations

import struct
import time
from pathlib import Path
from types import SimpleNamespace

from bracketry.sim.clock import SteppedClock
from bracketry_base.recording import topics as T
from bracketry_base.recording.verify import format_report, verify_recording
from bracketry_rig.cameras.fake_relay import ACK_READREG, REG_TRIGGERS_LOST, FakeCameraRelay, Trigger, _Forwarded
from bracketry_rig.cameras.profiles import profile_kind
from bracketry_rig.cameras.triggering import PRIMING_EXPOSURE_US
from bracketry_rig.events import TriggerEvent
from bracketry_rig.pairing.pairer import PairedSet
from bracketry_rig.recording.recorder import Recorder, RecorderConfig


def relay(clock: SteppedClock) -> FakeCameraRelay:
    return FakeCameraRelay("127.0.0.1", ("127.0.0.1", 1), lambda _a: 0, serial="T1", seed=1, trigger_expiry_s=2.0,
                           clock_s=clock.now_s)


def forward(r: FakeCameraRelay, clock: SteppedClock, exposure_us: int) -> None:
    """A trigger forwarded to the fake now (as ``_trigger`` does with nothing outstanding)."""
    r._outstanding = _Forwarded(Trigger(int(clock.now_s() * 1e9), exposure_us), clock.now_s())


def test_a_trigger_behind_a_long_fill_waits_one_the_idle_fake_never_fills_is_counted() -> None:
    clock = SteppedClock(100.0)
    r = relay(clock)
    forward(r, clock, PRIMING_EXPOSURE_US)  # the priming trigger, never filled: expired but not counted
    clock.sleep(2.5)
    assert r.expire(clock.now_s()) and r.triggers_expired == 1 and r.triggers_lost == 0
    forward(r, clock, 1000)
    taken = r.take_trigger(software_triggered=True)  # the fill of pulse 0 starts ...
    assert taken is not None and taken.exposure_us == 1000
    forward(r, clock, 2000)  # ... pulse 1's trigger reaches the fake during the fill
    clock.sleep(5.0)  # a fill lasting seconds (a starved host, a frame not rendered yet)
    assert not r.expire(clock.now_s())
    r.fill_done()
    clock.sleep(1.9)
    assert not r.expire(clock.now_s())  # its expiry counts from the end of the fill
    taken = r.take_trigger(software_triggered=True)
    assert taken is not None and taken.exposure_us == 2000  # filled with its own stamp and exposure: not lost
    r.fill_done()
    forward(r, clock, 4000)  # pulse 2's trigger: the idle fake never fills it
    clock.sleep(2.1)
    assert r.expire(clock.now_s()) and r.triggers_lost == 1
    assert r.take_trigger(software_triggered=True) is None and r.fills_untriggered == 1  # a fill for no trigger
    r.fill_done()
    # the relay answers its register: a READREG ack of REG_TRIGGERS_LOST carries the count
    ack = struct.pack(">BBHHH", 0, 0, ACK_READREG, 4, 7) + struct.pack(">I", 0)
    assert struct.unpack_from(">I", r._rewrite_read_ack(ack, [REG_TRIGGERS_LOST]), 8)[0] == 1
    assert profile_kind("aravis_fake").lost_triggers_register == REG_TRIGGERS_LOST
    assert profile_kind("basler_ace2").lost_triggers_register is None


def test_lost_triggers_reach_the_recording_and_verify_as_their_own_kind(tmp_path: Path) -> None:
    rec = Recorder(tmp_path, "t", RecorderConfig(queue_max_items=1000),
                   metadata={"brackets_us": "1000,2000", "fps": "10.0"}).start()
    for k in range(20):
        ev = TriggerEvent(1, k, k % 2, 1000 << (k % 2), k * 100_000, 1_700_000_000_000_000_000 + k * 100_000_000)
        frames = {side: None if (side, k) == ("left", 7) else SimpleNamespace(
            side=side, frame_id=k + 1, frame_index=k, skipped_ids=0, status="success", image=None,
            cam_timestamp_ns=ev.t_start_host_ns, host_receive_ns=ev.t_start_host_ns, missing_packets=0)
            for side in T.SIDES}
        rec.put_event(ev)
        rec.put_set(PairedSet(k, ev, frames, ev.t_start_host_ns))
        rec.put_status({"frames_left": k, "lost_triggers_left": 1 if k >= 8 else 0})
        time.sleep(0.001)
    rec.stop()
    report = verify_recording(Path(rec.summary.files[0]))
    left = report.sides["left"]
    assert (left.drops, left.lost_triggers, report.sides["right"].lost_triggers) == (1, 1, 0)
    assert "camera left: 1 software trigger(s) lost by the camera (no frame for them: among the drops)" in \
        report.problems
    assert "lost software triggers 1" in format_report(report)
    assert report.as_dict()["sides"]["left"]["lost_triggers"] == 1
