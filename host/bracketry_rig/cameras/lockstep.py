"""Two cameras in a calibration mode: one fixed exposure, zero gain, triggered together, one stereo pair per pulse.

The recording's bracket cycle reduced to a table of one entry: every pulse is :class:`bracketry_rig.events.TriggerEvent`
with ``bracket_index`` 0 and the same ``exposure_us``, fired at both cameras by the profile's trigger adapter
(:func:`bracketry_rig.cameras.triggering.camera_trigger`). The profile's feature writes already hold the gain at 0
(``GainRaw`` 0 on the fake, ``GainAuto`` Off and ``Gain`` 0 on the Basler) and are read back before the first pulse.

Only software-triggered profiles are driven here (the Aravis fake: the simulated rig). Line-triggered cameras (the
Basler ace 2 on the real rig, exposure = the trigger board's pulse width) need the trigger board to fire a one-entry
bracket table; :class:`LockstepPair` refuses them with one line.
"""

from __future__ import annotations

import queue
import time
from types import TracebackType

from bracketry_base.errors import BracketryError
from bracketry_rig.cameras.camera import Frame, GigECamera
from bracketry_rig.cameras.profiles import CameraSettings, profile_kind
from bracketry_rig.cameras.triggering import SoftwareTrigger
from bracketry_rig.events import TriggerEvent

SIDES = ("left", "right")
#: how long a pulse waits for each camera's frame, s (a fake camera renders its frame in its fill callback)
FRAME_TIMEOUT_S = 20.0


class LockstepPair:
    """Open, configure and stream two cameras; :meth:`grab` fires one pulse at both and returns their frames.

    Args:
        addresses: side -> IPv4 address of each camera (unicast, never discovered).
        settings: the cameras' settings (profile, pixel format, ROI); ``exposure_us`` is the fixed exposure.
        frame_timeout_s: how long :meth:`grab` waits for each camera's frame.
    """

    def __init__(self, addresses: dict[str, str], settings: CameraSettings,
                 frame_timeout_s: float = FRAME_TIMEOUT_S) -> None:
        if profile_kind(settings.profile).trigger != "software":
            raise BracketryError(f"camera profile {settings.profile}: its cameras are triggered on a line by the "
                                 "trigger board; the calibration capture drives software-triggered cameras only "
                                 "(the simulated rig, --rig sim)")
        self.addresses = dict(addresses)
        self.settings = settings
        self.exposure_us = round(settings.exposure_us)
        self.frame_timeout_s = frame_timeout_s
        self.cameras: dict[str, GigECamera] = {}
        self._queues: dict[str, queue.Queue[Frame]] = {s: queue.Queue() for s in SIDES}
        self._trigger: SoftwareTrigger | None = None
        self._seq = 0

    def __enter__(self) -> LockstepPair:
        try:
            for side in SIDES:
                cam = GigECamera(self.addresses[side], side=side)
                self.cameras[side] = cam
                cam.configure(self.settings).raise_if_mismatch()
            for side, cam in self.cameras.items():
                cam.start(self._queues[side].put)
            self._trigger = SoftwareTrigger(self.cameras)
            self._trigger.arm()
            for q in self._queues.values():  # a priming frame is not a pulse's
                while not q.empty():
                    q.get_nowait()
        except BaseException:
            self.close()
            raise
        return self

    def grab(self) -> tuple[Frame, Frame]:
        """Fire one pulse at both cameras (the fixed exposure) and return (left, right) frames; raises
        BracketryError when a camera gives no frame within the timeout."""
        assert self._trigger is not None, "use LockstepPair as a context manager"
        event = TriggerEvent(session_id=0, trigger_seq=self._seq, bracket_index=0, exposure_us=self.exposure_us,
                             t_start_device_us=0, t_start_host_ns=time.time_ns())
        self._seq += 1
        self._trigger.fire(event)
        if self._trigger.failed:
            raise BracketryError(f"camera {', '.join(sorted(self._trigger.failed))}: the software trigger failed")
        frames = []
        for side in SIDES:
            try:
                frames.append(self._queues[side].get(timeout=self.frame_timeout_s))
            except queue.Empty:
                raise BracketryError(f"camera {side} ({self.addresses[side]}): no frame within "
                                     f"{self.frame_timeout_s:g} s of a trigger") from None
        return frames[0], frames[1]

    def close(self) -> None:
        for cam in self.cameras.values():
            cam.close()
        self.cameras = {}

    def __exit__(self, exc_type: type[BaseException] | None, exc: BaseException | None,
                 tb: TracebackType | None) -> None:
        self.close()
