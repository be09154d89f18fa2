"""The daemon's sensor supervisor: the trigger device and the cameras up, down and back, and their faults.

It owns the open devices (the trigger client and the cameras, opened through the two ``open_*`` seams), one
reconnection backoff per device, and the fault checks: a trigger that stopped answering or rebooted, an idle camera
that no longer answers GVCP, a recording camera that stalled (:class:`StallWatch`, a pure state machine over the open
acquisition's frame and pulse counts). The daemon's own starvation (:class:`LoopWatch`: gaps in its supervisor loop)
is told from a silent device: the time the daemon was not run counts towards no device's fault. It never touches a
recording: it reports what it found, and the daemon (``bracketry_rig.daemon.rig``) decides what happens to the open
segment.

Threads: every method but the read-only properties runs under the daemon's action lock (buttons, the status socket,
the monitor's actions and the 1 Hz supervisor thread); the supervisor's own lock guards its fields for readers
outside it (the monitor's status). ``open_trigger`` gets the event pump's ``put``, which the trigger client calls
on its listener thread.
"""

from __future__ import annotations

import contextlib
import logging
import random
import threading
import time
from collections.abc import Callable, Iterable, Mapping, Sequence
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any, Protocol

from bracketry_rig.cameras.camera import Frame
from bracketry_rig.cameras.profiles import CameraSettings, settings_from_config
from bracketry_rig.daemon.config import CameraConfig, RigConfig, TriggerConfig
from bracketry_rig.daemon.state import RigState, SensorState
from bracketry_rig.events import TriggerEvent

if TYPE_CHECKING:
    from bracketry_rig.trigger.client import TriggerClient

log = logging.getLogger("bracketry_rig.daemon")

CAM_SENSOR = {"left": "cam_left", "right": "cam_right"}
#: a recording camera is stalled when this many pulses reached it without a frame (and camera_stall_s passed)
STALL_PULSES = 3
#: GigE Vision bootstrap register "Version" (read to see that an idle camera still answers GVCP)
GEV_VERSION_REGISTER = 0x0000


class GvcpDevice(Protocol):
    """A camera's control channel (``Aravis.Device``)."""

    def read_register(self, address: int) -> Any: ...


class Camera(Protocol):
    """A configured camera as the daemon uses it (``bracketry_rig.cameras.camera.GigECamera``)."""

    @property
    def device(self) -> GvcpDevice: ...

    def set_exposure_us(self, exposure_us: float) -> None: ...

    def software_trigger(self) -> None: ...

    def start(self, on_frame: Callable[[Frame], None]) -> None: ...

    def stop(self) -> None: ...

    def close(self) -> None: ...


class TriggerDevice(Protocol):
    """The trigger device as the daemon uses it: bracket table, START/STOP, and its health."""

    def configure(self, period_us: int, exposures_us: Sequence[int]) -> None: ...

    def start(self, session_id: int) -> None: ...

    def stop(self) -> None: ...

    def close(self) -> None: ...

    @property
    def reboots(self) -> int:
        """Device reboots the link saw (a change means the device lost its state)."""

    @property
    def peer_lost(self) -> bool:
        """No heartbeat from the device for too long."""


OpenCamera = Callable[[CameraConfig, CameraSettings], Camera]
OpenTrigger = Callable[[TriggerConfig, Callable[[TriggerEvent], None], int, Sequence[int]], TriggerDevice]


class ClientTrigger:
    """:class:`TriggerDevice` over a ``bracketry_rig.trigger.client.TriggerClient``."""

    def __init__(self, client: TriggerClient) -> None:
        self.client = client

    def configure(self, period_us: int, exposures_us: Sequence[int]) -> None:
        self.client.configure(period_us, list(exposures_us))

    def start(self, session_id: int) -> None:
        self.client.start(session_id)

    def stop(self) -> None:
        self.client.stop()

    def close(self) -> None:
        self.client.close()

    @property
    def reboots(self) -> int:
        return self.client.counters.reboots

    @property
    def peer_lost(self) -> bool:
        return bool(getattr(self.client.link, "peer_lost", False))


