"""How the trigger device's pulses start the cameras' exposures, seen from the host: one interface, two adapters.

A TRIGGER event reports a pulse the trigger device emitted. With real cameras the pulse already reached each camera's
trigger line (:class:`LineTrigger`: the host has nothing to do). Cameras without a trigger line (the Aravis fake camera)
are fired by the host at each event: :class:`SoftwareTrigger` writes each camera's exposure, then executes its
TriggerSoftware command, standing for the pulse. Applications hold a :class:`CameraTrigger` and never ask which kind
it is; :func:`camera_trigger` picks it from the cameras' profiles (the profile layer says how a camera is triggered).

Exposure read-back: right after a pulse's TriggerSoftware commands, :class:`SoftwareTrigger` reads each camera's
exposure register back (one GVCP read, ``read_exposure_us``; nothing writes it before the next pulse, so this is the
value the camera exposed with) into the camera's :class:`ExposureReadbacks` (``camera.exposure_readbacks``, keyed by
trigger_seq). The recording session attaches it to that camera's frame of that pulse once the pairer matched them
(``Frame.exposure_us_register``), and the recorder writes it as the frame's ``exposure_us_read`` (source ``register``)
when the camera sent no ExposureTime chunk. Cameras on trigger lines are not read per pulse (their chunk is the
read-back).

Trigger stamps: :class:`SoftwareTrigger` also notes, per camera, the host time (``time.time_ns()``) right before each
TriggerSoftware command went out and right after it was acknowledged, keyed by trigger_seq, into the camera's
:class:`TriggerStamps` (``camera.trigger_stamps``). A camera that stamps its frame with the receive time of its
trigger on the same clock (the Aravis fake behind its relay, ``bracketry_rig.cameras.fake_relay``) thereby tells which
pulse a frame is for: the k-th command went out after the (k-1)-th was acknowledged, so the stamps of consecutive
triggers never overlap (:meth:`TriggerStamps.pulse_of`). The recording session sets ``Frame.trigger_seq`` from it
and the pairer takes it as it is: a trigger the host fired late is still its own pulse's, never a missed pulse.

Threads: ``fire`` runs on one thread at a time (the daemon's event pump, or a harness's loop); ``remove``,
``failed`` and ``frames_expected`` may be called from another thread.
"""

from __future__ import annotations

import bisect
import logging
import threading
import time
from collections import OrderedDict
from collections.abc import Callable, Iterable, Mapping
from typing import Protocol

from bracketry_base.errors import BracketryError
from bracketry_rig.cameras.profiles import profile_kind
from bracketry_rig.events import TriggerEvent

log = logging.getLogger(__name__)

#: exposure (us) of the priming trigger fired after AcquisitionStart: marks a frame that is not a bracket
PRIMING_EXPOSURE_US = 77
#: shortest time between two software triggers: a camera ignores a trigger that comes while it is still taking the
#: previous frame (the fake camera of ``bracketry_rig.cameras.fake`` holds one instead, so it never merges two)
SOFTWARE_TRIGGER_MIN_INTERVAL_S = 0.004


#: read-backs an ``ExposureReadbacks`` keeps (the pairing window is 8..16 pulses; late frames come within ~1 s)
EXPOSURE_READBACKS_KEPT = 1024


class ExposureReadbacks:
    """One camera's exposure register as read back at each software trigger: trigger_seq -> microseconds, the latest
    ``keep`` pulses. Thread-safe: written on the trigger's thread, read on the pairing thread."""

    def __init__(self, keep: int = EXPOSURE_READBACKS_KEPT) -> None:
        self.keep = keep
        self._lock = threading.Lock()
        self._values: OrderedDict[int, float] = OrderedDict()

    def put(self, trigger_seq: int, exposure_us: float) -> None:
        with self._lock:
            self._values[trigger_seq] = float(exposure_us)
            self._values.move_to_end(trigger_seq)
            while len(self._values) > self.keep:
                self._values.popitem(last=False)

    def get(self, trigger_seq: int) -> float | None:
        with self._lock:
            return self._values.get(trigger_seq)

    def clear(self) -> None:
        """Forget every value (a new acquisition numbers its pulses from 0 again)."""
        with self._lock:
            self._values.clear()

    def __len__(self) -> int:
        with self._lock:
            return len(self._values)


