"""The daemon's segment recorder: the recording as a sequence of segments, and the monitor's preview session.

A recording is a sequence of *segments* (``<output_dir>/<rec_name>/segNN/``): one trigger session (trigger_seq
restarts at 0) and one set of split MCAP files each, verified on its own. A *preview session* (monitor on, sensors
up, not recording) is the same ``RecordingSession`` with a ``DiscardSink``: it feeds only the monitor's hub. At most
one of them is open: an :class:`Acquisition` (the session, its camera trigger adapter, its pulse counts).

Seams: the sensors (:class:`Sensors`, the ``SensorSupervisor``) give the cameras and the trigger and take the
failures; the event pump (:class:`EventHold`) is held while an acquisition closes; ``new_camera_trigger`` makes the
host's side of the pulses for a set of cameras (``bracketry_rig.cameras.triggering.camera_trigger``).

Threads: the methods that open, close or change the recording run under the daemon's action lock and hold the
recorder's own lock (order: the action lock, this lock, the sensors' lock, the pump's hold). ``deliver`` runs on the
event pump's thread, without this lock: it reads ``_open`` once, and ``_open`` only changes while the pump is held
(so an event is delivered to the acquisition that was open, or handed over by the closer). The read-only methods
(``progress``, ``counters``, ``last_status``: supervisor and monitor threads) read ``_open`` once, lock-free.
"""

from __future__ import annotations

import contextlib
import functools
import logging
import shutil
import threading
import time
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from typing import Any, Concatenate, ParamSpec, Protocol, TypeVar

from bracketry_base.errors import BracketryError
from bracketry_base.recording.calibration import read_calibration
from bracketry_rig.cameras.triggering import CameraTrigger
from bracketry_rig.daemon.config import RigConfig
from bracketry_rig.daemon.disk import free_mb
from bracketry_rig.daemon.sensors import Camera, Progress, TriggerDevice
from bracketry_rig.daemon.state import RigState, SensorState
from bracketry_rig.events import TriggerEvent
from bracketry_rig.pairing.pairer import PairedSet
from bracketry_rig.recording.recorder import Recorder, RecorderConfig
from bracketry_rig.recording.session import DiscardSink, RecordingSession, SessionStartError

log = logging.getLogger("bracketry_rig.daemon")


class Sensors(Protocol):
    """What the segment recorder needs of the sensors (``bracketry_rig.daemon.sensors.SensorSupervisor``)."""

    @property
    def trigger(self) -> TriggerDevice | None: ...

    def cameras(self) -> dict[str, Camera]: ...

    def missing_sides(self) -> list[str]: ...

    def camera_failed(self, side: str, error: str) -> None: ...

    def trigger_failed(self, error: str) -> None: ...

    def set_states(self, state: SensorState) -> None: ...


class EventHold(Protocol):
    """What the segment recorder needs of the event pump (``bracketry_rig.daemon.pump.EventPump``)."""

    def settle(self, timeout_s: float = 2.0) -> None: ...

    def hold(self) -> contextlib.AbstractContextManager[Callable[[], list[TriggerEvent]]]: ...


NewCameraTrigger = Callable[[Mapping[str, Camera]], CameraTrigger]
P = ParamSpec("P")
R = TypeVar("R")


def _locked(method: Callable[Concatenate[SegmentRecorder, P], R]) -> Callable[Concatenate[SegmentRecorder, P], R]:
    """Run a method of the segment recorder holding its lock."""

    @functools.wraps(method)
    def wrapper(self: SegmentRecorder, *args: P.args, **kwargs: P.kwargs) -> R:
        with self._lock:
            return method(self, *args, **kwargs)

    return wrapper


