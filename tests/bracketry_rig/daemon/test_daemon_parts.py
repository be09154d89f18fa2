"""The daemon's parts on their own, without devices: the stall watch and the backoff (pure), the event pump, the
sensor supervisor and the segment recorder over in-memory devices behind the daemon's device seams, and the
daemon's rules (a stalled camera leaves the recording, which goes on in a new segment). The real devices are
exercised by the simulated-rig tests (test_daemon_sim.py)."""

from __future__ import annotations

import threading
import time
from pathlib import Path
from typing import Any

import pytest

from bracketry_rig.cameras.camera import StreamStats
from bracketry_rig.cameras.triggering import camera_trigger
from bracketry_rig.daemon.config import RigConfig, parse_config
from bracketry_rig.daemon.pump import EventPump
from bracketry_rig.daemon.rig import DaemonOptions, RigDaemon
from bracketry_rig.daemon.segments import SegmentRecorder
from bracketry_rig.daemon.sensors import Backoff, LoopWatch, Progress, SensorSupervisor, StallWatch
from bracketry_rig.daemon.state import RigState, SensorState
from bracketry_rig.events import TriggerEvent


class MemTrigger:
    """A trigger device in memory: what it was told, and the health it reports."""

    def __init__(self) -> None:
        self.reboots, self.peer_lost = 0, False
        self.tables: list[tuple[int, list[int]]] = []
        self.started: list[int] = []
        self.stops = 0
        self.closed = self.fail_start = False

    def configure(self, period_us: int, exposures_us: Any) -> None:
        self.tables.append((period_us, list(exposures_us)))

    def start(self, session_id: int) -> None:
        if self.fail_start:
            raise OSError("NACK busy")
        self.started.append(session_id)

    def stop(self) -> None:
        self.stops += 1

    def close(self) -> None:
        self.closed = True


class MemCamera:
    """A camera in memory that streams nothing (``fail_start``: its stream cannot start; ``silent``: no GVCP)."""

    def __init__(self, side: str) -> None:
        self.side = side
        self.fail_start = self.silent = self.closed = False
        self.device = self

    def read_register(self, address: int) -> int:
        if self.silent:
            raise TimeoutError("GVCP timeout")
        return 0x00020000

    def set_exposure_us(self, exposure_us: float) -> None: ...

    def software_trigger(self) -> None: ...

    def start(self, on_frame: Any) -> None:
        if self.fail_start:
            raise RuntimeError("Controller privilege required")

    def stop(self) -> None: ...

    def close(self) -> None:
        self.closed = True

    def stats(self) -> StreamStats:
        return StreamStats()


class MemDevices:
    """The device seams of the daemon over in-memory devices; ``broken`` sides fail to open."""

    def __init__(self) -> None:
        self.trigger = MemTrigger()
        self.cameras: dict[str, MemCamera] = {}
        self.broken: set[str] = set()
        self.on_event: Any = None

    def open_camera(self, cc: Any, settings: Any) -> MemCamera:
        if cc.side in self.broken:
            raise OSError(f"{cc.address}: no answer")
        self.cameras[cc.side] = cam = MemCamera(cc.side)
        return cam

    def open_trigger(self, tc: Any, on_event: Any, period_us: int, brackets_us: Any) -> MemTrigger:
        self.on_event = on_event
        self.trigger = MemTrigger()
        self.trigger.configure(period_us, brackets_us)
        return self.trigger


def rig_config(tmp_path: Path) -> RigConfig:
    return parse_config({
        "rig": {"output_dir": str(tmp_path / "rec"), "brackets_ms": [1, 2, 4], "fps": 20, "min_free_mb": 0,
                "stop_free_mb": 0, "status_socket": str(tmp_path / "status.sock")},
        "panel": {"enabled": False},
        "cameras": [{"side": "left", "profile": "basler_ace2", "address": "10.0.0.2"},
                    {"side": "right", "profile": "basler_ace2", "address": "10.0.0.3"}],
    }, "test")


