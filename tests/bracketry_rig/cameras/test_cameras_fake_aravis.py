"""The camera layer against an in-process Aravis fake GigE camera on 127.0.0.1 (opened by IP, never discovered)."""

from __future__ import annotations

import threading
import time

import numpy as np
import pytest

from bracketry_rig.cameras.aravis_gi import CameraError

pytestmark = pytest.mark.aravis

W, H = 160, 100
PRIMING_US = 77


def pixels(exposure_us: int, width: int, height: int) -> np.ndarray:
    y, x = np.mgrid[0:height, 0:width]
    return ((x * 3 + y * 5 + exposure_us // 10) % 4096).astype(np.uint16)


@pytest.fixture
def fake_camera():  # type: ignore[no-untyped-def]
    from bracketry_rig.cameras.fake import FakeCameraServer

    server = FakeCameraServer("127.0.0.1", "PYTEST01", image_source=pixels).start()
    try:
        yield server
    finally:
        server.stop()


def grab(cam, exposures_us: list[int], timeout_s: float = 20.0) -> list:  # type: ignore[no-untyped-def]
    frames: list = []
    got = threading.Event()

    def on_frame(f):  # type: ignore[no-untyped-def]
        frames.append(f)
        got.set()

    cam.start(on_frame)
    try:
        # the Aravis 0.8 fake may lose the first software trigger after AcquisitionStart: prime it, drop the result
        cam.set_exposure_us(PRIMING_US)
        cam.software_trigger()
        time.sleep(0.3)
        frames.clear()
        for e in exposures_us:
            n = len(frames)
            got.clear()
            cam.set_exposure_us(e)
            cam.software_trigger()
            deadline = time.monotonic() + timeout_s
            while len(frames) <= n and time.monotonic() < deadline:
                got.wait(0.05)
    finally:
        cam.stop()
    return frames


def test_fake_profile_reads_back_and_serves_our_pixels(fake_camera) -> None:  # type: ignore[no-untyped-def]
    from bracketry_rig.cameras.camera import GigECamera
    from bracketry_rig.cameras.profiles import CameraSettings

    with GigECamera("127.0.0.1", side="left") as cam:
        info = cam.info()
        assert info["vendor"] == "Aravis" and "Mono16" in info["pixel_formats"]
        report = cam.configure(CameraSettings(profile="aravis_fake", pixel_format="Mono16", width=W, height=H))
        assert report.ok, report.as_rows()
        assert {r.name: r.read for r in report.results}["TriggerSource"] == "Software"
        exposures = [1000, 2000, 4000, 8000, 16000, 32000]
        frames = grab(cam, exposures)
    assert len(frames) == len(exposures)
    served = [e for e in fake_camera.exposures() if e != PRIMING_US]
    assert served == exposures  # the exposure of each served frame is readable
    for f, e in zip(frames, exposures, strict=True):
        assert f.status == "success" and f.pixel_format == "Mono16"
        assert np.array_equal(f.image, pixels(e, W, H))  # 12-bit codes through Mono16, bit-exact
    assert [f.frame_index - frames[0].frame_index for f in frames] == list(range(6))
    assert all(f.skipped_ids == 0 for f in frames)
    assert frames[-1].cam_timestamp_ns > frames[0].cam_timestamp_ns


def test_lost_software_triggers_are_read_from_the_relays_register(fake_camera) -> None:  # type: ignore[no-untyped-def]
    """The count of triggers the fake lost reaches a client over GVCP (the register its profile names)."""
    from bracketry_rig.cameras.camera import GigECamera
    from bracketry_rig.cameras.profiles import CameraSettings

    with GigECamera("127.0.0.1", side="left") as cam:
        assert cam.read_lost_triggers() is None  # not configured: no profile, no register
        cam.configure(CameraSettings(profile="aravis_fake", pixel_format="Mono16", width=W, height=H))
        assert cam.read_lost_triggers() == 0
        with fake_camera.relay._lock:
            fake_camera.relay._lost = 3
        assert cam.read_lost_triggers() == 3


def test_basler_profile_on_the_fake_refuses_with_a_clear_message(fake_camera) -> None:  # type: ignore[no-untyped-def]
    from bracketry_rig.cameras.camera import GigECamera
    from bracketry_rig.cameras.profiles import CameraSettings

    with GigECamera("127.0.0.1", side="right") as cam:
        report = cam.configure(CameraSettings(profile="basler_ace2", width=W, height=H))
        assert not report.ok
        with pytest.raises(CameraError) as exc:
            report.raise_if_mismatch()
    msg = str(exc.value)
    assert "refusing to record" in msg and "ExposureMode absent" in msg and "BayerRG12p" in msg
    assert "\n" not in msg


def test_configured_device_id_must_match_the_camera_at_the_address(fake_camera) -> None:  # type: ignore[no-untyped-def]
    from bracketry_rig.cameras.camera import GigECamera

    with GigECamera("127.0.0.1", side="left") as cam:
        cam.check_identity("PYTEST01")  # the fake's serial number
        with pytest.raises(CameraError, match="not the configured device_id 'OTHER01'"):
            cam.check_identity("OTHER01")


def test_packet_loss_marks_frames_incomplete(fake_camera) -> None:  # type: ignore[no-untyped-def]
    from bracketry_rig.cameras.camera import GigECamera
    from bracketry_rig.cameras.profiles import CameraSettings

    fake_camera.set_lost_packet_ratio(0.05)
    with GigECamera("127.0.0.1", side="left") as cam:
        cam.configure(CameraSettings(profile="aravis_fake", pixel_format="Mono16", width=W, height=H,
                                     packet_size_bytes=576)).raise_if_mismatch()
        frames = grab(cam, [4000] * 12, timeout_s=5.0)
        stats = cam.stats().as_dict()
    bad = [f for f in frames if f.status != "success"]
    assert bad, "5 % packet loss over ~70 packets per frame must hit some frames"
    assert all(f.image is None for f in bad)
    assert 0 < sum(f.missing_packets for f in frames) <= stats["n_missing_packets"]  # (priming frame excluded)
    assert len(bad) <= stats["frames_incomplete"] <= len(bad) + 1


def test_open_by_device_id_needs_a_private_namespace() -> None:
    from bracketry_rig.cameras.camera import GigECamera

    with pytest.raises(CameraError, match="discovery"):
        GigECamera(device_id="Aravis-Fake-X", side="left")


def test_cameras_cli_probe_configure_grab(fake_camera, tmp_path, capsys) -> None:  # type: ignore[no-untyped-def]
    from bracketry.cli import main as cli_main

    assert cli_main(["cameras", "probe", "--address", "127.0.0.1"]) == 0
    out = capsys.readouterr().out
    assert "Aravis Fake" in out and "ExposureMode" in out and "(absent)" in out
    # the Basler profile is refused on the fake, with the reason, exit 1
    assert cli_main(["cameras", "configure", "--address", "127.0.0.1"]) == 1
    captured = capsys.readouterr()
    assert "refusing to record" in captured.err
    assert cli_main(["cameras", "configure", "--address", "127.0.0.1", "--profile", "aravis_fake",
                     "--width", str(W), "--height", str(H)]) == 0
    assert cli_main(["cameras", "grab", "--address", "127.0.0.1", "--profile", "aravis_fake", "--width", str(W),
                     "--height", str(H), "--count", "3", "--software-trigger", "--exposure-us", "4000",
                     "--out", str(tmp_path)]) == 0
    out = capsys.readouterr().out
    assert out.count(" success ") == 3
    import cv2

    pngs = sorted(tmp_path.glob("*.png"))
    assert len(pngs) == 3
    assert np.array_equal(cv2.imread(str(pngs[0]), cv2.IMREAD_UNCHANGED), pixels(4000, W, H))


def test_cameras_cli_bad_address_is_one_line() -> None:
    from bracketry.cli import main as cli_main

    # 127.0.0.9 has no camera: a clear one-line error and exit 2, not a traceback
    assert cli_main(["cameras", "probe", "--address", "127.0.0.9"]) == 2


HOLDER = """
import time
from bracketry_rig.cameras.camera import GigECamera
cam = GigECamera("127.0.0.1", side="holder")
print("held", flush=True)
time.sleep(120)
"""


def test_control_privilege_of_a_killed_controller_is_taken_over(fake_camera) -> None:  # type: ignore[no-untyped-def]
    """A daemon restarted right after SIGKILL finds the camera still controlled by its dead predecessor: opening
    waits for the heartbeat timeout and takes control (streaming works); a live controller is refused clearly."""
    import signal
    import subprocess
    import sys

    from bracketry_rig.cameras.camera import GigECamera
    from bracketry_rig.cameras.profiles import CameraSettings

    holder = subprocess.Popen([sys.executable, "-c", HOLDER], stdout=subprocess.PIPE, text=True)
    try:
        assert holder.stdout is not None and holder.stdout.readline().strip() == "held"
        with pytest.raises(CameraError, match=r"another application controls the camera at 127\.0\.0\.1"):
            GigECamera("127.0.0.1", side="left", control_wait_s=0.5)
        holder.send_signal(signal.SIGKILL)
        holder.wait(10)
        with GigECamera("127.0.0.1", side="left") as cam:
            assert cam.device.is_controller()
            cam.configure(CameraSettings(profile="aravis_fake", pixel_format="Mono16", width=W,
                                         height=H)).raise_if_mismatch()
            frames = grab(cam, [2000, 4000])
        assert [f.status for f in frames] == ["success", "success"]
    finally:
        if holder.poll() is None:
            holder.kill()
            holder.wait(10)


def test_a_camera_that_cannot_stream_fails_the_session_start_cleanly(fake_camera, tmp_path) -> None:  # type: ignore[no-untyped-def]
    """A camera without the control privilege cannot create its stream: the session names the camera, ends its
    pairing thread, and the recorder still closes a readable (empty) recording."""
    from bracketry_base.recording.reader import RecordingReader
    from bracketry_rig.cameras.camera import GigECamera
    from bracketry_rig.recording.recorder import Recorder, RecorderConfig
    from bracketry_rig.recording.session import RecordingSession, SessionStartError

    with GigECamera("127.0.0.1", side="left") as cam:
        cam.device.leave_control()
        recorder = Recorder(tmp_path, "s", RecorderConfig(sides=("left",))).start()
        session = RecordingSession({"left": cam}, recorder)
        with pytest.raises(SessionStartError, match="Controller privilege required") as exc:
            session.start()
        assert exc.value.side == "left"
        assert not any(t.name == "pairing" and t.is_alive() for t in threading.enumerate())
        summary = recorder.stop()
    assert summary.error is None and summary.files
    assert not list(RecordingReader(summary.files[0]).messages({"/stereo/left/image_raw"}))