#: trigger_seq under which the priming trigger's stamps are kept (a frame stamped by it is for no pulse)
PRIMING_SEQ = -1


class TriggerStamps:
    """One camera's software triggers as the host sent them: trigger_seq -> (``sent_ns``: host time right before the
    TriggerSoftware command went out, ``acked_ns``: right after it was acknowledged, or None while it is not), the
    latest ``keep``. Thread-safe: written on the trigger's thread, read on the pairing thread.

    The commands go out one after the other (the next only once the previous one was acknowledged), so a camera's
    receive time of trigger k lies in ``[sent_ns(k), acked_ns(k)]`` and those intervals do not overlap.
    """

    def __init__(self, keep: int = EXPOSURE_READBACKS_KEPT) -> None:
        self.keep = keep
        self._lock = threading.Lock()
        self._sent: list[int] = []  # sent_ns, ascending
        self._seqs: list[int] = []
        self._acked: list[int | None] = []

    def sent(self, trigger_seq: int, t_ns: int) -> None:
        """The TriggerSoftware command of ``trigger_seq`` goes out now (host time ``t_ns``)."""
        with self._lock:
            if self._sent and t_ns < self._sent[-1]:  # the host clock stepped back: earlier stamps mean nothing now
                self._sent, self._seqs, self._acked = [], [], []
            self._sent.append(int(t_ns))
            self._seqs.append(int(trigger_seq))
            self._acked.append(None)
            if len(self._sent) > 2 * self.keep:
                del self._sent[:-self.keep], self._seqs[:-self.keep], self._acked[:-self.keep]

    def acked(self, trigger_seq: int, t_ns: int) -> None:
        """The command of ``trigger_seq`` returned (acknowledged, or failed) at host time ``t_ns``."""
        with self._lock:
            if self._seqs and self._seqs[-1] == trigger_seq:
                self._acked[-1] = int(t_ns)

    def pulse_of(self, stamp_ns: int) -> int | None:
        """The trigger_seq of the trigger received at host time ``stamp_ns`` (a frame's stamp): the last one sent
        at or before it, unless it was acknowledged before it (then no trigger of ours was received then: None);
        None too before every stamp kept."""
        with self._lock:
            i = bisect.bisect_right(self._sent, stamp_ns) - 1
            if i < 0:
                return None
            acked = self._acked[i]
            if acked is not None and stamp_ns > acked:
                return None
            return self._seqs[i]

    def clear(self) -> None:
        """Forget every stamp (a new acquisition numbers its pulses from 0 again)."""
        with self._lock:
            self._sent, self._seqs, self._acked = [], [], []

    def __len__(self) -> int:
        with self._lock:
            return len(self._sent)


def frame_pulse(frame: object, stamps: TriggerStamps | None) -> int | None:
    """The trigger_seq ``frame``'s own trigger stamp shows (``cam_timestamp_ns`` looked up in the camera's
    ``stamps``), None when it shows none (no stamps, no timestamp, or a stamp outside every trigger's)."""
    stamp_ns = int(getattr(frame, "cam_timestamp_ns", 0) or 0)
    if stamps is None or stamp_ns <= 0:
        return None
    return stamps.pulse_of(stamp_ns)


