"""Board capture through the trigger board (#42 item 3): ``bracketry calibrate capture --config rig.toml`` drives
line-triggered cameras (the ``basler_ace2`` profile: TriggerSource Line3, exposure = pulse width) with a one-entry
bracket table on the real trigger firmware in QEMU, pairs each pulse's frames as the daemon does, keeps an enough
set and solves it within the calibration tolerances.

QEMU models no GPIO, so the trigger's lines are modelled here: each TRIGGER event the firmware sends is the pulse
reaching both cameras' Line3 (before the host sees it, as on the rig). The cameras are doubles of the line-triggered
Basler: a pulse starts an exposure of the pulse's width; the frame (a view of a board moved by hand, rendered at that
exposure by the simulated rig's board renderer) arrives later on the camera's own thread.
"""

from __future__ import annotations

import json
import queue
import threading
import time
from collections import Counter
from collections.abc import Callable
from pathlib import Path
from types import SimpleNamespace
from typing import Any

import pytest
import yaml

from bracketry.cli import main as cli_main
from bracketry.sim.board_rig import BoardSource
from bracketry.sim.frames import read_frame_id
from bracketry_base.calibration.board import BoardSpec
from bracketry_base.errors import BracketryError
from bracketry_emulator.vo.calibration import CameraInfo, StereoRectifier
from bracketry_rig.boardcapture.trigger_board import TriggerCaptureOptions, capture_through_trigger
from bracketry_rig.cameras.camera import Frame
from bracketry_rig.daemon.config import parse_config
from bracketry_rig.daemon.sensors import open_trigger_client
from bracketry_rig.trigger.qemu import QemuTrigger

SIZE = (640, 400)
EXPOSURE_US = 800
#: pulses of the capture (a hand-held session's 40 views give an "enough" set; 20 solve within the tolerances)
PAIRS = 20
#: the calibration tolerances of docs/CALIBRATION.md (focal, principal point, baseline)
FOCAL_REL, PP_PX, BASELINE_REL = 0.005, 2.0, 0.01


class Views:
    """The board views the cameras will see, rendered ahead on a thread at the capture's exposure (a camera double
    delivers its frame right after the pulse, as the rig's cameras do, whatever the renderer's speed)."""

    def __init__(self, source: BoardSource, n: int) -> None:
        self.source, self.n = source, n
        self.frames: dict[str, list[Any]] = {"left": [], "right": []}
        self._ready = threading.Condition()
        self._thread = threading.Thread(target=self._render, name="board-views", daemon=True)
        self._thread.start()

    def _render(self) -> None:
        fills = {side: self.source.source(side) for side in ("left", "right")}
        for _ in range(self.n):
            for side in ("left", "right"):
                img = fills[side](EXPOSURE_US, *SIZE)
                with self._ready:
                    self.frames[side].append(img)
                    self._ready.notify_all()

    def get(self, side: str, k: int, timeout_s: float = 120.0) -> Any:
        with self._ready:
            assert self._ready.wait_for(lambda: len(self.frames[side]) > k, timeout=timeout_s), "renderer stalled"
            return self.frames[side][k]