def event(session_id: int, seq: int) -> TriggerEvent:
    return TriggerEvent(session_id=session_id, trigger_seq=seq, bracket_index=seq % 3, exposure_us=1000 << (seq % 3),
                        t_start_device_us=seq * 50_000)


def test_stall_watch_blames_only_a_camera_that_pulses_reached() -> None:
    watch = StallWatch(stall_s=2.0, stall_pulses=3)

    def progress(frames: int, pulses: int, session_id: int = 1, failed: tuple[str, ...] = ()) -> Progress:
        return Progress(session_id, {"left": frames, "right": 0}, {"left": pulses, "right": 0}, frozenset(failed))

    assert watch.observe(progress(0, 0), ["left", "right"], 100.0) == ({}, None)
    assert watch.observe(progress(10, 10), ["left", "right"], 101.0) == ({"left": 10.0, "right": 0.0}, None)
    assert watch.observe(progress(10, 12), ["left"], 103.5) == ({"left": 0.0}, None)  # 2 pulses without a frame
    assert watch.observe(progress(10, 13), ["left"], 103.6)[1] == "left"  # 3 pulses and 2.6 s without a frame
    assert watch.observe(progress(0, 0), ["right"], 200.0)[1] is None  # right: no pulse ever reached it
    assert watch.observe(progress(0, 0, session_id=2), ["left"], 300.0) == ({}, None)  # a new acquisition
    assert watch.observe(progress(0, 0, session_id=2, failed=("left",)), ["left"], 302.5)[1] == "left"


def test_the_daemons_own_starvation_is_no_camera_stall() -> None:
    """A supervisor step 3.5 s after the previous one (period 1 s): the daemon itself was not run for 2.5 s, which
    count towards no camera's stall; a camera that stays silent once the daemon runs again is still blamed."""
    loop, watch = LoopWatch(period_s=1.0), StallWatch(stall_s=2.0, stall_pulses=3)

    def step(now_s: float, frames: int, pulses: int) -> str | None:
        progress = Progress(1, {"left": frames}, {"left": pulses}, frozenset())
        return watch.observe(progress, ["left"], now_s, loop.step(now_s))[1]

    assert step(100.0, 5, 5) is None and step(101.0, 5, 5) is None
    assert step(104.5, 5, 40) is None  # 35 pulses without a frame, but the daemon lost 2.5 s of the 3.5 s
    assert (loop.starved_windows, loop.starved_s, loop.longest_gap_s) == (1, 2.5, 3.5)
    assert step(105.0, 5, 45) == "left"  # 2.5 s of the daemon's own time without a frame: stalled
    unforgiving = StallWatch(stall_s=2.0, stall_pulses=3)  # the same steps with no starvation left out: blamed
    unforgiving.observe(Progress(1, {"left": 5}, {"left": 5}, frozenset()), ["left"], 101.0)
    assert unforgiving.observe(Progress(1, {"left": 5}, {"left": 40}, frozenset()), ["left"], 104.5)[1] == "left"
    on_time = LoopWatch(period_s=1.0)
    assert [on_time.step(t) for t in (0.0, 1.0, 2.9, 3.9)] == [0.0, 0.0, 0.0, 0.0]  # 1.9 s: late, not starved


def stall_daemon(tmp_path: Path, dev: MemDevices) -> RigDaemon:
    """A daemon on ``dev``, recording (its pump started, both buttons pressed), that calls a camera stalled after 2 s
    of pulses without frames and does not retry within a test (60 s back-off)."""
    daemon = RigDaemon(rig_config(tmp_path), DaemonOptions(open_camera=dev.open_camera, open_trigger=dev.open_trigger,
                                                           camera_stall_s=2.0, backoff_s=(60.0, 60.0)))
    daemon.pump.start()
    daemon.on_button("sensors")
    daemon.on_button("record")
    return daemon