class TriggeredCamera(Protocol):
    """What a camera trigger adapter needs of a camera (``bracketry_rig.cameras.camera.GigECamera``)."""

    def set_exposure_us(self, exposure_us: float) -> None: ...

    def software_trigger(self) -> None: ...

    # optional (``GigECamera`` has them; a camera without them is fired without read-back or stamps):
    # ``read_exposure_us() -> float``, ``exposure_readbacks: ExposureReadbacks``, ``trigger_stamps: TriggerStamps``


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
    ``min_interval_s`` apart (a camera busy with the previous frame would ignore a closer one). After every camera's
    TriggerSoftware, each camera's exposure register is read back into its ``exposure_readbacks`` under the pulse's
    trigger_seq (after the triggers, so the read does not spread the cameras' exposure starts; a failed read is
    logged and leaves no value). Each TriggerSoftware command is stamped into the camera's ``trigger_stamps``
    (module doc); ``clock_ns`` is the host clock of those stamps (``time.time_ns``, the clock the fake camera stamps
    its frames with; tests inject one).
    """

    initial_alignment = "host_time"

    def __init__(self, cameras: Mapping[str, TriggeredCamera], *,
                 min_interval_s: float = SOFTWARE_TRIGGER_MIN_INTERVAL_S,
                 clock_ns: Callable[[], int] | None = None) -> None:
        self._clock_ns = clock_ns or (lambda: time.time_ns())
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
            readbacks = getattr(cam, "exposure_readbacks", None)
            if readbacks is not None:
                readbacks.clear()  # this acquisition's pulses are numbered from 0 again
            stamps = _stamps(cam)
            if stamps is not None:
                stamps.clear()
            cam.set_exposure_us(exposure_us)
            self._trigger_one(cam, PRIMING_SEQ)
        time.sleep(settle_s)

    def _trigger_one(self, cam: TriggeredCamera, trigger_seq: int) -> None:
        """One camera's TriggerSoftware, stamped (sent, acknowledged) into its ``trigger_stamps``."""
        stamps = _stamps(cam)
        if stamps is not None:
            stamps.sent(trigger_seq, self._clock_ns())
        try:
            cam.software_trigger()
        finally:
            if stamps is not None:
                stamps.acked(trigger_seq, self._clock_ns())

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
                self.fired_at_ns = self._clock_ns()
            for side, cam in cams.items():
                if side in self._failed:
                    continue
                try:
                    if step == "set_exposure_us":
                        cam.set_exposure_us(event.exposure_us)
                    else:
                        self._trigger_one(cam, event.trigger_seq)
                except Exception as exc:
                    with self._lock:
                        self._failed.add(side)
                    log.warning("camera %s: software trigger failed: %s", side, exc)
        self._read_back(event.trigger_seq, cams)
        with self._lock:
            self._fired += 1
        return tuple(cams)

    def _read_back(self, trigger_seq: int, cams: Mapping[str, TriggeredCamera]) -> None:
        """Each fired camera's exposure register, as it stood at this pulse, into its ``exposure_readbacks``."""
        for side, cam in cams.items():
            read = getattr(cam, "read_exposure_us", None)
            readbacks = getattr(cam, "exposure_readbacks", None)
            if read is None or readbacks is None or side in self._failed:
                continue
            try:
                readbacks.put(trigger_seq, float(read()))
            except Exception as exc:
                log.warning("camera %s: exposure read-back of trigger_seq %d failed: %s", side, trigger_seq, exc)

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


def _stamps(cam: object) -> TriggerStamps | None:
    stamps = getattr(cam, "trigger_stamps", None)
    return stamps if isinstance(stamps, TriggerStamps) else None


def camera_trigger(cameras: Mapping[str, TriggeredCamera], profiles: Mapping[str, str]) -> CameraTrigger:
    """The adapter for ``cameras`` (side -> camera) whose profiles (side -> profile name) say how they are
    triggered (``bracketry_rig.cameras.profiles.profile_kind``). Raises BracketryError for a mix of both kinds."""
    kinds = {profile_kind(profiles[side]).trigger for side in cameras}
    if len(kinds) > 1:
        raise BracketryError(f"cameras {', '.join(sorted(cameras))}: mixed line and software triggering")
    if kinds == {"software"}:
        return SoftwareTrigger(cameras)
    return LineTrigger(cameras)
