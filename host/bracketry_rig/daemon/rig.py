"""The rig daemon: four parts with typed seams, wired here, and the rig's rules for what happens when.

- :class:`~bracketry_rig.daemon.sensors.SensorSupervisor` — the trigger and the cameras: up, down, reconnection with
  backoff, fault checks (trigger lost or rebooted, idle camera silent, recording camera stalled).
- :class:`~bracketry_rig.daemon.segments.SegmentRecorder` — the recording as segments, and the monitor's previews; the
  open acquisition and its camera trigger adapter (``bracketry_rig.cameras.triggering``: hardware line or software,
  chosen by the camera profiles, never by a "simulated" switch).
- :class:`~bracketry_rig.daemon.pump.EventPump` — TRIGGER events from the trigger link to the open acquisition.
- :class:`~bracketry_rig.daemon.view.RigView` — the status socket, the panel and the browser monitor.

:class:`RigDaemon` owns the rules that span parts (a button press, a lost trigger closes the open segment, a
sensor back starts a new one) and the 1 Hz supervisor thread (free disk, recorder errors, device health,
reconnection, systemd watchdog). When a device fails, the open segment is closed cleanly (nothing already recorded
is lost), the failed sensor shows ERR, recording continues with what still works, and a new segment with every
sensor starts when it is back.

Threads and locks: every action (panel buttons, each on a thread of its own; the status socket's thread; the
monitor's HTTP threads) and every supervisor step holds the daemon's action lock ``_lock``, so actions never
interleave; inside it, the parts take their own locks (order: action lock -> segment recorder -> sensor supervisor
-> event pump's hold; the view's and ``RigState``'s locks are leaves, held around their own fields only). The event
pump's thread delivers events without the action lock (see ``segments``); the trigger client's listener thread only
queues them. Readers of the state (the panel's refresh, status requests, the monitor's status) use ``RigState``
snapshots and never wait for an action.
"""

from __future__ import annotations

import dataclasses
import logging
import threading
import time
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any

from bracketry_base.errors import BracketryError
from bracketry_rig.cameras.triggering import CameraTrigger, camera_trigger
from bracketry_rig.daemon.config import RigConfig, check_brackets_ms
from bracketry_rig.daemon.disk import free_mb
from bracketry_rig.daemon.pump import EventPump
from bracketry_rig.daemon.sdnotify import Notifier
from bracketry_rig.daemon.segments import SegmentOptions, SegmentRecorder
from bracketry_rig.daemon.sensors import (
    Camera,
    LoopWatch,
    OpenCamera,
    OpenTrigger,
    SensorSupervisor,
    close_in_background,
    open_gige_camera,
    open_trigger_client,
)
from bracketry_rig.daemon.state import RigState
from bracketry_rig.daemon.view import RigView
from bracketry_rig.events import TriggerEvent

if TYPE_CHECKING:
    from bracketry_rig.monitor.server import MonitorServer

log = logging.getLogger("bracketry_rig.daemon")

#: the supervisor's step period (shorter when systemd's watchdog asks for it), seconds
SUPERVISOR_PERIOD_S = 1.0
#: the main thread's longest sleep in RigDaemon.wait, seconds: how late a signal's handler may run
WAKE_S = 0.5


@dataclass
class DaemonOptions:
    """Run-time options that are not part of the rig config.

    ``width``/``height``: region of interest (None keeps the camera's); ``camera_stall_s``: a recording camera
    with no frame for this long is in ERR; ``idle_check_s``: period of the GVCP check of idle cameras;
    ``backoff_s``: first and maximum reconnection delays; ``open_camera``/``open_trigger``: the device seams.
    """

    width: int | None = None
    height: int | None = None
    camera_stall_s: float = 2.0
    idle_check_s: float = 2.0
    backoff_s: tuple[float, float] = (0.5, 8.0)
    status_socket: Path | None = None
    calibration: dict[str, dict[str, Any]] = field(default_factory=dict)
    metadata: dict[str, str] = field(default_factory=dict)
    open_camera: OpenCamera = open_gige_camera
    open_trigger: OpenTrigger = open_trigger_client


