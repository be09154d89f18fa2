"""The rig daemon's core: sensors, recording segments, buttons, faults and the panel, in one object.

Threads: a supervisor (1 Hz: free disk, FPS, device health, reconnection with backoff, systemd watchdog), an event
pump (TRIGGER events -> software trigger of fake cameras when simulated -> pairing), the panel client, the status
socket, and the threads of the camera, pairing and recorder layers.

A recording is a sequence of *segments* (``<output_dir>/<rec_name>/segNN/``): one trigger session (trigger_seq
restarts at 0) and one set of split MCAP files each, verified on its own.
When a device fails, the open segment is closed cleanly (nothing already recorded is lost), the failed sensor shows
ERR, recording continues with what still works, and a new segment with every sensor starts when it is back.

With the browser monitor on (config ``[monitor]``), sensors that are up but not recording still stream: a *preview
session* (the same ``RecordingSession`` with a ``DiscardSink``: nothing is written) feeds only the monitor's preview
hub, triggered by the current bracket table. A recording closes it before its first segment starts and reopens it
when it stops; a new bracket table restarts it. With the monitor off there is no preview session.
"""

from __future__ import annotations

import contextlib
import dataclasses
import logging
import queue
import random
import shutil
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from bracketry.cameras.triggering import CameraTrigger, LineTrigger, camera_trigger
from bracketry.daemon.config import RigConfig
from bracketry.daemon.disk import free_mb
from bracketry.daemon.sdnotify import Notifier
from bracketry.daemon.state import RigState, SensorState
from bracketry.daemon.status import StatusServer
from bracketry.errors import BracketryError
from bracketry.events import TriggerEvent

log = logging.getLogger("bracketry.daemon")

CAM_SENSOR = {"left": "cam_left", "right": "cam_right"}
#: a recording camera is stalled when this many pulses reached it without a frame (and camera_stall_s passed)
STALL_PULSES = 3
#: GigE Vision bootstrap register "Version" (read to see that an idle camera still answers GVCP)
GEV_VERSION_REGISTER = 0x0000


@dataclass
class DaemonOptions:
    """Run-time options that are not part of the rig config.

    ``width``/``height``: region of interest (None keeps the camera's); ``camera_stall_s``: a recording camera
    with no frame for this long is in ERR; ``idle_check_s``: period of the GVCP check of idle cameras;
    ``backoff_s``: first and maximum reconnection delays.
    """

    width: int | None = None
    height: int | None = None
    camera_stall_s: float = 2.0
    idle_check_s: float = 2.0
    backoff_s: tuple[float, float] = (0.5, 8.0)
    status_socket: Path | None = None
    calibration: dict[str, dict[str, Any]] = field(default_factory=dict)
    metadata: dict[str, str] = field(default_factory=dict)


class _Backoff:
    """Exponential backoff with jitter between reconnection attempts of one device."""

    def __init__(self, first_s: float, max_s: float) -> None:
        self.first_s, self.max_s = first_s, max_s
        self.delay_s = first_s
        self.next_t = 0.0

    def due(self) -> bool:
        return time.monotonic() >= self.next_t

    def failed(self) -> None:
        self.next_t = time.monotonic() + self.delay_s * (0.8 + 0.4 * random.random())
        self.delay_s = min(self.delay_s * 2.0, self.max_s)

    def reset(self) -> None:
        self.delay_s = self.first_s
        self.next_t = 0.0


