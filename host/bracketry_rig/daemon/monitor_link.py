"""The daemon's side of the browser monitor: its status snapshot, the actions it accepts, and start-up.

The monitor never touches the acquisition path: the recording session hands each paired set (after the recorder
took it) to :meth:`bracketry_rig.monitor.hub.PreviewHub.offer` (while the sensors are up and not recording, the daemon's
preview session does the same and writes nothing); everything else reads the daemon's state through
:class:`MonitorRig`. Its HTTP threads call the rig's actions, which take the daemon's action lock.
"""

from __future__ import annotations

import collections
import logging
import math
import time
from collections.abc import Sequence
from typing import TYPE_CHECKING, Any, Protocol

from bracketry_base.errors import BracketryError
from bracketry_rig.daemon.config import MonitorConfig, RigConfig
from bracketry_rig.daemon.state import RigState, SensorState
from bracketry_rig.monitor.core import disk_time_left_s
from bracketry_rig.wire import bproto

if TYPE_CHECKING:
    from bracketry_rig.monitor.hub import PreviewHub
    from bracketry_rig.monitor.server import MonitorServer

log = logging.getLogger("bracketry_rig.daemon")


class MonitorRig(Protocol):
    """What the monitor reads of the rig and the actions it may take (``bracketry_rig.daemon.rig.RigDaemon``)."""

    @property
    def config(self) -> RigConfig: ...

    @property
    def state(self) -> RigState: ...

    @property
    def recording(self) -> bool: ...

    @property
    def rec_name(self) -> str | None: ...

    @property
    def segment_index(self) -> int: ...

    @property
    def sensors_on(self) -> bool: ...

    def pairing_counters(self) -> dict[str, Any]: ...

    def last_status(self) -> dict[str, Any]: ...

    def sensors_up(self) -> bool: ...

    def sensors_down(self) -> None: ...

    def start_recording(self) -> bool: ...

    def stop_recording(self) -> dict[str, Any] | None: ...

    def set_brackets_us(self, brackets_us: Sequence[int]) -> None: ...


class DaemonBackend:
    """Implements :class:`bracketry_rig.monitor.server.Backend` for a :class:`MonitorRig`."""

    def __init__(self, daemon: MonitorRig) -> None:
        self.daemon = daemon
        self._disk: collections.deque[tuple[float, float]] = collections.deque(maxlen=120)

    def monitor_limits_us(self) -> tuple[tuple[int, ...], int, int]:
        cfg = self.daemon.config
        return tuple(cfg.brackets_us), bproto.MIN_EXPOSURE_US, cfg.period_us - bproto.EXPOSURE_MARGIN_US

    def monitor_status(self) -> dict[str, Any]:
        d = self.daemon
        snap = d.state.snapshot()
        counters = d.pairing_counters()
        last = d.last_status()
        cameras: dict[str, Any] = {}
        for cam in d.config.cameras:
            side = cam.side
            c = counters.get(side)
            temp = last.get(f"temperature_{side}_c")
            cameras[side] = {"state": SensorState(snap.states[f"cam_{side}"]).name,
                             "fps": round(snap.fps.get(side, 0.0), 2),
                             "frames": c.frames if c is not None else 0, "drops": c.drops if c is not None else 0,
                             "temperature_c": None if temp is None or not math.isfinite(temp) else round(temp, 1),
                             "error": snap.errors.get(f"cam_{side}")}
        now = time.monotonic()
        if d.recording:
            self._disk.append((now, float(snap.free_disk_mb)))
            while self._disk and now - self._disk[0][0] > 60.0:
                self._disk.popleft()
        else:
            self._disk.clear()
        left = disk_time_left_s(list(self._disk), snap.free_disk_mb, d.config.stop_free_mb)
        return {
            "time_ns": snap.time_ns,
            "sensors": {name: SensorState(v).name for name, v in snap.states.items()},
            "errors": snap.errors,
            "cameras": cameras,
            "disk": {"free_mb": snap.free_disk_mb, "time_left_s": None if left is None else round(left)},
            "recording": {"active": bool(d.recording), "name": d.rec_name, "segment": d.segment_index,
                          "seconds": snap.rec_seconds},
            "message": snap.message,
            "brackets_us": list(d.config.brackets_us),
            "fps_target": d.config.fps,
            "sensors_on": bool(d.sensors_on),
        }

    def monitor_action(self, action: str, body: dict[str, Any]) -> dict[str, Any]:
        from bracketry_rig.monitor.server import ActionError

        d = self.daemon
        if action == "sensors_on":
            return {"sensors_ok": bool(d.sensors_up())}
        if action == "sensors_off":
            if d.recording:
                raise ActionError("recording: stop it before switching the sensors off")
            d.sensors_down()
            return {}
        if action == "record_start":
            started = d.start_recording()
            if not d.recording:  # refused (disk low); a recording waiting for its sensors is on
                raise ActionError(f"recording refused: {d.state.snapshot().message}")
            return {"name": d.rec_name, "segment_started": bool(started)}
        if action == "record_stop":
            d.stop_recording()
            return {}
        if action == "apply_brackets":
            table = body.get("brackets_us")
            if not isinstance(table, list) or not table or not all(isinstance(v, int) and not isinstance(v, bool)
                                                                   for v in table):
                raise ActionError("brackets_us must be a list of integer microseconds", status=400)
            try:
                d.set_brackets_us(table)
            except BracketryError as exc:
                raise ActionError(str(exc), status=409 if d.recording else 400) from None
            return {"brackets_us": list(d.config.brackets_us)}
        raise ActionError(f"unknown action {action!r}", status=400)


def start_monitor(mc: MonitorConfig, rig: MonitorRig) -> tuple[PreviewHub, MonitorServer] | None:
    """Start the preview hub and the HTTP server of ``mc``; failures are logged, never fatal (None)."""
    from bracketry_rig.monitor.address import is_loopback, parse_listen
    from bracketry_rig.monitor.hub import PreviewHub
    from bracketry_rig.monitor.server import MonitorServer

    host, port = parse_listen(mc.listen)
    hub = PreviewHub(bayer=mc.bayer, white_dn=mc.white_dn, rate_hz=mc.preview_hz).start()
    try:
        server = MonitorServer(DaemonBackend(rig), hub, host, port).start()
    except BracketryError as exc:
        hub.close()
        log.error("%s", exc)
        return None
    log.info("monitor: %s", server.url)
    if not is_loopback(host):
        rig.state.set_message(f"WEB KEY {server.token}")
    return hub, server