def deliver_pulses(daemon: RigDaemon, dev: MemDevices, n: int) -> None:
    """``n`` trigger pulses of bracket 1 through the trigger's listener thread and the pump into the segment (the
    last event taken is delivered too)."""
    for seq in range(n):
        dev.on_event(event(1, seq))
    daemon.pump.settle(2.0)
    with daemon.pump.hold():
        pass


def test_daemon_declares_no_fault_for_a_window_it_was_starved_in(tmp_path: Path) -> None:
    """Injected clock: the daemon's supervisor steps at 100 s, then (starved) at 103.5 s; pulses reached the
    cameras, no frame came and the trigger's heartbeat was not read: nothing goes ERR. Steps on time afterwards blame
    the camera still silent, then a trigger still silent."""
    dev = MemDevices()
    daemon = stall_daemon(tmp_path, dev)
    try:
        daemon.supervise_once(now_s=100.0)
        deliver_pulses(daemon, dev, 3)
        dev.trigger.peer_lost = True
        daemon.supervise_once(now_s=103.5)  # 3.5 s after the previous step: the daemon itself was starved
        snap = daemon.state.snapshot()
        assert all(snap.states[k] == SensorState.REC for k in ("cam_left", "cam_right", "trigger")), snap.states
        assert snap.counters["daemon_starved"] == 1 and daemon.segment_index == 1
        dev.trigger.peer_lost = False  # its heartbeats were only waiting to be read
        daemon.supervise_once(now_s=104.5)
        assert daemon.state.snapshot().states["cam_left"] == SensorState.REC  # 2.0 s of the daemon's own time
        daemon.supervise_once(now_s=105.5)  # 3.0 s of its own time, 3 pulses, no frame: stalled
        assert daemon.state.snapshot().states["cam_left"] == SensorState.ERR
        trigger = daemon.sensors.trigger
        assert isinstance(trigger, MemTrigger)
        trigger.peer_lost = True
        assert daemon.sensors.check_trigger(starved_s=2.5) is None  # starved: looked at again next step
        assert daemon.sensors.check_trigger() == "lost (no heartbeat)"  # on time: a silent trigger is a fault
        assert daemon.state.snapshot().states["trigger"] == SensorState.ERR
    finally:
        daemon.close()


def test_backoff_doubles_with_jitter_up_to_its_maximum_and_resets() -> None:
    b = Backoff(0.5, 2.0)
    assert b.due(0.0)
    delays = []
    for _ in range(4):
        b.failed(now_s=10.0)
        delays.append(b.next_t - 10.0)
    for d, nominal in zip(delays, [0.5, 1.0, 2.0, 2.0], strict=True):
        assert 0.8 * nominal - 1e-9 <= d <= 1.2 * nominal + 1e-9
    assert not b.due(10.0 + 0.8 * 2.0 - 0.01) and b.due(10.0 + 1.2 * 2.0)
    b.reset()
    assert b.due(0.0) and b.delay_s == 0.5


def test_event_pump_delivers_in_order_counts_overflow_and_holds() -> None:
    got: list[TriggerEvent] = []
    dropped: list[int] = []
    pump = EventPump(got.append, lambda: dropped.append(1), max_events=2)
    for seq in range(3):
        pump.put(event(1, seq))
    assert len(dropped) == 1
    with pump.hold() as take_queued:  # not started: the closer takes what is queued
        assert [e.trigger_seq for e in take_queued()] == [0, 1]
    pump.start()
    try:
        pump.put(event(1, 3))
        pump.settle(2.0)  # queue empty: the pump took it ...
        with pump.hold():
            assert [e.trigger_seq for e in got] == [3]  # ... and delivered it before anyone can hold the pump
        with pump.hold() as take_queued:
            pump.put(event(1, 4))
            threading.Event().wait(0.15)
            assert [e.trigger_seq for e in got] == [3]  # held: nothing delivered
            assert [e.trigger_seq for e in take_queued()] == [4]
    finally:
        pump.close()