class RigDaemon:
    """The rig: ``sensors_up``/``sensors_down``, ``start_recording``/``stop_recording``, ``on_button``, ``close``."""

    def __init__(self, config: RigConfig, options: DaemonOptions | None = None) -> None:
        self.config = config
        self.options = options or DaemonOptions()
        self.state = RigState()
        self.notifier = Notifier()
        self._lock = threading.RLock()
        self._stop = threading.Event()
        self.cameras: dict[str, Any] = {}
        self.trigger: Any = None
        self.panel: Any = None
        self.status_server: StatusServer | None = None
        self.sensors_on = False
        self.recording = False
        self.rec_name: str | None = None
        self.segment_index = 0
        self.segments: list[dict[str, Any]] = []
        self._session: Any = None
        self._recorder: Any = None
        self._session_id = 0
        self._events: queue.Queue[TriggerEvent | None] = queue.Queue(maxsize=10_000)
        self._pump: threading.Thread | None = None
        self._supervisor: threading.Thread | None = None
        self._backoff = {name: _Backoff(*self.options.backoff_s) for name in ("trigger", "left", "right", "panel")}
        self._last_frames: dict[str, tuple[float, int, int]] = {}  # side -> (t_s, frames, pulses) at last frame
        self._last_idle_check = 0.0
        self._pulses: dict[str, int] = {}  # side -> pulses delivered to it in this segment
        self._trigger_reboots_seen = 0
        self._deliver_lock = threading.Lock()
        self._camera_trigger: CameraTrigger = LineTrigger(())
        self._pump_paused = threading.Event()
        self.monitor_hub: Any = None  # the browser monitor (config [monitor]), see bracketry.daemon.monitor_link
        self.monitor_server: Any = None
        self.previewing = False  # the open session is a preview session (monitor on, sensors up, not recording)
        self._closing = False

    # ------------------------------------------------------------------------------------------------ lifecycle
    def start(self) -> RigDaemon:
        """Start the monitor, the status socket, the panel link and the supervisor; sensors stay OFF until SENSORS."""
        if self.config.monitor is not None:  # before the status socket: a daemon that answers serves its monitor
            from bracketry.daemon.monitor_link import start_monitor

            start_monitor(self)
        sock = self.options.status_socket or self.config.status_socket
        try:
            self.status_server = StatusServer(sock, self.handle_request)
        except OSError as exc:
            log.warning("status socket %s unavailable: %s", sock, exc)
        self._connect_panel()
        self.state.set_free_disk_mb(free_mb(self.config.output_dir))
        self._pump = threading.Thread(target=self._pump_events, name="event-pump", daemon=True)
        self._pump.start()
        self._supervisor = threading.Thread(target=self._supervise, name="supervisor", daemon=True)
        self._supervisor.start()
        self.notifier.ready()
        log.info("daemon started: output_dir=%s brackets_us=%s period_us=%d", self.config.output_dir,
                 self.config.brackets_us, self.config.period_us)
        return self

    def close(self) -> None:
        """Stop recording cleanly (files finished), close every device, the panel and the status socket."""
        self.notifier.stopping()
        with self._lock:
            self._closing = True  # no preview session between the recording's end and the sensors' shutdown
            if self.recording:
                self.stop_recording()
            self.sensors_down()
        self._stop.set()
        with contextlib.suppress(queue.Full):
            self._events.put_nowait(None)
        for t in (self._pump, self._supervisor):
            if t is not None:
                t.join(timeout=5.0)
        if self.panel is not None:
            with contextlib.suppress(Exception):
                self.panel.stop()
                self.panel.link.close()
            self.panel = None
        if self.status_server is not None:
            self.status_server.close()
            self.status_server = None
        if self.monitor_server is not None:
            from bracketry.daemon.monitor_link import stop_monitor

            stop_monitor(self)
        log.info("daemon stopped")

    def wait(self, timeout_s: float | None = None) -> bool:
        """Block until :meth:`request_stop` (or ``timeout_s``); True if stop was requested."""
        return self._stop.wait(timeout_s)

    def request_stop(self) -> None:
        """Ask :meth:`wait` to return (e.g. from a SIGTERM handler); :meth:`close` does the work."""
        self._stop.set()

    # ------------------------------------------------------------------------------------------------ panel
    def _connect_panel(self) -> None:
        if not self.config.panel.enabled:
            return
        from bracketry.panel.client import connect, snapshot_fields

        try:
            self.panel = connect(self.config.panel.port, lambda: snapshot_fields(self.state.snapshot()),
                                 self._on_panel_button, rate_hz=self.config.panel.refresh_hz,
                                 baudrate=self.config.panel.baudrate)
            self._backoff["panel"].reset()
            log.info("panel connected on %s", self.config.panel.port)
        except Exception as exc:
            self.panel = None
            self._backoff["panel"].failed()
            log.warning("panel on %s unavailable: %s", self.config.panel.port, exc)

    def _on_panel_button(self, ev: Any) -> None:
        name = "sensors" if ev.button == 1 else "record"
        threading.Thread(target=self._button_thread, args=(name, ev.action == 2), name="button", daemon=True).start()

    def _button_thread(self, button: str, long_press: bool) -> None:
        try:
            self.on_button(button, long_press)
        except Exception:  # the daemon survives any failure of a button action; the panel shows it
            log.exception("button %s failed", button)
            self.state.set_message(f"{button.upper()} FAILED")

    def on_button(self, button: str, long_press: bool = False) -> None:
        """SENSORS: bring sensors up (or down when idle and already up); RECORD: start/stop recording."""
        log.info("button %s%s", button, " (long)" if long_press else "")
        with self._lock:
            if button == "sensors":
                if self.recording:
                    self.state.set_message("STOP REC FIRST")
                elif self.sensors_on and long_press:
                    self.sensors_down()
                elif not self.sensors_on:
                    self.sensors_up()
                else:
                    self.sensors_up()  # retry the ones in ERR
            elif button == "record":
                if self.recording:
                    self.stop_recording()
                else:
                    self.start_recording()

    # ------------------------------------------------------------------------------------------------ sensors
    def sensors_up(self) -> bool:
        """Open and configure the trigger and both cameras; True when all are up (each failure -> ERR)."""
        with self._lock:
            ok = self._sensors_up()
            session = self._session
            if not self.recording and (session is None or set(session.cameras) != set(self.cameras)):
                self._preview_stop()  # a camera back (retry) joins the previews
                self._preview_start()
            return ok

    def _sensors_up(self) -> bool:
        self.sensors_on = True
        ok = self._trigger_up()
        for cam in self.config.cameras:
            ok = self._camera_up(cam.side) and ok
        self.state.set_message("SENSORS OK" if ok else "SENSOR ERROR")
        return ok

    def sensors_down(self) -> None:
        with self._lock:
            self._preview_stop()
            self.sensors_on = False
            for side in list(self.cameras):
                self._camera_down(side, SensorState.OFF)
            self._trigger_down(SensorState.OFF)
            self.state.set_message("SENSORS OFF")

    def _trigger_up(self) -> bool:
        if self.trigger is not None:
            return True
        from bracketry.trigger.client import TriggerClient

        tc = self.config.trigger
        try:
            client = TriggerClient.open(tc.port, baudrate=tc.baudrate, on_event=self._on_trigger_event,
                                        timeout_s=0.25)
            client.hello(timeout_s=1.0)
            client.sync_clock()
            client.stop()
            client.configure(self.config.period_us, list(self.config.brackets_us))
        except Exception as exc:
            with contextlib.suppress(Exception):
                client.close()
            self._backoff["trigger"].failed()
            self.state.set_state("trigger", SensorState.ERR, f"{tc.port}: {exc}")
            log.error("trigger on %s: %s", tc.port, exc)
            return False
        self.trigger = client
        self._trigger_reboots_seen = client.counters.reboots if hasattr(client.counters, "reboots") else 0
        self._backoff["trigger"].reset()
        self.state.set_state("trigger", SensorState.IDLE)
        log.info("trigger up on %s: %s", tc.port, client.device)
        return True

    def _trigger_down(self, new_state: SensorState, error: str | None = None) -> None:
        client, self.trigger = self.trigger, None
        if client is not None:
            with contextlib.suppress(Exception):
                client.stop()
            with contextlib.suppress(Exception):
                client.close()
        self.state.set_state("trigger", new_state, error)

    def _camera_up(self, side: str) -> bool:
        if side in self.cameras:
            return True
        from bracketry.cameras.camera import GigECamera
        from bracketry.cameras.profiles import settings_from_config

        cc = self.config.camera(side)
        sensor = CAM_SENSOR[side]
        cam = None
        try:
            cam = GigECamera(cc.address, side=side)
            if cc.device_id:
                cam.check_identity(cc.device_id)
            cam.configure(settings_from_config(cc, width=self.options.width, height=self.options.height,
                                               exposure_us=self.config.brackets_us[0])).raise_if_mismatch()
        except Exception as exc:
            if cam is not None:
                with contextlib.suppress(Exception):
                    cam.close()
            self._backoff[side].failed()
            self.state.set_state(sensor, SensorState.ERR, f"{cc.address or cc.device_id}: {exc}")
            log.error("camera %s (%s): %s", side, cc.address or cc.device_id, exc)
            return False
        self.cameras[side] = cam
        self._backoff[side].reset()
        self.state.set_state(sensor, SensorState.IDLE)
        log.info("camera %s up: %s", side, cc.address or cc.device_id)
        return True

    def _camera_down(self, side: str, new_state: SensorState, error: str | None = None) -> None:
        cam = self.cameras.pop(side, None)
        if cam is not None:
            with contextlib.suppress(Exception):
                cam.stop()
            with contextlib.suppress(Exception):
                cam.close()
        self.state.set_state(CAM_SENSOR[side], new_state, error)
        self.state.set_fps(side, 0.0)

    def set_brackets_us(self, brackets_us: list[int]) -> None:
        """Change the bracket table (refused while recording: a segment keeps one table); the trigger, when up, is
        reconfigured at once. Raises BracketryError naming the problem."""
        from bracketry.daemon.config import check_brackets_ms

        with self._lock:
            if self.recording:
                raise BracketryError("recording: stop it before changing the bracket table")
            brackets_ms = [b / 1000.0 for b in brackets_us]
            problem = check_brackets_ms(brackets_ms, self.config.fps)
            if problem:
                raise BracketryError(f"brackets_us{problem[0]}: {problem[1]}")
            previewing = self._preview_stop()  # the trigger takes a new table only when stopped
            if self.trigger is not None:
                self.trigger.configure(self.config.period_us, list(brackets_us))
            self.config = dataclasses.replace(self.config, brackets_ms=tuple(brackets_ms))
            log.info("bracket table changed: brackets_us=%s", self.config.brackets_us)
            if self.monitor_hub is not None:
                self.monitor_hub.clear()  # previews of the old table are gone; the new table's come next
            if previewing:
                self._preview_start()

    # ------------------------------------------------------------------------------------------------ recording
    def start_recording(self) -> bool:
        """Start a recording (refused below ``min_free_mb`` or without sensors); True when a segment started."""
        with self._lock:
            if self.recording:
                return True
            free = free_mb(self.config.output_dir)
            self.state.set_free_disk_mb(free)
            if free < self.config.min_free_mb:
                self.state.set_message(f"DISK LOW {free // 1024}GB" if free >= 1024 else f"DISK LOW {free}MB")
                log.error("recording refused: %d MB free < min_free_mb %d", free, self.config.min_free_mb)
                return False
            self._preview_stop()
            if not self.sensors_on:
                self._sensors_up()
            self.config.output_dir.mkdir(parents=True, exist_ok=True)
            self.rec_name = time.strftime("rec_%Y%m%d_%H%M%S")
            self.recording = True
            self.segment_index = 0
            self.state.set_recording(str(self.config.output_dir / self.rec_name))
            started = self._segment_start()
            if not started:
                self.state.set_message("REC WAITING")
            return started

    def stop_recording(self) -> dict[str, Any] | None:
        """Stop the recording: close the open segment cleanly; returns its summary."""
        with self._lock:
            if not self.recording:
                return None
            summary = self._segment_stop()
            self.recording = False
            self.state.set_recording(None)
            for side in self.cameras:
                self.state.set_state(CAM_SENSOR[side], SensorState.IDLE)
            if self.trigger is not None:
                self.state.set_state("trigger", SensorState.IDLE)
            self.state.set_message("SAVED")
            log.info("recording %s stopped after %d segment(s)", self.rec_name, len(self.segments))
            self._preview_start()
            return summary

    # ------------------------------------------------------------------------------------------------ previews
    def _preview_start(self) -> bool:
        """Open the preview session (monitor on, sensors up, not recording): the cameras stream on the trigger's
        pulses, paired sets go only to the monitor's hub, nothing is written. True when it started."""
        from bracketry.recording.session import DiscardSink, RecordingSession, SessionStartError

        if (self.monitor_hub is None or self._closing or self.recording or not self.sensors_on
                or self._session is not None or self.trigger is None or not self.cameras):
            return False
        camera_trigger = self._new_camera_trigger()
        try:
            session = RecordingSession(dict(self.cameras), DiscardSink(self.config.output_dir),
                                       disk_path=self.config.output_dir,
                                       initial_alignment=camera_trigger.initial_alignment,
                                       tap=self.monitor_hub.offer).start()
        except SessionStartError as exc:
            log.error("preview start: %s", exc)
            self._camera_down(exc.side, SensorState.ERR, str(exc))
            self._backoff[exc.side].failed()
            return self._preview_start()
        camera_trigger.arm()
        self._camera_trigger = camera_trigger
        self._session_id = (self._session_id + 1) & 0xFFFFFFFF or 1
        self._recorder, self._session = None, session
        self.previewing = True
        self._last_frames = {}
        self._pulses = {}
        try:
            self.trigger.start(self._session_id)
        except Exception as exc:
            log.error("trigger START (previews) failed: %s", exc)
            self._preview_stop()
            self._trigger_down(SensorState.ERR, f"START failed: {exc}")
            return False
        log.info("previews started: sides=%s session_id=%d", ",".join(session.cameras), self._session_id)
        return True

    def _preview_stop(self) -> bool:
        """Close the preview session (the cameras stop, stay open and configured); True when one was open."""
        if not self.previewing:
            return False
        self._close_session()
        self.previewing = False
        for side in self.cameras:
            self.state.set_fps(side, 0.0)
        log.info("previews stopped")
        return True

    def _segment_start(self) -> bool:
        from bracketry.recording.recorder import Recorder, RecorderConfig
        from bracketry.recording.session import RecordingSession, SessionStartError

        if self.trigger is None or not self.cameras:
            return False
        self.segment_index += 1
        name = f"{self.rec_name}_seg{self.segment_index:02d}"
        seg_dir = self.config.output_dir / str(self.rec_name) / f"seg{self.segment_index:02d}"
        cfg = RecorderConfig(split_bytes=self.config.split_size_mb << 20, split_s=self.config.split_minutes * 60.0,
                             sides=tuple(sorted(self.cameras, key=lambda s: s != "left")))
        metadata = {"rig_brackets_us": ",".join(map(str, self.config.brackets_us)),
                    "rig_period_us": str(self.config.period_us), "segment": str(self.segment_index),
                    "sides": ",".join(cfg.sides), **self.options.metadata}
        recorder = Recorder(seg_dir, name, cfg, metadata=metadata,
                            calibration=self.options.calibration).start()
        camera_trigger = self._new_camera_trigger()
        try:
            session = RecordingSession(dict(self.cameras), recorder, disk_path=self.config.output_dir,
                                       initial_alignment=camera_trigger.initial_alignment,
                                       tap=self.monitor_hub.offer if self.monitor_hub is not None else None).start()
        except SessionStartError as exc:
            # this camera cannot stream: ERR (reconnected by the supervisor); the empty segment is closed and the
            # recording goes on with the cameras that work
            log.error("segment start: %s", exc)  # names the camera
            with contextlib.suppress(Exception):
                recorder.stop()
            shutil.rmtree(seg_dir, ignore_errors=True)  # it holds no frame
            self.segment_index -= 1
            self._camera_down(exc.side, SensorState.ERR, str(exc))
            self._backoff[exc.side].failed()
            return self._segment_start()
        camera_trigger.arm()  # e.g. the fake camera loses the first software trigger after AcquisitionStart
        self._camera_trigger = camera_trigger
        self._session_id = (self._session_id + 1) & 0xFFFFFFFF or 1
        self._recorder, self._session = recorder, session
        self._last_frames = {}
        self._pulses = {}
        try:
            self.trigger.start(self._session_id)
        except Exception as exc:
            log.error("trigger START failed: %s", exc)
            self._segment_stop()
            self._trigger_down(SensorState.ERR, f"START failed: {exc}")
            return False
        for side in self.cameras:
            self.state.set_state(CAM_SENSOR[side], SensorState.REC)
        self.state.set_state("trigger", SensorState.REC)
        missing = [cc.side for cc in self.config.cameras if cc.side not in self.cameras]
        self.state.set_message(f"REC: {missing[0].upper()} CAM ERR" if missing else "RECORDING")
        log.info("segment %s started: sides=%s session_id=%d", name, cfg.sides, self._session_id)
        return True

    def _new_camera_trigger(self) -> CameraTrigger:
        """The host's side of the pulses for the cameras up now (software triggering when their profile says so)."""
        return camera_trigger(self.cameras, {cc.side: cc.profile for cc in self.config.cameras})

    def _segment_stop(self) -> dict[str, Any] | None:
        recorder = self._recorder
        if self._session is None or recorder is None:
            return None
        status = self._close_session()
        rsum = recorder.summary
        summary = {"dir": str(recorder.out_dir), "files": list(rsum.files), "frames_written": dict(rsum.frames_written),
                   "status": status, "overflows": rsum.overflows, "error": rsum.error}
        self.segments.append(summary)
        # cameras were stopped by the session; they stay open and configured for the next segment
        log.info("segment closed: files=%s frames=%s", rsum.files, rsum.frames_written)
        return summary

    def _close_session(self) -> dict[str, Any]:
        """Stop the trigger, deliver its last events, stop the open session (recording or previews)."""
        session = self._session
        if self.trigger is not None:
            try:
                self.trigger.stop()  # events of every pulse before STOP arrive before its ACK
            except Exception as exc:
                log.warning("trigger STOP failed: %s", exc)
        deadline = time.monotonic() + 2.0
        while not self._events.empty() and time.monotonic() < deadline:
            time.sleep(0.02)  # the pump delivers the last events (and fires their software triggers)
        self._pump_paused.set()
        try:
            with self._deliver_lock:  # an event the pump holds reaches this session before it stops
                self._session = self._recorder = None
            self._drain_events(session)
        finally:
            self._pump_paused.clear()
        # the last pulses' buffers, also under load
        return session.stop(drain_s=3.0, expect_frames=self._camera_trigger.frames_expected)

    def _restart_segment(self, reason: str) -> None:
        """Close the open segment cleanly and start a new one with the sensors that work."""
        log.warning("restarting recording segment: %s", reason)
        self._segment_stop()
        if not self._segment_start():
            self.state.set_message("REC WAITING")

    # ------------------------------------------------------------------------------------------------ events
    def _on_trigger_event(self, ev: TriggerEvent) -> None:
        try:
            self._events.put_nowait(ev)
        except queue.Full:
            self.state.count("events_dropped_host")

    def _drain_events(self, session: Any) -> None:
        while True:
            try:
                ev = self._events.get_nowait()
            except queue.Empty:
                return
            if ev is not None:
                self._deliver(ev, session)

    def _deliver(self, ev: TriggerEvent, session: Any) -> None:
        if ev.session_id != self._session_id:
            return
        # the pulse reaches the cameras (a camera that failed a software trigger is skipped until the next segment;
        # the stall check takes it down)
        for side in self._camera_trigger.fire(ev, session.cameras):
            self._pulses[side] = self._pulses.get(side, 0) + 1
        session.on_trigger_event(ev)
        self.state.count("trigger_events")

    def _pump_events(self) -> None:
        """Deliver TRIGGER events to the open session; paused while a segment closes (it drains the queue)."""
        while not self._stop.is_set():
            if self._pump_paused.is_set():
                time.sleep(0.01)
                continue
            with self._deliver_lock:
                try:
                    ev = self._events.get(timeout=0.05)
                except queue.Empty:
                    continue
                if ev is None:
                    return
                session = self._session
                if session is not None:
                    self._deliver(ev, session)

    # ------------------------------------------------------------------------------------------------ supervision
    def _supervise(self) -> None:
        period_s = 1.0
        if self.notifier.watchdog_interval_s:
            period_s = min(period_s, self.notifier.watchdog_interval_s)
        while not self._stop.wait(period_s):
            try:
                self._supervise_once()
            except Exception:
                log.exception("supervisor step failed")
            self.notifier.watchdog()

    def _supervise_once(self) -> None:
        free = free_mb(self.config.output_dir)
        self.state.set_free_disk_mb(free)
        with self._lock:
            if self.recording and free < self.config.stop_free_mb:
                log.error("free disk %d MB < stop_free_mb %d: stopping the recording", free, self.config.stop_free_mb)
                self.stop_recording()
                self.state.set_message("DISK FULL: STOPPED")
            if self.recording and self._recorder is not None and self._recorder.error:
                log.error("recorder failed: %s", self._recorder.error)
                self.stop_recording()
                self.state.set_message("WRITE ERROR")
            self._check_trigger()
            self._check_cameras()
            self._check_idle_cameras()
            self._reconnect()
            if self.panel is None and self.config.panel.enabled and self._backoff["panel"].due():
                self._connect_panel()

    def _check_trigger(self) -> None:
        client = self.trigger
        if client is None:
            return
        lost = bool(getattr(client.link, "peer_lost", False))
        reboots = client.counters.reboots if hasattr(client.counters, "reboots") else 0
        if lost or reboots != self._trigger_reboots_seen:
            why = "lost (no heartbeat)" if lost else "rebooted"
            log.error("trigger %s", why)
            self._trigger_down(SensorState.ERR, why)
            self._preview_stop()  # its trigger is gone: the previews start again when it is back
            if self.recording:
                self._segment_stop()
                self.state.set_message("TRIGGER LOST")

    def _check_cameras(self) -> None:
        session = self._session
        if session is None:
            return
        now = time.monotonic()
        status = session.pairer.counters
        for side in list(self.cameras):
            frames = status[side].frames if side in status else 0
            pulses = self._pulses.get(side, 0)
            t0, n0, _p0 = self._last_frames.get(side, (now, frames, pulses))
            if frames != n0 or side not in self._last_frames:
                self._last_frames[side] = (now, frames, pulses)
            fps = (frames - n0) / (now - t0) if now > t0 else 0.0
            if now > t0:
                self.state.set_fps(side, fps)
            t_last, _, pulses_then = self._last_frames[side]
            # stalled: no frame for camera_stall_s although pulses reached it (a camera nobody triggered, e.g.
            # while the trigger pump waited on the other camera, is not blamed), or it failed a GVCP write
            if now - t_last > self.options.camera_stall_s and (side in self._camera_trigger.failed or
                                                              pulses - pulses_then >= STALL_PULSES):
                log.error("camera %s: no frame for %.1f s (%d pulses)", side, now - t_last, pulses - pulses_then)
                self._camera_lost(side, session)
                return

    def _check_idle_cameras(self) -> None:
        """Cameras up but not recording: one GVCP register read each every ``idle_check_s``; a camera that does
        not answer goes to ERR and is reconnected with backoff (a recording camera is watched by its frames)."""
        if self._session is not None or not self.cameras:
            return
        now = time.monotonic()
        if now - self._last_idle_check < self.options.idle_check_s:
            return
        self._last_idle_check = now
        for side, cam in list(self.cameras.items()):
            try:
                cam.device.read_register(GEV_VERSION_REGISTER)
            except Exception as exc:
                log.error("camera %s: no answer while idle: %s", side, exc)
                self.cameras.pop(side, None)
                self.state.set_state(CAM_SENSOR[side], SensorState.ERR, f"no answer: {exc}")
                self._backoff[side].failed()
                threading.Thread(target=_close_quietly, args=(cam,), name=f"close-{side}", daemon=True).start()

    def _camera_lost(self, side: str, session: Any) -> None:
        """A recording camera stalled: ERR, the segment closes without it, a new one starts with what works.

        The session stops every camera it holds with AcquisitionStop, which a camera gone from the network answers
        only after GVCP timeouts (seconds): the lost camera leaves the session first and is closed in the
        background once the segment is closed (its stream thread no longer used by the pairing thread)."""
        cam = self.cameras.pop(side, None)
        session.cameras = {s: c for s, c in session.cameras.items() if s != side}  # rebind: readers keep the old
        self._camera_trigger.remove(side)
        self.state.set_state(CAM_SENSOR[side], SensorState.ERR, "no frames")
        self.state.set_fps(side, 0.0)
        self._backoff[side].failed()
        if self.previewing:
            self._preview_stop()
            self._preview_start()
        else:
            self._restart_segment(f"camera {side} lost")
        if cam is not None:
            threading.Thread(target=_close_quietly, args=(cam,), name=f"close-{side}", daemon=True).start()

    def _reconnect(self) -> None:
        if not self.sensors_on:
            return
        changed = False
        if self.trigger is None and self._backoff["trigger"].due():
            changed = self._trigger_up() or changed
        for cc in self.config.cameras:
            if cc.side not in self.cameras and self._backoff[cc.side].due():
                changed = self._camera_up(cc.side) or changed
        if changed and self.recording:
            self._restart_segment("sensor back")
        elif changed and self.monitor_hub is not None:
            self._preview_stop()
            self._preview_start()

    # ------------------------------------------------------------------------------------------------ status
    def handle_request(self, request: dict[str, Any]) -> dict[str, Any]:
        """Status socket handler: ``status`` and ``button``."""
        cmd = request.get("cmd")
        if cmd == "status":
            snap = self.state.snapshot().to_json()
            return {"ok": True, "state": snap, "segments": len(self.segments),
                    "panel": self.panel.status() if self.panel is not None else None,
                    "monitor": {"url": self.monitor_server.url} if self.monitor_server is not None else None}
        if cmd == "button":
            button = request.get("button")
            if button not in ("sensors", "record"):
                return {"ok": False, "error": "button must be sensors or record"}
            self.on_button(str(button), bool(request.get("long", False)))
            return {"ok": True}
        return {"ok": False, "error": f"unknown cmd {cmd!r}"}


def _close_quietly(cam: Any) -> None:
    with contextlib.suppress(Exception):
        cam.close()


def install_signal_handlers(daemon: RigDaemon) -> Callable[[], None]:
    """SIGTERM/SIGINT -> :meth:`RigDaemon.request_stop`; returns a function restoring the old handlers."""
    import signal

    old = {s: signal.getsignal(s) for s in (signal.SIGTERM, signal.SIGINT)}

    def handler(signum: int, _frame: Any) -> None:
        log.info("signal %d: stopping", signum)
        daemon.request_stop()

    for s in old:
        signal.signal(s, handler)

    def restore() -> None:
        for s, h in old.items():
            signal.signal(s, h)

    return restore