def open_trigger_client(tc: TriggerConfig, on_event: Callable[[TriggerEvent], None], period_us: int,
                        brackets_us: Sequence[int]) -> TriggerDevice:
    """Open the trigger on ``tc.port``: HELLO, clock sync, STOP, the bracket table. Raises on any failure."""
    from bracketry_rig.trigger.client import TriggerClient

    client = TriggerClient.open(tc.port, baudrate=tc.baudrate, on_event=on_event, timeout_s=0.25)
    try:
        client.hello(timeout_s=1.0)
        client.sync_clock()
        client.stop()
        client.configure(period_us, list(brackets_us))
    except Exception:
        with contextlib.suppress(Exception):
            client.close()
        raise
    log.info("trigger device: %s", client.device)
    return ClientTrigger(client)


def open_gige_camera(cc: CameraConfig, settings: CameraSettings) -> Camera:
    """Open the camera of ``cc`` by IP, check its identity, write its profile. Raises on any failure."""
    from bracketry_rig.cameras.camera import GigECamera

    cam = GigECamera(cc.address, side=cc.side)
    try:
        if cc.device_id:
            cam.check_identity(cc.device_id)
        cam.configure(settings).raise_if_mismatch()
    except Exception:
        with contextlib.suppress(Exception):
            cam.close()
        raise
    return cam


class Backoff:
    """Exponential backoff with jitter between reconnection attempts of one device (``now_s``: monotonic)."""

    def __init__(self, first_s: float, max_s: float) -> None:
        self.first_s, self.max_s = first_s, max_s
        self.delay_s = first_s
        self.next_t = 0.0

    def due(self, now_s: float | None = None) -> bool:
        return (time.monotonic() if now_s is None else now_s) >= self.next_t

    def failed(self, now_s: float | None = None) -> None:
        now = time.monotonic() if now_s is None else now_s
        self.next_t = now + self.delay_s * (0.8 + 0.4 * random.random())
        self.delay_s = min(self.delay_s * 2.0, self.max_s)

    def reset(self) -> None:
        self.delay_s = self.first_s
        self.next_t = 0.0


@dataclass(frozen=True)
class Progress:
    """Where the open acquisition stands: ``frames`` each camera delivered (received), ``pulses`` meant for it,
    ``failed`` the cameras that failed a trigger."""

    session_id: int
    frames: Mapping[str, int]
    pulses: Mapping[str, int]
    failed: frozenset[str]


#: a supervisor step that comes more than this many periods after the previous one shows the daemon itself starved
STARVED_GAP_PERIODS = 2.0


class LoopWatch:
    """Gaps in the daemon's own supervisor loop (pure: the caller gives the time of each step).

    The loop waits ``period_s`` after each step; a step that starts more than ``starved_periods`` periods after the
    previous one ended shows that the daemon itself was starved (a loaded host did not run it), not that a device fell
    silent: for that window the daemon saw nothing, so nothing seen missing in it is a device's fault (a step that
    itself took long, e.g. restarting a segment, is the daemon at work, not starved). :meth:`step` returns the time
    the daemon lost in the window (the gap less one period; 0.0 for a step on time), which the fault checks leave
    out. ``starved_windows``, ``starved_s`` and ``longest_gap_s`` sum it up.
    """

    def __init__(self, period_s: float = 1.0, starved_periods: float = STARVED_GAP_PERIODS) -> None:
        self.period_s, self.starved_periods = period_s, starved_periods
        self._last_s: float | None = None  # end of the previous step
        self.starved_windows = 0
        self.starved_s = 0.0
        self.longest_gap_s = 0.0

    def done(self, now_s: float) -> None:
        """The step that began with :meth:`step` ended at ``now_s``: the wait for the next one starts."""
        self._last_s = now_s

    def step(self, now_s: float) -> float:
        """A supervisor step begins at ``now_s`` (monotonic seconds); returns the seconds the daemon was starved
        since the previous step ended (0.0 when it came on time)."""
        last, self._last_s = self._last_s, now_s
        if last is None:
            return 0.0
        gap = now_s - last
        self.longest_gap_s = max(self.longest_gap_s, gap)
        if gap <= self.starved_periods * self.period_s:
            return 0.0
        lost = gap - self.period_s
        self.starved_windows += 1
        self.starved_s += lost
        log.warning("daemon starved: supervisor step %.2f s after the previous one ended (period %.2f s): no device "
                    "fault is declared for those %.2f s", gap, self.period_s, lost)
        return lost