class RigDaemon:
    """The rig: ``sensors_up``/``sensors_down``, ``start_recording``/``stop_recording``, ``on_button``, ``close``."""

    def __init__(self, config: RigConfig, options: DaemonOptions | None = None) -> None:
        self.config = config
        self.options = o = options or DaemonOptions()
        self.state = RigState()
        self.notifier = Notifier()
        self._lock = threading.RLock()
        self._stop = threading.Event()
        self._supervisor: threading.Thread | None = None
        current = self._current_config
        self.pump = EventPump(self._deliver, lambda: self.state.count("events_dropped_host"))
        self.sensors = SensorSupervisor(current, self.state, self.pump.put, roi=(o.width, o.height),
                                        backoff_s=o.backoff_s, idle_check_s=o.idle_check_s,
                                        camera_stall_s=o.camera_stall_s, open_camera=o.open_camera,
                                        open_trigger=o.open_trigger)
        self.segmenter = SegmentRecorder(current, self.state, self.sensors, self.pump, self._camera_trigger,
                                         SegmentOptions(o.calibration, o.metadata))
        self.view = RigView(current, self.state, self, o.status_socket, o.backoff_s)
        #: gaps in the supervisor loop: the daemon's own starvation, told from a silent device
        self.loop_watch = LoopWatch(SUPERVISOR_PERIOD_S)

    def _current_config(self) -> RigConfig:
        return self.config

    def _deliver(self, event: TriggerEvent) -> None:
        self.segmenter.deliver(event)

    def _camera_trigger(self, cameras: Mapping[str, Camera]) -> CameraTrigger:
        """The host's side of the pulses for ``cameras``, as their profiles say (line or software)."""
        return camera_trigger(cameras, {cc.side: cc.profile for cc in self.config.cameras})

    # ------------------------------------------------------------------------------------------------ reading
    @property
    def recording(self) -> bool:
        return self.segmenter.recording

    @property
    def rec_name(self) -> str | None:
        return self.segmenter.rec_name

    @property
    def segment_index(self) -> int:
        return self.segmenter.segment_index

    @property
    def segments(self) -> list[dict[str, Any]]:
        """Summaries of the closed segments."""
        return self.segmenter.segments

    @property
    def sensors_on(self) -> bool:
        return self.sensors.on

    @property
    def cameras(self) -> dict[str, Camera]:
        """The cameras up now (a copy)."""
        return self.sensors.cameras()

    @property
    def monitor_server(self) -> MonitorServer | None:
        return self.view.monitor_server

    def pairing_counters(self) -> dict[str, Any]:
        return self.segmenter.counters()

    def last_status(self) -> dict[str, Any]:
        return self.segmenter.last_status()

    def handle_request(self, request: dict[str, Any]) -> dict[str, Any]:
        """Status socket handler (see :meth:`bracketry_rig.daemon.view.RigView.handle_request`)."""
        return self.view.handle_request(request)

    # ------------------------------------------------------------------------------------------------ lifecycle
    def start(self) -> RigDaemon:
        """Start the monitor, the status socket, the panel link and the supervisor; sensors stay OFF until SENSORS."""
        self.view.start_monitor()
        self.segmenter.preview_tap = self.view.preview_tap  # previews only with a monitor
        self.view.start_links()
        self.state.set_free_disk_mb(free_mb(self.config.output_dir))
        self.pump.start()
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
            self.segmenter.closing = True  # no preview session between the recording's end and the sensors' shutdown
            if self.recording:
                self.stop_recording()
            self.sensors_down()
        self._stop.set()
        self.pump.close()
        if self._supervisor is not None:
            self._supervisor.join(timeout=5.0)
        self.view.close()
        log.info("daemon stopped")

    def wait(self, timeout_s: float | None = None) -> bool:
        """Block until :meth:`request_stop` (or ``timeout_s``); True if stop was requested.

        The wait wakes every ``WAKE_S`` seconds: Python runs a signal's handler in the main thread only, and a signal
        the kernel hands to another of the daemon's threads (the cameras', the monitor's) is handled when the main
        thread next runs, which a wait on an event alone would put off until the event is set."""
        deadline = None if timeout_s is None else time.monotonic() + timeout_s
        while True:
            left = WAKE_S if deadline is None else min(WAKE_S, deadline - time.monotonic())
            if left <= 0.0:
                return self._stop.is_set()
            if self._stop.wait(left):
                return True

    def request_stop(self) -> None:
        """Ask :meth:`wait` to return (e.g. from a SIGTERM handler); :meth:`close` does the work."""
        self._stop.set()

    # ------------------------------------------------------------------------------------------------ actions
    def on_button(self, button: str, long_press: bool = False) -> None:
        """SENSORS: bring sensors up (or down when idle and already up); RECORD: start/stop recording."""
        log.info("button %s%s", button, " (long)" if long_press else "")
        with self._lock:
            if button == "sensors":
                if self.recording:
                    self.state.set_message("STOP REC FIRST")
                elif self.sensors_on and long_press:
                    self.sensors_down()
                else:
                    self.sensors_up()  # also retries the ones in ERR
            elif button == "record":
                if self.recording:
                    self.stop_recording()
                else:
                    self.start_recording()

    def sensors_up(self) -> bool:
        """Open and configure the trigger and both cameras; True when all are up (each failure -> ERR)."""
        with self._lock:
            ok = self.sensors.up()
            session = self.segmenter.open_session()
            if not self.recording and (session is None or set(session.cameras) != set(self.sensors.cameras())):
                self.segmenter.previews_again()  # a camera back (retry) joins the previews
            return ok

    def sensors_down(self) -> None:
        with self._lock:
            self.segmenter.preview_stop()
            self.sensors.down()

    def start_recording(self) -> bool:
        """Start a recording (refused below ``min_free_mb`` or without sensors); True when a segment started."""
        with self._lock:
            if self.recording:
                return True
            if self.segmenter.free_mb_to_start() is not None:
                return False
            self.segmenter.preview_stop()
            if not self.sensors_on:
                self.sensors.up()
            return self.segmenter.begin()

    def stop_recording(self) -> dict[str, Any] | None:
        """Stop the recording: close the open segment cleanly; returns its summary."""
        with self._lock:
            if not self.recording:
                return None
            summary = self.segmenter.end()
            self.segmenter.preview_start()
            return summary

    def set_brackets_us(self, brackets_us: Sequence[int]) -> None:
        """Change the bracket table (refused while recording: a segment keeps one table); the trigger, when up, is
        reconfigured at once. Raises BracketryError naming the problem."""
        with self._lock:
            if self.recording:
                raise BracketryError("recording: stop it before changing the bracket table")
            brackets_ms = [b / 1000.0 for b in brackets_us]
            problem = check_brackets_ms(brackets_ms, self.config.fps)
            if problem:
                raise BracketryError(f"brackets_us{problem[0]}: {problem[1]}")
            previewing = self.segmenter.preview_stop()  # the trigger takes a new table only when stopped
            self.sensors.configure_trigger(self.config.period_us, list(brackets_us))
            self.config = dataclasses.replace(self.config, brackets_ms=tuple(brackets_ms))
            log.info("bracket table changed: brackets_us=%s", self.config.brackets_us)
            if self.view.monitor_hub is not None:
                self.view.monitor_hub.clear()  # previews of the old table are gone; the new table's come next
            if previewing:
                self.segmenter.preview_start()

    # ------------------------------------------------------------------------------------------------ supervision
    def _supervise(self) -> None:
        period_s = SUPERVISOR_PERIOD_S
        if self.notifier.watchdog_interval_s:
            period_s = min(period_s, self.notifier.watchdog_interval_s)
        self.loop_watch.period_s = period_s
        while not self._stop.wait(period_s):
            try:
                self.supervise_once()
            except Exception:
                log.exception("supervisor step failed")
            self.notifier.watchdog()

    def supervise_once(self, now_s: float | None = None) -> None:
        """One supervisor step: disk and recorder, trigger, cameras, reconnection, panel. A step long after the
        previous one (the daemon itself starved, ``LoopWatch``) declares no device fault for the time it lost."""
        now = time.monotonic() if now_s is None else now_s
        starved_s = self.loop_watch.step(now)
        if starved_s > 0.0:
            self.state.count("daemon_starved")
        free = free_mb(self.config.output_dir)
        self.state.set_free_disk_mb(free)
        with self._lock:
            if self.recording and free < self.config.stop_free_mb:
                log.error("free disk %d MB < stop_free_mb %d: stopping the recording", free, self.config.stop_free_mb)
                self.stop_recording()
                self.state.set_message("DISK FULL: STOPPED")
            error = self.segmenter.recorder_error() if self.recording else None
            if error:
                log.error("recorder failed: %s", error)
                self.stop_recording()
                self.state.set_message("WRITE ERROR")
            self._check_trigger(starved_s)
            self._check_cameras(now, starved_s)
            self._reconnect()
            self.view.check_panel()
        self.loop_watch.done(time.monotonic() if now_s is None else now_s)

    def _check_trigger(self, starved_s: float) -> None:
        if self.sensors.check_trigger(starved_s) is None:
            return
        self.segmenter.preview_stop()  # its trigger is gone: the previews start again when it is back
        if self.recording:
            self.segmenter.segment_stop()
            self.state.set_message("TRIGGER LOST")

    def _check_cameras(self, now: float, starved_s: float) -> None:
        """A camera of the open acquisition that stalled leaves it: the segment closes without it and a new one
        starts with what works (or the previews restart); idle cameras are checked over GVCP."""
        progress = self.segmenter.progress()
        if progress is None:
            self.sensors.check_idle_cameras(now)
            return
        side = self.sensors.check_stalls(progress, now, starved_s)
        if side is None:
            return
        cam = self.sensors.camera_lost(side, "no frames")
        self.segmenter.drop_camera(side)  # the session no longer stops it (AcquisitionStop would wait for timeouts)
        if self.segmenter.previewing:
            self.segmenter.previews_again()
        else:
            self.segmenter.restart_segment(f"camera {side} lost")
        close_in_background(cam)  # once no session uses its stream

    def _reconnect(self) -> None:
        if not self.sensors.reconnect():
            return
        if self.recording:
            self.segmenter.restart_segment("sensor back")
        elif self.view.monitor_hub is not None:
            self.segmenter.previews_again()


def install_signal_handlers(daemon: RigDaemon) -> Callable[[], None]:
    """SIGTERM/SIGINT -> :meth:`RigDaemon.request_stop`; SIGUSR1 writes every thread's Python stack to stderr (the
    daemon's log), so a daemon that does not stop can say where it waits. Returns a function restoring the old
    handlers."""
    import faulthandler
    import signal

    faulthandler.register(signal.SIGUSR1, all_threads=True)
    old = {s: signal.getsignal(s) for s in (signal.SIGTERM, signal.SIGINT)}

    def handler(signum: int, _frame: Any) -> None:
        log.info("signal %d: stopping", signum)
        daemon.request_stop()

    for s in old:
        signal.signal(s, handler)

    def restore() -> None:
        faulthandler.unregister(signal.SIGUSR1)
        for s, h in old.items():
            signal.signal(s, h)

    return restore