@dataclass
class Acquisition:
    """One open session (a recording segment, or previews when ``recorder`` is None) and its trigger session."""

    session: RecordingSession
    recorder: Recorder | None
    session_id: int
    camera_trigger: CameraTrigger
    pulses: dict[str, int] = field(default_factory=dict)  # side -> pulses meant for it (written by the pump only)
    armed_frames: dict[str, int] = field(default_factory=dict)  # side -> frames received before the first pulse

    def frames_to_wait_for(self) -> dict[str, int]:
        """Frames each camera will have delivered once the pulses fired so far arrived (priming frames included)."""
        fired = self.camera_trigger.frames_expected
        return {side: self.armed_frames.get(side, 0) + fired for side in self.session.cameras}

    def deliver(self, event: TriggerEvent, state: RigState) -> None:
        """The pulse reaches the cameras (a camera that failed a software trigger is skipped until the next
        acquisition; the stall check takes it down), then its event goes to the session."""
        if event.session_id != self.session_id:
            return
        for side in self.camera_trigger.fire(event, self.session.cameras):
            self.pulses[side] += 1
        self.session.on_trigger_event(event)
        state.count("trigger_events")

    def drop_camera(self, side: str) -> None:
        """A camera left: no further pulse for it; the session no longer waits for it (readers keep the old dict)."""
        self.camera_trigger.remove(side)
        self.session.cameras = {s: c for s, c in self.session.cameras.items() if s != side}


@dataclass
class SegmentOptions:
    """``calibration``/``metadata``: written into every segment's files."""

    calibration: dict[str, dict[str, Any]] = field(default_factory=dict)
    metadata: dict[str, str] = field(default_factory=dict)