class StallWatch:
    """Frame rate and stalls of the cameras of one acquisition (pure: the caller gives the time).

    A camera is stalled when it delivered no frame for ``stall_s`` although ``stall_pulses`` pulses reached it since
    its last frame (a camera nobody triggered, e.g. while the pump waited on the other camera, is not blamed), or
    when it failed a trigger. The marks start over with each new acquisition (``session_id``).
    """

    def __init__(self, stall_s: float, stall_pulses: int = STALL_PULSES) -> None:
        self.stall_s, self.stall_pulses = stall_s, stall_pulses
        self._session_id: int | None = None
        self._marks: dict[str, tuple[float, int, int]] = {}  # side -> (t_s, frames, pulses) at its last new frame

    def observe(self, progress: Progress, sides: Iterable[str], now_s: float,
                starved_s: float = 0.0) -> tuple[dict[str, float], str | None]:
        """Frame rates (frames/s since the previous mark, for sides with one) and the first stalled side or None
        (sides after it are not looked at). ``starved_s``: seconds since the previous call the daemon itself was
        not run (``LoopWatch.step``): they do not count towards ``stall_s``."""
        if progress.session_id != self._session_id:
            self._session_id, self._marks = progress.session_id, {}
        if starved_s > 0.0:
            self._marks = {side: (t + starved_s, n, p) for side, (t, n, p) in self._marks.items()}
        fps: dict[str, float] = {}
        for side in sides:
            frames = progress.frames.get(side, 0)
            pulses = progress.pulses.get(side, 0)
            t0, n0, _ = self._marks.get(side, (now_s, frames, pulses))
            if frames != n0 or side not in self._marks:
                self._marks[side] = (now_s, frames, pulses)
            if now_s > t0:
                fps[side] = (frames - n0) / (now_s - t0)
            t_last, _, pulses_then = self._marks[side]
            if now_s - t_last > self.stall_s and (side in progress.failed or
                                                  pulses - pulses_then >= self.stall_pulses):
                log.error("camera %s: no frame for %.1f s (%d pulses)", side, now_s - t_last, pulses - pulses_then)
                return fps, side
        return fps, None