class LineCamera:
    """A line-triggered camera double (the ``Camera`` protocol of the daemon): a pulse on its line exposes for the
    pulse's width (the view rendered at that exposure), the frame arrives on the camera's own thread."""

    def __init__(self, side: str, settings: Any, views: Views) -> None:
        self.side, self.settings, self.views = side, settings, views
        self.device = SimpleNamespace(read_register=lambda address: 0)
        self.exposures_us: list[int] = []
        self._pulses: queue.Queue[Any] = queue.Queue()
        self._thread: threading.Thread | None = None
        self._on_frame: Callable[[Frame], None] | None = None
        self.closed = False

    def set_exposure_us(self, exposure_us: float) -> None:
        raise AssertionError("a line-triggered camera's exposure is the pulse width, never written by the host")

    def software_trigger(self) -> None:
        raise AssertionError("a line-triggered camera is never fired in software")

    def pulse(self, event: Any) -> None:
        """The trigger's pulse on this camera's line."""
        if self._on_frame is not None:
            self._pulses.put(event)

    def start(self, on_frame: Callable[[Frame], None]) -> None:
        self._on_frame = on_frame
        self._thread = threading.Thread(target=self._run, name=f"line-camera-{self.side}", daemon=True)
        self._thread.start()

    def _run(self) -> None:
        k = 0
        on_frame = self._on_frame
        assert on_frame is not None
        while (event := self._pulses.get()) is not None:
            self.exposures_us.append(int(event.exposure_us))
            # the view rendered at the pulse's width (ahead, at the capture's exposure: any other is rendered now)
            img = (self.views.get(self.side, k) if event.exposure_us == EXPOSURE_US else
                   self.views.source.source(self.side)(int(event.exposure_us), *SIZE))
            on_frame(Frame(self.side, k + 1, k, 0, "success", img, SIZE[0], SIZE[1], "BayerRG12p",
                           int(event.t_start_device_us) * 1000, time.time_ns(),
                           exposure_us_reported=float(event.exposure_us)))
            k += 1

    def stop(self) -> None:
        self._on_frame = None
        self._pulses.put(None)
        if self._thread is not None:
            self._thread.join(timeout=30)

    def close(self) -> None:
        self.closed = True


def rig_config(tmp_path: Path, trigger_url: str) -> Any:
    return parse_config({
        "rig": {"output_dir": str(tmp_path / "rec"), "brackets_ms": [1, 2, 4, 8, 16, 32], "fps": 22},
        "trigger": {"kind": "qemu", "port": trigger_url},
        "panel": {"enabled": False},
        "cameras": [{"side": "left", "profile": "basler_ace2", "address": "192.0.2.11"},
                    {"side": "right", "profile": "basler_ace2", "address": "192.0.2.12"}]}, str(tmp_path / "rig.toml"))


@pytest.fixture(scope="module")
def views() -> Views:
    """Rendered while the firmware builds and QEMU boots."""
    return Views(BoardSource(BoardSpec(), SIZE, seed=1), PAIRS)


