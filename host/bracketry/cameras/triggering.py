"""How the trigger device's pulses start the cameras' exposures, seen from the host: one interface, two adapters.

A TRIGGER event reports a pulse the trigger device emitted. With real cameras the pulse already reached each camera's
trigger line (:class:`LineTrigger`: the host has nothing to do). Cameras without a trigger line (the Aravis fake camera)
are fired by the host at each event: :class:`SoftwareTrigger` writes each camera's exposure, then executes its
TriggerSoftware command, standing for the pulse. Applications hold a :class:`CameraTrigger` and never ask which kind
it is; :func:`camera_trigger` picks it from the cameras' profiles (the profile layer says how a camera is triggered).

Threads: ``fire`` runs on one thread at a time (the daemon's event pump, or a harness's loop); ``remove``,
``failed`` and ``frames_expected`` may be called from another thread.
"""

from __future__ import annotations

import logging
import threading
import time
from collections.abc import Iterable, Mapping
from typing import Protocol

from bracketry.cameras.profiles import profile_kind
from bracketry.errors import BracketryError
from bracketry.events import TriggerEvent

log = logging.getLogger(__name__)

#: exposure (us) of the priming trigger fired after AcquisitionStart: marks a frame that is not a bracket
PRIMING_EXPOSURE_US = 77
#: shortest time between two software triggers: the fake camera polls its trigger register (~1 kHz), two triggers
#: closer than that would merge into one frame
SOFTWARE_TRIGGER_MIN_INTERVAL_S = 0.004


class TriggeredCamera(Protocol):
    """What a camera trigger adapter needs of a camera (``bracketry.cameras.camera.GigECamera``)."""

    def set_exposure_us(self, exposure_us: float) -> None: ...

    def software_trigger(self) -> None: ...


class CameraTrigger(Protocol):
    """The host's side of the pulses of one acquisition (one recording segment or preview session).

    ``initial_alignment``: how the pairer finds the first frame's pulse (``count``: the k-th frame since START;
    ``host_time``: the cameras were fired by the host, their timestamps are host time).
    """

    initial_alignment: str

    def arm(self) -> None:
        """Called once right after the cameras' AcquisitionStart, before the trigger device's START."""

    def fire(self, event: TriggerEvent, sides: Iterable[str] | None = None) -> tuple[str, ...]:
        """The pulse of ``event`` reaches the cameras (``sides``: only these; None: every camera still working).
        Returns the sides the pulse was meant for (cameras that failed before it are left out)."""

    def remove(self, side: str) -> None:
        """A camera left the acquisition: no further pulse is meant for it."""

    @property
    def failed(self) -> frozenset[str]:
        """Sides that failed a trigger (never fired again in this acquisition)."""

    @property
    def frames_expected(self) -> int:
        """Frames each camera will deliver for the pulses fired so far (one per pulse; priming frames not counted)."""


class LineTrigger:
    """Cameras on the trigger device's lines: each pulse starts their exposures in hardware; the host does nothing."""

    initial_alignment = "count"

    def __init__(self, sides: Iterable[str]) -> None:
        self._lock = threading.Lock()
        self._sides = list(sides)
        self._fired = 0

    def arm(self) -> None:
        return None

    def fire(self, event: TriggerEvent, sides: Iterable[str] | None = None) -> tuple[str, ...]:
        wanted = None if sides is None else set(sides)
        with self._lock:
            self._fired += 1
            return tuple(s for s in self._sides if wanted is None or s in wanted)

    def remove(self, side: str) -> None:
        with self._lock:
            self._sides = [s for s in self._sides if s != side]

    @property
    def failed(self) -> frozenset[str]:
        return frozenset()

    @property
    def frames_expected(self) -> int:
        with self._lock:
            return self._fired  # every reported pulse reached every camera's line: one frame each


class SoftwareTrigger:
    """Cameras without a trigger line: per pulse, write every camera's exposure, then fire each one's TriggerSoftware.

    A camera that fails a GVCP write is gone (each further write would wait for GVCP timeouts and hold up the other
    camera): it is skipped until the next acquisition and listed in ``failed``. Two pulses are fired at least
    ``min_interval_s`` apart (the fake camera would merge closer ones).
    """

    initial_alignment = "host_time"

    def __init__(self, cameras: Mapping[str, TriggeredCamera], *,
                 min_interval_s: float = SOFTWARE_TRIGGER_MIN_INTERVAL_S) -> None:
        self._lock = threading.Lock()
        self._cameras = dict(cameras)
        self._failed: set[str] = set()
        self._fired = 0
        self._last_fire_s = 0.0
        self.min_interval_s = min_interval_s
        #: host time (``time.time_ns()``) right before the last pulse's first TriggerSoftware
        self.fired_at_ns: int | None = None

    def arm(self, settle_s: float = 0.2, exposure_us: int = PRIMING_EXPOSURE_US) -> None:
        """Fire one priming trigger per camera right after AcquisitionStart: the Aravis 0.8 fake camera loses the
        first software trigger of each acquisition. A frame it may still give precedes every TRIGGER event, and the
        pairer (``initial_alignment="host_time"``) ignores it. ``exposure_us`` marks such a frame (not a bracket)."""
        for cam in self._live().values():
            cam.set_exposure_us(exposure_us)
            cam.software_trigger()
        time.sleep(settle_s)

    def _live(self, sides: Iterable[str] | None = None) -> dict[str, TriggeredCamera]:
        wanted = None if sides is None else set(sides)
        with self._lock:
            return {s: c for s, c in self._cameras.items()
                    if s not in self._failed and (wanted is None or s in wanted)}

    def fire(self, event: TriggerEvent, sides: Iterable[str] | None = None) -> tuple[str, ...]:
        wait_s = self._last_fire_s + self.min_interval_s - time.monotonic()
        if wait_s > 0:
            time.sleep(wait_s)
        self._last_fire_s = time.monotonic()
        cams = self._live(sides)
        for step in ("set_exposure_us", "software_trigger"):
            if step == "software_trigger":
                self.fired_at_ns = time.time_ns()
            for side, cam in cams.items():
                if side in self._failed:
                    continue
                try:
                    if step == "set_exposure_us":
                        cam.set_exposure_us(event.exposure_us)
                    else:
                        cam.software_trigger()
                except Exception as exc:
                    with self._lock:
                        self._failed.add(side)
                    log.warning("camera %s: software trigger failed: %s", side, exc)
        with self._lock:
            self._fired += 1
        return tuple(cams)

    def remove(self, side: str) -> None:
        with self._lock:
            self._cameras.pop(side, None)

    @property
    def failed(self) -> frozenset[str]:
        with self._lock:
            return frozenset(self._failed)

    @property
    def frames_expected(self) -> int:
        with self._lock:
            return self._fired


def camera_trigger(cameras: Mapping[str, TriggeredCamera], profiles: Mapping[str, str]) -> CameraTrigger:
    """The adapter for ``cameras`` (side -> camera) whose profiles (side -> profile name) say how they are
    triggered (``bracketry.cameras.profiles.profile_kind``). Raises BracketryError for a mix of both kinds."""
    kinds = {profile_kind(profiles[side]).trigger for side in cameras}
    if len(kinds) > 1:
        raise BracketryError(f"cameras {', '.join(sorted(cameras))}: mixed line and software triggering")
    if kinds == {"software"}:
        return SoftwareTrigger(cameras)
    return LineTrigger(cameras)
