"""The host's side of the trigger pulses: the adapter is chosen by the cameras' profiles; the software adapter writes
each exposure before any TriggerSoftware, spaces pulses, and skips a camera that failed (the real fake cameras are
fired through it by the recording and daemon tests)."""

from __future__ import annotations

import time
from typing import Any

import pytest

from bracketry.sim.clock import SteppedClock
from bracketry_base.errors import BracketryError
from bracketry_rig.cameras import triggering
from bracketry_rig.cameras.profiles import profile_kind, settings_from_config
from bracketry_rig.cameras.triggering import PRIMING_EXPOSURE_US, LineTrigger, SoftwareTrigger, camera_trigger
from bracketry_rig.daemon.config import CameraConfig, ConfigError, parse_config
from bracketry_rig.events import TriggerEvent


class SteppedTime:
    """The ``time`` module as the trigger sees it: monotonic time and sleeps on ``clock``, the rest real."""

    def __init__(self, clock: SteppedClock) -> None:
        self.monotonic, self.sleep = clock.now_s, clock.sleep

    def __getattr__(self, name: str) -> Any:
        return getattr(time, name)


class Cam:
    """Records the GVCP writes a camera received; ``fail`` makes its next TriggerSoftware fail."""

    def __init__(self, side: str, calls: list[tuple[str, str, float | None]]) -> None:
        self.side, self.calls, self.fail = side, calls, False

    def set_exposure_us(self, exposure_us: float) -> None:
        self.calls.append((self.side, "exposure", exposure_us))

    def software_trigger(self) -> None:
        if self.fail:
            raise OSError("GVCP timeout")
        self.calls.append((self.side, "trigger", None))


def event(seq: int, exposure_us: int = 2000) -> TriggerEvent:
    return TriggerEvent(session_id=1, trigger_seq=seq, bracket_index=0, exposure_us=exposure_us, t_start_device_us=0)


def test_profiles_choose_the_adapter_and_the_settings() -> None:
    calls: list[tuple[str, str, float | None]] = []
    cams = {"left": Cam("left", calls), "right": Cam("right", calls)}
    soft = camera_trigger(cams, {"left": "aravis_fake", "right": "aravis_fake"})
    line = camera_trigger(cams, {"left": "basler_ace2", "right": "basler_ace2"})
    assert isinstance(soft, SoftwareTrigger) and soft.initial_alignment == "host_time"
    assert isinstance(line, LineTrigger) and line.initial_alignment == "count"
    with pytest.raises(BracketryError, match="mixed"):
        camera_trigger(cams, {"left": "aravis_fake", "right": "basler_ace2"})
    assert line.fire(event(0)) == ("left", "right") and not calls  # the pulse reached the lines: nothing to write
    line.remove("left")
    assert line.fire(event(1)) == ("right",) and line.frames_expected == 2

    fake = settings_from_config(CameraConfig(side="left", profile="aravis_fake", address="127.0.0.2"),
                                exposure_us=3000)
    basler = settings_from_config(CameraConfig(side="left", profile="basler_ace2", address="10.0.0.2"))
    assert (fake.trigger_source, fake.packet_size_bytes, fake.pixel_format, fake.exposure_us) == \
        ("Software", None, "Mono16", 3000.0)
    assert (basler.trigger_source, basler.packet_size_bytes, basler.packet_delay_ticks) == ("Line3", 9000, 0)
    assert profile_kind("aravis_fake").trigger == "software"
    with pytest.raises(BracketryError, match="unknown camera profile"):
        profile_kind("webcam")
    mixed = {"rig": {"output_dir": "/tmp/x", "brackets_ms": [1, 2], "fps": 20},
             "cameras": [{"side": "left", "profile": "aravis_fake", "address": "127.0.0.2"},
                         {"side": "right", "profile": "basler_ace2", "address": "127.0.0.3"}]}
    with pytest.raises(ConfigError, match="one camera is triggered on a line and the other in software"):
        parse_config(mixed, "mixed")


def test_software_trigger_writes_exposures_first_spaces_pulses_and_skips_a_failed_camera(
        monkeypatch: pytest.MonkeyPatch) -> None:
    clock = SteppedClock(100.0)  # the trigger's time: moves only when it waits
    monkeypatch.setattr(triggering, "time", SteppedTime(clock))
    calls: list[tuple[str, str, float | None]] = []
    cams = {"left": Cam("left", calls), "right": Cam("right", calls)}
    trig = SoftwareTrigger(cams, min_interval_s=0.05)
    trig.arm(settle_s=0.0)
    assert calls == [("left", "exposure", PRIMING_EXPOSURE_US), ("left", "trigger", None),
                     ("right", "exposure", PRIMING_EXPOSURE_US), ("right", "trigger", None)]
    calls.clear()
    clock.slept.clear()
    assert trig.fire(event(0, 1000)) == ("left", "right")
    assert clock.slept == []  # the first pulse waits for nothing
    assert trig.fire(event(1, 4000), sides=["right"]) == ("right",)  # the left camera misses this pulse
    assert clock.slept == [pytest.approx(0.05)]  # the second pulse waited for the first one's interval
    assert calls == [("left", "exposure", 1000), ("right", "exposure", 1000), ("left", "trigger", None),
                     ("right", "trigger", None), ("right", "exposure", 4000), ("right", "trigger", None)]
    cams["right"].fail = True
    calls.clear()
    assert trig.fire(event(2)) == ("left", "right") and trig.failed == {"right"}
    assert trig.fire(event(3)) == ("left",)  # never written to again in this acquisition
    assert [c for c in calls if c[0] == "right"] == [("right", "exposure", 2000)]
    trig.remove("left")
    assert trig.fire(event(4)) == () and trig.frames_expected == 5