@pytest.mark.qemu
@pytest.mark.slow
def test_capture_drives_line_triggered_cameras_through_the_trigger_firmware(views: Views, trigger_qemu: QemuTrigger,
                                                                            tmp_path: Path) -> None:
    config = rig_config(tmp_path, trigger_qemu.url)
    cams: dict[str, LineCamera] = {}
    events: list[Any] = []
    tables: list[tuple[int, list[int]]] = []

    def open_camera(cc: Any, settings: Any) -> LineCamera:
        cams[cc.side] = LineCamera(cc.side, settings, views)
        return cams[cc.side]

    def open_trigger(tc: Any, on_event: Callable[[Any], None], period_us: int, brackets_us: Any) -> Any:
        tables.append((period_us, list(brackets_us)))

        def on_pulse(event: Any) -> None:  # the pulse reaches both lines, then its event the host
            events.append(event)
            for cam in cams.values():
                cam.pulse(event)
            on_event(event)

        return open_trigger_client(tc, on_pulse, period_us, brackets_us)

    out = tmp_path / "kept"
    opts = TriggerCaptureOptions(exposure_us=EXPOSURE_US, rate_hz=2.0, max_pairs=PAIRS, pair_timeout_s=60.0)
    board_yaml = yaml.safe_dump(BoardSpec().to_dict(), sort_keys=False)
    status, pairs = capture_through_trigger(config, out, BoardSpec(), board_yaml, opts,
                                            open_trigger=open_trigger, open_camera=open_camera)
    cap = json.loads((out / "capture.json").read_text())
    # every pulse gave one clean stereo pair; the kept views solve (fewer than "enough" suffice at this tolerance)
    assert pairs == PAIRS and not any(p["why"].startswith(("incomplete", "not paired")) for p in cap["pairs"]), \
        Counter(p["why"] for p in cap["pairs"])
    assert status["kept"] >= 10, Counter(p["why"] for p in cap["pairs"])
    # the trigger board ran a one-entry table at the capture's rate; every pulse was that exposure, bracket 0
    assert tables == [(500_000, [EXPOSURE_US])]
    assert events and {(e.bracket_index, e.exposure_us) for e in events} == {(0, EXPOSURE_US)}
    # the cameras were configured as line-triggered (Line3, the profile's TriggerWidth) and exposed for the pulse
    for cam in cams.values():
        assert cam.settings.profile == "basler_ace2" and cam.settings.trigger_source == "Line3"
        assert cam.exposures_us and set(cam.exposures_us) == {EXPOSURE_US} and cam.closed
    assert (out / "board.yaml").read_text() == board_yaml
    assert cap["trigger"] == "qemu" and cap["exposure_us"] == EXPOSURE_US and cap["gain"] == 0
    assert len(cap["pairs"]) == PAIRS and cap["pulse_exposures_us"][:PAIRS] == [EXPOSURE_US] * PAIRS
    # each kept pair is one pulse's two frames: both images show the same hand-held view
    names = sorted(p.name for p in (out / "left").glob("*.png"))
    assert len(names) == status["kept"] and names == sorted(p.name for p in (out / "right").glob("*.png"))
    import cv2

    for name in names:
        ids = [read_frame_id(cv2.imread(str(out / side / name), cv2.IMREAD_UNCHANGED)) for side in ("left", "right")]
        assert ids[0] is not None and ids[0] == ids[1], name

    cal = tmp_path / "cal"
    assert cli_main(["calibrate", "solve", str(out), "--out", str(cal), "--trials", "12", "--quiet"]) == 0
    truth = views.source.calib
    for side in ("left", "right"):
        info, cam = CameraInfo.from_yaml(cal / f"{side}.yaml"), truth.side(side)
        assert abs(info.K[0, 0] / cam.fx - 1) < FOCAL_REL and abs(info.K[1, 1] / cam.fy - 1) < FOCAL_REL
        assert abs(info.K[0, 2] - cam.cx) < PP_PX and abs(info.K[1, 2] - cam.cy) < PP_PX
    assert abs(StereoRectifier.from_dir(cal).baseline_m / truth.baseline_m - 1) < BASELINE_REL


def test_a_table_the_trigger_refuses_and_a_mixed_stream_are_one_line(tmp_path: Path, capsys) -> None:  # type: ignore[no-untyped-def]
    config = rig_config(tmp_path, "socket://127.0.0.1:9")
    with pytest.raises(BracketryError, match=r"--exposure-us 90000 at --rate-hz 20: .*does not fit"):
        capture_through_trigger(config, tmp_path / "a", BoardSpec(), "", TriggerCaptureOptions(exposure_us=90000,
                                                                                              rate_hz=20.0))
    (tmp_path / "rig.toml").write_text(
        f'[rig]\noutput_dir = "{tmp_path / "rec"}"\nbrackets_ms = [1]\nfps = 10\n[trigger]\nkind = "qemu"\n'
        'port = "socket://127.0.0.1:9"\n[panel]\nenabled = false\n'
        '[[cameras]]\nside = "left"\nprofile = "basler_ace2"\naddress = "192.0.2.11"\n'
        '[[cameras]]\nside = "right"\nprofile = "basler_ace2"\naddress = "192.0.2.12"\n')
    rig = ["--config", str(tmp_path / "rig.toml")]
    for args, problem in (([*rig, "--rig", "sim"], "give one stream"),
                          ([*rig, "--rate-hz", "0"], "--rate-hz must be above 0"),
                          ([*rig, "--exposure-us", "60000", "--rate-hz", "20"], "does not fit")):
        capsys.readouterr()
        assert cli_main(["calibrate", "capture", *args, "--out", str(tmp_path / "kept")]) == 2
        err = capsys.readouterr().err.strip()
        assert problem in err and len(err.splitlines()) == 1, err
        assert not (tmp_path / "kept").exists()