class SegmentRecorder:
    """Recording segments and previews over the cameras and trigger of ``sensors``."""

    def __init__(self, config: Callable[[], RigConfig], state: RigState, sensors: Sensors, pump: EventHold,
                 new_camera_trigger: NewCameraTrigger, options: SegmentOptions | None = None) -> None:
        self._config = config
        self.state = state
        self.sensors = sensors
        self.pump = pump
        self.new_camera_trigger = new_camera_trigger
        self.options = options or SegmentOptions()
        self.recording = False
        self.rec_name: str | None = None
        self.segment_index = 0
        self.segments: list[dict[str, Any]] = []  # summaries of the closed segments
        self.calibration_files: dict[str, str] = {}  # the open recording's calibration (rig.calibration)
        self.preview_tap: Callable[[PairedSet], None] | None = None  # previews only with a tap (the monitor's hub)
        self.closing = False  # no preview session between the recording's end and the sensors' shutdown
        self._open: Acquisition | None = None
        self._session_id = 0
        self._lock = threading.RLock()  # held by every method that opens, closes or changes the recording

    # ------------------------------------------------------------------------------------------------ reading
    @property
    def previewing(self) -> bool:
        o = self._open
        return o is not None and o.recorder is None

    @property
    def is_open(self) -> bool:
        return self._open is not None

    def progress(self) -> Progress | None:
        """Frames and pulses per camera of the open acquisition (None when none is open). Frames are counted as they
        arrive from each camera (``RecordingSession.frames_received``), not once paired: a pairing thread behind on
        a loaded host is not a silent camera."""
        o = self._open
        if o is None:
            return None
        return Progress(o.session_id, o.session.received(), dict(o.pulses), o.camera_trigger.failed)

    def open_session(self) -> RecordingSession | None:
        o = self._open
        return o.session if o is not None else None

    def recorder_error(self) -> str | None:
        o = self._open
        return o.recorder.error if o is not None and o.recorder is not None else None

    # ------------------------------------------------------------------------------------------------ events
    def deliver(self, event: TriggerEvent) -> None:
        """A TRIGGER event (event pump thread) to the open acquisition."""
        o = self._open
        if o is not None:
            o.deliver(event, self.state)

    # ------------------------------------------------------------------------------------------------ recording
    def free_mb_to_start(self) -> int | None:
        """Free space of the output folder when too low to start a recording (``min_free_mb``), else None."""
        cfg = self._config()
        free = free_mb(cfg.output_dir)
        self.state.set_free_disk_mb(free)
        if free >= cfg.min_free_mb:
            return None
        self.state.set_message(f"DISK LOW {free // 1024}GB" if free >= 1024 else f"DISK LOW {free}MB")
        log.error("recording refused: %d MB free < min_free_mb %d", free, cfg.min_free_mb)
        return free

    @_locked
    def begin(self) -> bool:
        """A new recording; its first segment starts when the sensors allow (True when it did)."""
        cfg = self._config()
        cfg.output_dir.mkdir(parents=True, exist_ok=True)
        self.rec_name = time.strftime("rec_%Y%m%d_%H%M%S")
        self.calibration_files = self._read_calibration(cfg)
        self.recording = True
        self.segment_index = 0
        self.state.set_recording(str(cfg.output_dir / self.rec_name))
        started = self.segment_start()
        if not started:
            self.state.set_message("REC WAITING")
        return started

    @staticmethod
    def _read_calibration(cfg: RigConfig) -> dict[str, str]:
        """The files of ``rig.calibration`` every segment of the recording carries ({} without one; a folder that
        became unreadable since the config was checked: logged, the recording goes on without it)."""
        if cfg.calibration is None:
            return {}
        try:
            files = read_calibration(cfg.calibration)
        except BracketryError as exc:
            log.error("recording without its calibration: %s", exc)
            return {}
        log.info("calibration %s attached to the recording", cfg.calibration)
        return files

    @_locked
    def end(self) -> dict[str, Any] | None:
        """Close the open segment cleanly and end the recording; returns the segment's summary."""
        summary = self.segment_stop()
        self.recording = False
        self.state.set_recording(None)
        self.sensors.set_states(SensorState.IDLE)
        self.state.set_message("SAVED")
        log.info("recording %s stopped after %d segment(s)", self.rec_name, len(self.segments))
        return summary

    @_locked
    def segment_start(self) -> bool:
        """Open the next segment with the cameras that stream; a camera that cannot goes ERR (the sensors reconnect
        it) and the segment starts without it. True when a segment started."""
        while True:
            cameras, trigger = self.sensors.cameras(), self.sensors.trigger
            if trigger is None or not cameras:
                return False
            try:
                acquisition = self._open_segment(cameras)
                break
            except SessionStartError as exc:
                log.error("segment start: %s", exc)  # names the camera
                self.sensors.camera_failed(exc.side, str(exc))
        if not self._start_trigger(acquisition, trigger, "START"):
            return False
        self.sensors.set_states(SensorState.REC)
        missing = self.sensors.missing_sides()
        self.state.set_message(f"REC: {missing[0].upper()} CAM ERR" if missing else "RECORDING")
        log.info("segment %s_seg%02d started: sides=%s session_id=%d", self.rec_name, self.segment_index,
                 ",".join(acquisition.session.cameras), acquisition.session_id)
        return True

    def _open_segment(self, cameras: dict[str, Camera]) -> Acquisition:
        """The next segment's recorder and session (raises SessionStartError: the empty segment is removed)."""
        cfg = self._config()
        index = self.segment_index + 1
        seg_dir = cfg.output_dir / str(self.rec_name) / f"seg{index:02d}"
        rcfg = RecorderConfig(split_bytes=cfg.split_size_mb << 20, split_s=cfg.split_minutes * 60.0,
                              sides=tuple(sorted(cameras, key=lambda s: s != "left")))
        metadata = {"rig_brackets_us": ",".join(map(str, cfg.brackets_us)), "rig_period_us": str(cfg.period_us),
                    "segment": str(index), "sides": ",".join(rcfg.sides), **self.options.metadata}
        recorder = Recorder(seg_dir, f"{self.rec_name}_seg{index:02d}", rcfg, metadata=metadata,
                            calibration=self.options.calibration,
                            calibration_files=self.calibration_files).start()
        try:
            acquisition = self._start_session(cameras, recorder)
        except SessionStartError:
            with contextlib.suppress(Exception):
                recorder.stop()
            shutil.rmtree(seg_dir, ignore_errors=True)  # it holds no frame
            raise
        self.segment_index = index
        return acquisition

    @_locked
    def segment_stop(self) -> dict[str, Any] | None:
        """Close the open segment cleanly (the cameras stay open and configured); returns its summary."""
        o = self._open
        if o is None or o.recorder is None:
            return None
        status = self._close()
        rsum = o.recorder.summary
        summary = {"dir": str(o.recorder.out_dir), "files": list(rsum.files),
                   "frames_written": dict(rsum.frames_written), "status": status, "overflows": rsum.overflows,
                   "error": rsum.error}
        self.segments.append(summary)
        log.info("segment closed: files=%s frames=%s", rsum.files, rsum.frames_written)
        return summary

    @_locked
    def restart_segment(self, reason: str) -> None:
        """Close the open segment cleanly and start a new one with the sensors that work."""
        log.warning("restarting recording segment: %s", reason)
        self.segment_stop()
        if not self.segment_start():
            self.state.set_message("REC WAITING")

    # ------------------------------------------------------------------------------------------------ previews
    @_locked
    def preview_start(self) -> bool:
        """Open the preview session (a tap, sensors up, not recording): the cameras stream on the trigger's pulses,
        paired sets go only to the tap, nothing is written. True when it started."""
        while True:
            cameras, trigger = self.sensors.cameras(), self.sensors.trigger
            if (self.preview_tap is None or self.closing or self.recording or self._open is not None
                    or trigger is None or not cameras):
                return False
            try:
                acquisition = self._start_session(cameras, None)
                break
            except SessionStartError as exc:
                log.error("preview start: %s", exc)
                self.sensors.camera_failed(exc.side, str(exc))
        if not self._start_trigger(acquisition, trigger, "START (previews)"):
            return False
        log.info("previews started: sides=%s session_id=%d", ",".join(acquisition.session.cameras),
                 acquisition.session_id)
        return True

    @_locked
    def preview_stop(self) -> bool:
        """Close the preview session (the cameras stop, stay open and configured); True when one was open."""
        if not self.previewing:
            return False
        self._close()
        for side in self.sensors.cameras():
            self.state.set_fps(side, 0.0)
        log.info("previews stopped")
        return True

    @_locked
    def previews_again(self) -> None:
        """Restart the previews (a camera came back or left, a new bracket table)."""
        self.preview_stop()
        self.preview_start()

    # ------------------------------------------------------------------------------------------------ acquisitions
    def _start_session(self, cameras: dict[str, Camera], recorder: Recorder | None) -> Acquisition:
        """Start the cameras' session and arm their trigger adapter (raises SessionStartError)."""
        cfg = self._config()
        camera_trigger = self.new_camera_trigger(cameras)
        sink: Recorder | DiscardSink = recorder if recorder is not None else DiscardSink(cfg.output_dir)
        session = RecordingSession(dict(cameras), sink, disk_path=cfg.output_dir,
                                   initial_alignment=camera_trigger.initial_alignment, tap=self.preview_tap).start()
        camera_trigger.arm()  # e.g. the fake camera loses the first software trigger after AcquisitionStart
        self._session_id = (self._session_id + 1) & 0xFFFFFFFF or 1
        armed = {side: session.frames_received.get(side, 0) for side in cameras}  # e.g. a priming frame
        return Acquisition(session, recorder, self._session_id, camera_trigger, dict.fromkeys(cameras, 0), armed)

    def _start_trigger(self, acquisition: Acquisition, trigger: TriggerDevice, what: str) -> bool:
        """Make ``acquisition`` the open one and START the trigger; on failure it is closed and the trigger ERR."""
        with self.pump.hold():
            self._open = acquisition
        try:
            trigger.start(acquisition.session_id)
        except Exception as exc:
            log.error("trigger %s failed: %s", what, exc)
            if acquisition.recorder is not None:
                self.segment_stop()
            else:
                self.preview_stop()
            self.sensors.trigger_failed(f"START failed: {exc}")
            return False
        return True

    def _close(self) -> dict[str, Any]:
        """Stop the trigger, deliver its last events, stop the open session (recording or previews)."""
        o = self._open
        assert o is not None
        trigger = self.sensors.trigger
        if trigger is not None:
            try:
                trigger.stop()  # events of every pulse before STOP arrive before its ACK
            except Exception as exc:
                log.warning("trigger STOP failed: %s", exc)
        self.pump.settle(2.0)  # the pump delivers the last events (and fires their software triggers)
        with self.pump.hold() as take_queued:  # an event the pump holds reaches this session before it stops
            self._open = None
            for event in take_queued():
                o.deliver(event, self.state)
        # the last pulses' buffers, also under load
        return o.session.stop(drain_s=3.0, expect_frames=o.frames_to_wait_for())

    @_locked
    def drop_camera(self, side: str) -> None:
        """A camera of the open acquisition is lost: it leaves the acquisition at once."""
        o = self._open
        if o is not None:
            o.drop_camera(side)

    def counters(self) -> dict[str, Any]:
        """Pairing counters per side of the open acquisition (``bracketry_rig.pairing.pairer.SideCounters``)."""
        o = self._open
        return dict(o.session.pairer.counters) if o is not None else {}

    def last_status(self) -> dict[str, Any]:
        """The open session's latest rig status (RigStatus fields), empty when none is open."""
        o = self._open
        return dict(o.session.last_status) if o is not None else {}