def test_sensor_supervisor_up_errors_reconnect_trigger_reboot_and_idle_camera(tmp_path: Path) -> None:
    cfg, state, dev = rig_config(tmp_path), RigState(), MemDevices()
    dev.broken.add("right")
    sup = SensorSupervisor(lambda: cfg, state, lambda ev: None, backoff_s=(0.0, 0.0), idle_check_s=0.0,
                           open_camera=dev.open_camera, open_trigger=dev.open_trigger)
    assert not sup.up()
    snap = state.snapshot()
    assert snap.states["cam_left"] == snap.states["trigger"] == SensorState.IDLE
    assert snap.states["cam_right"] == SensorState.ERR and "no answer" in snap.errors["cam_right"]
    assert snap.message == "SENSOR ERROR" and sup.missing_sides() == ["right"] and sup.on
    assert dev.trigger.tables == [(50_000, [1000, 2000, 4000])]
    assert not sup.reconnect()  # right still broken
    dev.broken.clear()
    assert sup.reconnect() and set(sup.cameras()) == {"left", "right"}
    assert state.state("cam_right") == SensorState.IDLE

    first = dev.trigger
    assert sup.check_trigger() is None
    first.reboots = 1
    assert sup.check_trigger() == "rebooted" and sup.trigger is None and first.closed
    assert state.snapshot().errors["trigger"] == "rebooted"
    assert sup.reconnect() and sup.trigger is dev.trigger is not first

    dev.cameras["left"].silent = True
    sup.check_idle_cameras(now_s=1000.0)
    assert "left" not in sup.cameras() and state.snapshot().errors["cam_left"].startswith("no answer")
    sup.down()  # the devices up go OFF; a camera in ERR keeps its error
    assert state.state("cam_right") == state.state("trigger") == SensorState.OFF
    assert state.state("cam_left") == SensorState.ERR
    assert not sup.on and not sup.reconnect()


def test_segment_recorder_goes_on_without_a_camera_that_cannot_stream(tmp_path: Path) -> None:
    cfg, state, dev = rig_config(tmp_path), RigState(), MemDevices()
    sup = SensorSupervisor(lambda: cfg, state, lambda ev: None, open_camera=dev.open_camera,
                           open_trigger=dev.open_trigger)
    sup.up()
    pump = EventPump(lambda ev: None, lambda: None)
    profiles = {cc.side: cc.profile for cc in cfg.cameras}
    rec = SegmentRecorder(lambda: cfg, state, sup, pump, lambda cams: camera_trigger(cams, profiles))
    dev.cameras["left"].fail_start = True
    assert rec.begin() and rec.recording and rec.segment_index == 1
    snap = state.snapshot()
    assert snap.states["cam_left"] == SensorState.ERR and "Controller privilege" in snap.errors["cam_left"]
    assert snap.states["cam_right"] == snap.states["trigger"] == SensorState.REC
    assert snap.message == "REC: LEFT CAM ERR" and dev.trigger.started == [1]
    for seq in range(4):
        rec.deliver(event(1, seq))
    rec.deliver(event(7, 0))  # another trigger session's event: not this segment's
    progress = rec.progress()
    assert progress is not None and progress.pulses == {"right": 4} and state.snapshot().counters["trigger_events"] == 4
    summary = rec.end()
    assert summary is not None and summary["dir"].endswith("seg01") and summary["status"]["pairing"]
    assert not rec.recording and rec.progress() is None and dev.trigger.stops >= 1
    assert state.snapshot().message == "SAVED" and state.state("cam_right") == SensorState.IDLE

    dev.trigger.fail_start = True  # a trigger that refuses START: the segment closes, the trigger goes ERR
    assert not rec.begin() and state.snapshot().message == "REC WAITING" and rec.recording
    assert state.snapshot().errors["trigger"] == "START failed: NACK busy" and sup.trigger is None
    assert len(rec.segments) == 2 and rec.progress() is None