class SensorSupervisor:
    """The trigger and the cameras of ``config()``: ``up``/``down``, reconnection with backoff, fault checks.

    Args:
        config: the daemon's current rig config (read at each use: the bracket table can change).
        state: the shared state store (sensor states, errors, fps, the panel's message).
        on_event: where the trigger client sends TRIGGER events (the event pump's ``put``).
        roi: camera region of interest (width, height), None each to keep the camera's.
        backoff_s: first and maximum reconnection delays; ``idle_check_s``: period of the idle cameras' GVCP check;
        camera_stall_s: see :class:`StallWatch`.
        open_camera, open_trigger: the device seams (real devices by default).
    """

    def __init__(self, config: Callable[[], RigConfig], state: RigState, on_event: Callable[[TriggerEvent], None],
                 *, roi: tuple[int | None, int | None] = (None, None), backoff_s: tuple[float, float] = (0.5, 8.0),
                 idle_check_s: float = 2.0, camera_stall_s: float = 2.0, open_camera: OpenCamera = open_gige_camera,
                 open_trigger: OpenTrigger = open_trigger_client) -> None:
        self._config = config
        self.state = state
        self._on_event = on_event
        self.roi = roi
        self.idle_check_s = idle_check_s
        self._open_camera = open_camera
        self._open_trigger = open_trigger
        self._lock = threading.RLock()
        self.on = False  # SENSORS pressed (devices are kept up, and reconnected)
        self._trigger: TriggerDevice | None = None
        self._cameras: dict[str, Camera] = {}
        self._backoff = {name: Backoff(*backoff_s) for name in ("trigger", "left", "right")}
        self._trigger_reboots_seen = 0
        self._last_idle_check = 0.0
        self.stalls = StallWatch(camera_stall_s)

    # ------------------------------------------------------------------------------------------------ reading
    @property
    def trigger(self) -> TriggerDevice | None:
        return self._trigger

    def cameras(self) -> dict[str, Camera]:
        """The cameras up now (a copy)."""
        with self._lock:
            return dict(self._cameras)

    def missing_sides(self) -> list[str]:
        """Sides of the config whose camera is not up."""
        with self._lock:
            return [cc.side for cc in self._config().cameras if cc.side not in self._cameras]

    # ------------------------------------------------------------------------------------------------ up / down
    def up(self) -> bool:
        """Open and configure the trigger and both cameras; True when all are up (each failure -> ERR)."""
        with self._lock:
            self.on = True
            ok = self._trigger_up()
            for cam in self._config().cameras:
                ok = self._camera_up(cam.side) and ok
            self.state.set_message("SENSORS OK" if ok else "SENSOR ERROR")
            return ok

    def down(self) -> None:
        """Close every device (state OFF)."""
        with self._lock:
            self.on = False
            for side in list(self._cameras):
                self._camera_down(side, SensorState.OFF)
            self.trigger_down(SensorState.OFF)
            self.state.set_message("SENSORS OFF")

    def _trigger_up(self) -> bool:
        if self._trigger is not None:
            return True
        cfg = self._config()
        tc = cfg.trigger
        try:
            device = self._open_trigger(tc, self._on_event, cfg.period_us, cfg.brackets_us)
        except Exception as exc:
            self._backoff["trigger"].failed()
            self.state.set_state("trigger", SensorState.ERR, f"{tc.port}: {exc}")
            log.error("trigger on %s: %s", tc.port, exc)
            return False
        self._trigger = device
        self._trigger_reboots_seen = device.reboots
        self._backoff["trigger"].reset()
        self.state.set_state("trigger", SensorState.IDLE)
        log.info("trigger up on %s", tc.port)
        return True

    def trigger_down(self, new_state: SensorState, error: str | None = None) -> None:
        with self._lock:
            device, self._trigger = self._trigger, None
            if device is not None:
                with contextlib.suppress(Exception):
                    device.stop()
                with contextlib.suppress(Exception):
                    device.close()
            self.state.set_state("trigger", new_state, error)

    def _camera_up(self, side: str) -> bool:
        if side in self._cameras:
            return True
        cfg = self._config()
        cc = cfg.camera(side)
        width, height = self.roi
        try:
            cam = self._open_camera(cc, settings_from_config(cc, width=width, height=height,
                                                             exposure_us=cfg.brackets_us[0]))
        except Exception as exc:
            self._backoff[side].failed()
            self.state.set_state(CAM_SENSOR[side], SensorState.ERR, f"{cc.address or cc.device_id}: {exc}")
            log.error("camera %s (%s): %s", side, cc.address or cc.device_id, exc)
            return False
        self._cameras[side] = cam
        self._backoff[side].reset()
        self.state.set_state(CAM_SENSOR[side], SensorState.IDLE)
        log.info("camera %s up: %s", side, cc.address or cc.device_id)
        return True

    def _camera_down(self, side: str, new_state: SensorState, error: str | None = None) -> None:
        cam = self._cameras.pop(side, None)
        if cam is not None:
            with contextlib.suppress(Exception):
                cam.stop()
            with contextlib.suppress(Exception):
                cam.close()
        self.state.set_state(CAM_SENSOR[side], new_state, error)
        self.state.set_fps(side, 0.0)

    # ------------------------------------------------------------------------------------------------ failures
    def camera_failed(self, side: str, error: str) -> None:
        """A camera could not stream: closed, ERR, reconnected later with backoff."""
        with self._lock:
            self._camera_down(side, SensorState.ERR, error)
            self._backoff[side].failed()

    def trigger_failed(self, error: str) -> None:
        """The trigger refused a command: closed, ERR, reconnected later with backoff."""
        self.trigger_down(SensorState.ERR, error)

    def camera_lost(self, side: str, error: str) -> Camera | None:
        """A camera stopped answering: ERR at once, reconnected later with backoff. Returns the camera, for the
        caller to close with :func:`close_in_background` once no acquisition uses it (a camera gone from the
        network answers the closing GVCP commands only after timeouts)."""
        with self._lock:
            cam = self._cameras.pop(side, None)
            self.state.set_state(CAM_SENSOR[side], SensorState.ERR, error)
            self.state.set_fps(side, 0.0)
            self._backoff[side].failed()
            return cam

    def set_states(self, state: SensorState) -> None:
        """Every device up shows ``state`` (REC while a segment records, IDLE otherwise)."""
        with self._lock:
            for side in self._cameras:
                self.state.set_state(CAM_SENSOR[side], state)
            if self._trigger is not None:
                self.state.set_state("trigger", state)

    def configure_trigger(self, period_us: int, brackets_us: Sequence[int]) -> None:
        """A new bracket table for the trigger when it is up (it must be stopped)."""
        with self._lock:
            if self._trigger is not None:
                self._trigger.configure(period_us, brackets_us)

    # ------------------------------------------------------------------------------------------------ checks
    def check_trigger(self, starved_s: float = 0.0) -> str | None:
        """A trigger that stopped answering or rebooted goes ERR; returns why (None when it is fine or down). A
        trigger silent while the daemon itself was starved (``starved_s`` > 0, see :class:`LoopWatch`) is looked at
        again at the next step: its heartbeats may be waiting to be read."""
        with self._lock:
            device = self._trigger
            if device is None:
                return None
            lost = device.peer_lost
            if not lost and device.reboots == self._trigger_reboots_seen:
                return None
            if lost and starved_s > 0.0 and device.reboots == self._trigger_reboots_seen:
                log.warning("trigger: no heartbeat while the daemon was starved (%.2f s): checked again next step",
                            starved_s)
                return None
            why = "lost (no heartbeat)" if lost else "rebooted"
            log.error("trigger %s", why)
            self.trigger_down(SensorState.ERR, why)
            return why

    def check_stalls(self, progress: Progress, now_s: float, starved_s: float = 0.0) -> str | None:
        """Frame rates of the cameras in the open acquisition into the state; returns a stalled side or None
        (``starved_s``: see :meth:`StallWatch.observe`)."""
        with self._lock:
            sides = list(self._cameras)
        fps, stalled = self.stalls.observe(progress, sides, now_s, starved_s)
        for side, value in fps.items():
            self.state.set_fps(side, value)
        return stalled

    def check_idle_cameras(self, now_s: float) -> None:
        """Cameras up but not in an acquisition: one GVCP register read each every ``idle_check_s``; a camera that
        does not answer goes ERR (closed in the background, reconnected with backoff)."""
        with self._lock:
            if not self._cameras or now_s - self._last_idle_check < self.idle_check_s:
                return
            self._last_idle_check = now_s
            for side, cam in list(self._cameras.items()):
                try:
                    cam.device.read_register(GEV_VERSION_REGISTER)
                except Exception as exc:
                    log.error("camera %s: no answer while idle: %s", side, exc)
                    close_in_background(self.camera_lost(side, f"no answer: {exc}"))

    def reconnect(self) -> bool:
        """Devices down while the sensors are on are opened again when their backoff is due; True if one came up."""
        with self._lock:
            if not self.on:
                return False
            changed = False
            if self._trigger is None and self._backoff["trigger"].due():
                changed = self._trigger_up() or changed
            for cc in self._config().cameras:
                if cc.side not in self._cameras and self._backoff[cc.side].due():
                    changed = self._camera_up(cc.side) or changed
            return changed


def close_in_background(cam: Camera | None) -> None:
    """Close ``cam`` on a thread of its own (GVCP timeouts of a camera gone never hold up the caller)."""
    if cam is not None:
        threading.Thread(target=_close_quietly, args=(cam,), name="close-camera", daemon=True).start()


def _close_quietly(cam: Camera) -> None:
    with contextlib.suppress(Exception):
        cam.close()