def test_daemon_closes_a_segment_whose_camera_stalled_and_records_on_without_it(tmp_path: Path) -> None:
    dev = MemDevices()
    daemon = stall_daemon(tmp_path, dev)
    try:
        assert daemon.recording and daemon.segment_index == 1
        daemon.supervise_once(now_s=100.0)  # marks
        deliver_pulses(daemon, dev, 3)
        daemon.supervise_once(now_s=101.0)
        daemon.supervise_once(now_s=102.0)
        daemon.supervise_once(now_s=102.5)  # 3 pulses, 2.5 s, no frame: the left camera stalled
        snap = daemon.state.snapshot()
        assert snap.states["cam_left"] == SensorState.ERR and snap.errors["cam_left"] == "no frames"
        assert daemon.segment_index == 2 and len(daemon.segments) == 1 and dev.trigger.started == [1, 2]
        assert snap.message == "REC: LEFT CAM ERR" and set(daemon.cameras) == {"right"}
        daemon.on_button("record")
        assert not daemon.recording and len(daemon.segments) == 2
    finally:
        daemon.close()
    assert dev.trigger.closed
    deadline = time.monotonic() + 10.0
    while not dev.cameras["left"].closed and time.monotonic() < deadline:
        time.sleep(0.05)  # the lost camera is closed in the background
    assert dev.cameras["left"].closed
    assert all(daemon.state.state(s) == SensorState.OFF for s in ("cam_right", "trigger"))


@pytest.mark.parametrize("button", ["sensors", "record"])
def test_daemon_buttons_without_devices_show_errors(tmp_path: Path, button: str) -> None:
    dev = MemDevices()
    dev.broken.update({"left", "right"})
    daemon = RigDaemon(rig_config(tmp_path), DaemonOptions(open_camera=dev.open_camera, open_trigger=dev.open_trigger))
    try:
        daemon.on_button(button)
        snap = daemon.state.snapshot()
        assert snap.states["cam_left"] == snap.states["cam_right"] == SensorState.ERR
        assert snap.message == ("SENSOR ERROR" if button == "sensors" else "REC WAITING")
        assert daemon.recording == (button == "record") and daemon.segment_index == 0
    finally:
        daemon.close()


def test_a_sigterm_handed_to_another_thread_stops_the_daemons_wait(tmp_path: Path) -> None:
    """The kernel may hand a process's SIGTERM to any of its threads; Python runs the handler in the main thread
    only. The signal goes to a helper thread once the main thread sleeps in ``RigDaemon.wait``: the wait must
    return True (stop requested), not sleep out its timeout."""
    import linecache
    import signal
    import sys

    from bracketry_rig.daemon.rig import install_signal_handlers

    dev = MemDevices()
    daemon = RigDaemon(rig_config(tmp_path), DaemonOptions(open_camera=dev.open_camera, open_trigger=dev.open_trigger))
    main = threading.get_ident()

    def blocked_at() -> tuple[int, int] | None:
        """Where the main thread is, if at the lock acquire of threading's Condition.wait: (frame id, last op)."""
        frame = sys._current_frames().get(main)
        if frame is None or frame.f_code.co_name != "wait" or not frame.f_code.co_filename.endswith("threading.py"):
            return None
        line = linecache.getline(frame.f_code.co_filename, frame.f_lineno)
        return (id(frame), frame.f_lasti) if "waiter.acquire(" in line else None

    def signal_from_a_helper_thread() -> None:
        seen = None
        while True:  # until the main thread sleeps in the lock: at the acquire twice, with the GIL let go between
            now = blocked_at()
            if now is not None and now == seen:
                break
            seen = now
            time.sleep(0.001)
        signal.pthread_kill(threading.get_ident(), signal.SIGTERM)

    restore = install_signal_handlers(daemon)
    helper = threading.Thread(target=signal_from_a_helper_thread, daemon=True)
    try:
        helper.start()
        assert daemon.wait(timeout_s=30.0) is True
    finally:
        helper.join(timeout=5.0)
        restore()
        daemon.close()
