"""Each frame's exposure read back (chunk, or the exposure register read at the software trigger) and compared with
its pulse width by verify; each frame's mid-exposure host time; recordings made before these fields still verify."""

from __future__ import annotations

import json
import math
import subprocess
import sys
from pathlib import Path
from types import SimpleNamespace
from typing import Any

import numpy as np
import pytest

from bracketry_base.recording import topics as T
from bracketry_base.recording.decode import decode
from bracketry_base.recording.msgdefs import MSGDEFS
from bracketry_base.recording.reader import RecordingReader
from bracketry_base.recording.verify import (
    EXPOSURE_READ_TOLERANCE_REL,
    EXPOSURE_READ_TOLERANCE_US,
    exposure_read_mismatch,
    verify_recording,
)
from bracketry_rig.cameras.camera import StreamStats
from bracketry_rig.cameras.triggering import ExposureReadbacks, SoftwareTrigger
from bracketry_rig.events import TriggerEvent
from bracketry_rig.pairing.pairer import PairedSet
from bracketry_rig.recording.recorder import Recorder, RecorderConfig, current_frame_meta, frame_meta_message
from bracketry_rig.recording.session import RecordingSession

pytestmark = pytest.mark.filterwarnings("ignore::DeprecationWarning:mcap_ros2.reader")

BRACKETS = [1000, 2000, 4000, 8000, 16000, 32000]
T0_NS = 1_700_000_000_000_000_000
PERIOD_NS = 45_454_000


def trigger_event(k: int, *, host_time: bool = True) -> TriggerEvent:
    return TriggerEvent(7, k, k % 6, BRACKETS[k % 6], 1_000_000 + k * 45_454,
                        T0_NS + k * PERIOD_NS if host_time else None)


def host_ns(ev: TriggerEvent) -> int:
    assert ev.t_start_host_ns is not None
    return ev.t_start_host_ns


def frame(side: str, k: int, **fields: Any) -> SimpleNamespace:
    return SimpleNamespace(side=side, frame_id=k + 1, frame_index=k, skipped_ids=0, status="success",
                           image=np.full((4, 6), k, np.uint16), cam_timestamp_ns=T0_NS + k * PERIOD_NS + 50_000,
                           host_receive_ns=T0_NS + k * PERIOD_NS + 9_000_000, missing_packets=0,
                           **{"exposure_us_reported": None, **fields})


def record_sets(out: Path, sets: list[PairedSet], name: str = "t") -> Path:
    rec = Recorder(out, name, RecorderConfig(queue_max_items=1000),
                   metadata={"brackets_us": ",".join(map(str, BRACKETS)), "fps": "22.0"}).start()
    for pset in sets:
        if pset.event is not None:
            assert rec.put_event(pset.event)
        assert rec.put_set(pset)
    rec.stop()
    assert rec.summary.error is None
    return Path(rec.summary.files[0])


def frame_metas(path: Path, side: str) -> list[Any]:
    reader = RecordingReader(path)
    out = []
    for msg in reader.messages({T.frame_meta_topic(side)}):
        schema = reader.schemas[reader.channels[msg.channel_id][1]][2]
        out.append(decode(msg.schema_name, msg.data, schema))
    return out


def test_the_tolerance_covers_the_granularity_and_nothing_more() -> None:
    assert (EXPOSURE_READ_TOLERANCE_US, EXPOSURE_READ_TOLERANCE_REL) == (1.0, 0.005)
    assert not exposure_read_mismatch(1005.0, 1000)  # 0.5 % of 1 ms
    assert exposure_read_mismatch(1005.5, 1000) and exposure_read_mismatch(994.0, 1000)
    assert not exposure_read_mismatch(51.0, 50) and exposure_read_mismatch(51.5, 50)  # 1 µs below 200 µs
    assert not exposure_read_mismatch(32000.0 * 1.0049, 32000)
    assert not exposure_read_mismatch(math.nan, 1000)  # nothing read back: nothing to compare


def test_a_chunk_one_frame_behind_flags_every_frame_from_the_first_change(tmp_path: Path) -> None:
    """Aravis #312: on some models the ExposureTime chunk carries the previous frame's exposure. The first frame's
    chunk is right (the camera held that exposure before), every later one is one bracket behind: all flagged."""
    n = 24
    sets = []
    for k in range(n):
        ev = trigger_event(k)
        lagging = BRACKETS[max(k - 1, 0) % 6]
        frames = {"left": frame("left", k, exposure_us_reported=float(lagging)),
                  "right": frame("right", k, exposure_us_reported=float(BRACKETS[k % 6]))}
        sets.append(PairedSet(k, ev, frames, host_ns(ev)))
    path = record_sets(tmp_path, sets)
    report = verify_recording(path)
    left, right = report.sides["left"], report.sides["right"]
    assert left.exposures_checked == right.exposures_checked == n
    assert left.exposure_mismatches == n - 1 and left.seqs["exposure_mismatches"] == list(range(1, n))
    assert right.exposure_mismatches == 0 and "exposure_mismatches" not in report.as_dict()["sides"]["right"]["seqs"]
    assert not report.ok and any("camera left: 23 exposure mismatches" in p for p in report.problems)
    metas = frame_metas(path, "left")
    assert {m.exposure_source for m in metas} == {"chunk"}
    assert [m.exposure_us_read for m in metas[:3]] == [1000.0, 1000.0, 2000.0]


def test_frame_meta_fields_mid_exposure_and_source_precedence() -> None:
    ev = trigger_event(3)  # 8000 µs
    chunk_and_register = frame("left", 3, exposure_us_reported=7990.0, exposure_us_register=8000.0)
    register_only = frame("right", 3, exposure_us_register=8000.0)
    pset = PairedSet(3, ev, {"left": chunk_and_register, "right": register_only}, host_ns(ev))
    left, right = frame_meta_message(pset, "left", chunk_and_register), frame_meta_message(pset, "right",
                                                                                           register_only)
    assert (left["exposure_us_read"], left["exposure_source"]) == (7990.0, "chunk")
    assert (right["exposure_us_read"], right["exposure_source"]) == (8000.0, "register")
    # mid-exposure = the pulse's start in host time + half the pulse width, the same for both cameras
    assert left["mid_exposure_host_ns"] == right["mid_exposure_host_ns"] == host_ns(ev) + 4_000_000
    nothing = frame("left", 3)
    meta = frame_meta_message(pset, "left", nothing)
    assert math.isnan(meta["exposure_us_read"]) and meta["exposure_source"] == "none"
    # no TRIGGER event: the frame time (earliest receive) + half the read-back exposure; nothing known: -1
    lost = PairedSet(3, None, {"left": register_only, "right": None}, register_only.host_receive_ns)
    assert frame_meta_message(lost, "left", register_only)["mid_exposure_host_ns"] == \
        register_only.host_receive_ns + 4_000_000
    assert frame_meta_message(lost, "left", frame("left", 3))["mid_exposure_host_ns"] == -1
    # an event without a host time (no clock model yet): the frame time stands for the trigger time
    no_clock = trigger_event(3, host_time=False)
    pset = PairedSet(3, no_clock, {"left": nothing, "right": None}, nothing.host_receive_ns)
    assert frame_meta_message(pset, "left", nothing)["mid_exposure_host_ns"] == nothing.host_receive_ns + 4_000_000


class RegisterCam:
    """A software-triggered camera whose exposure register clamps at ``max_us`` (a camera that did not take the
    exposure it was given); ``start`` hands its ``on_frame`` to the test, which delivers the frames."""

    def __init__(self, side: str, max_us: float = 1e9) -> None:
        self.side, self.max_us, self.exposure_us = side, max_us, 0.0
        self.exposure_readbacks = ExposureReadbacks()
        self.on_frame: Any = None
        self.reads = 0

    def set_exposure_us(self, exposure_us: float) -> None:
        self.exposure_us = min(float(exposure_us), self.max_us)

    def read_exposure_us(self) -> float:
        self.reads += 1
        return self.exposure_us

    def software_trigger(self) -> None:
        pass

    def start(self, on_frame: Any) -> None:
        self.on_frame = on_frame

    def stop(self) -> None:
        pass

    def stats(self) -> StreamStats:
        return StreamStats()


def test_register_read_back_at_the_software_trigger_reaches_the_frame_meta(tmp_path: Path) -> None:
    """The software trigger reads each camera's exposure register after the pulse; the session attaches it to that
    camera's frame of that pulse; a camera that clamped the exposure is caught by verify."""
    cams = {"left": RegisterCam("left"), "right": RegisterCam("right", max_us=20000)}
    recorder = Recorder(tmp_path, "reg", RecorderConfig(queue_max_items=1000),
                        metadata={"brackets_us": ",".join(map(str, BRACKETS)), "fps": "22.0"}).start()
    session = RecordingSession(cams, recorder, initial_alignment="count", window=3).start()
    trigger = SoftwareTrigger(cams, min_interval_s=0.0)
    trigger.arm(settle_s=0.0)
    n = 12
    for k in range(n):
        ev = trigger_event(k)
        trigger.fire(ev)
        session.on_trigger_event(ev)
        for side, cam in cams.items():
            cam.on_frame(frame(side, k))
    assert cams["left"].exposure_readbacks.get(5) == 32000.0 and cams["right"].exposure_readbacks.get(5) == 20000.0
    assert cams["left"].reads == n  # one GVCP read per pulse, none for the priming trigger
    session.stop(drain_s=0.2, expect_frames=n)
    path = Path(recorder.summary.files[0])
    for side in cams:
        metas = frame_metas(path, side)
        assert len(metas) == n and {m.exposure_source for m in metas} == {"register"}
        assert all(m.mid_exposure_host_ns == m.trigger_host_ns + m.exposure_us * 500 for m in metas)
    report = verify_recording(path)
    assert report.sides["left"].exposure_mismatches == 0 and report.sides["left"].exposures_checked == n
    # 32000 µs pulses (trigger_seq 5, 11) were clamped to 20000 µs by the right camera
    assert report.sides["right"].seqs["exposure_mismatches"] == [5, 11] and not report.ok


def test_a_new_acquisition_forgets_the_previous_read_backs() -> None:
    cam = RegisterCam("left")
    trigger = SoftwareTrigger({"left": cam}, min_interval_s=0.0)
    trigger.fire(trigger_event(0))
    assert len(cam.exposure_readbacks) == 1
    SoftwareTrigger({"left": cam}).arm(settle_s=0.0)  # the next acquisition numbers its pulses from 0 again
    assert cam.exposure_readbacks.get(0) is None
    store = ExposureReadbacks(keep=3)
    for k in range(5):
        store.put(k, 100.0 + k)
    assert [store.get(k) for k in range(5)] == [None, None, 102.0, 103.0, 104.0]


def _old_frame_meta_schema() -> str:
    """The FrameMeta definition of recordings made before the read-back fields (everything up to ``note``)."""
    text = MSGDEFS[T.SCHEMA_FRAME_META]
    head, sep, deps = text.partition("\n" + "=" * 80)
    lines = head.split("\n")
    end = next(i for i, line in enumerate(lines) if line.startswith("string note"))
    return "\n".join(lines[:end + 1]) + sep + deps


def test_a_recording_without_the_read_back_fields_verifies_as_before(tmp_path: Path,
                                                                     monkeypatch: pytest.MonkeyPatch) -> None:
    import bracketry_rig.recording.recorder as recorder_module

    old_defs = {**MSGDEFS, T.SCHEMA_FRAME_META: _old_frame_meta_schema()}
    assert "exposure_source" not in old_defs[T.SCHEMA_FRAME_META]
    monkeypatch.setattr(recorder_module, "MSGDEFS", old_defs)  # the recorder of before: the old schema in the file

    def sets(reported: dict[int, float]) -> list[PairedSet]:
        out = []
        for k in range(18):
            ev = trigger_event(k)
            frames = {s: frame(s, k, exposure_us_reported=reported.get(k)) for s in T.SIDES}
            out.append(PairedSet(k, ev, frames, host_ns(ev)))
        return out

    clean = record_sets(tmp_path / "clean", sets({}))
    chunks = record_sets(tmp_path / "chunks", sets({4: 16000 * 1.01, 7: 2000 * 1.5}))
    monkeypatch.undo()
    stored = RecordingReader(clean)
    list(stored.messages())
    assert all("exposure_source" not in text for name, _e, text in stored.schemas.values()
               if name == T.SCHEMA_FRAME_META)
    report = verify_recording(clean)
    assert report.ok, report.problems
    assert report.sides["left"].exposure_mismatches == report.sides["left"].exposures_checked == 0
    old = verify_recording(chunks)  # the chunk check of before: max(2 %, 20 µs)
    assert old.sides["left"].seqs["exposure_mismatches"] == [7] and old.sides["left"].exposures_checked == 2

    # an older FrameMeta read as today's definition (the ROS 1 export's frame_meta): fields derived as written now
    meta = current_frame_meta(frame_metas(chunks, "left")[4])
    assert (meta["exposure_us_read"], meta["exposure_source"]) == (16000 * 1.01, "chunk")
    assert meta["mid_exposure_host_ns"] == T0_NS + 4 * PERIOD_NS + 8_000_000
    from bracketry.cli import main as cli_main

    assert cli_main(["verify", str(clean)]) == 0
    pytest.importorskip("rosbags")
    bag = tmp_path / "old.bag"
    assert cli_main(["export", str(chunks), "--format", "rosbag1", "--out", str(bag)]) == 0
    from rosbags.highlevel import AnyReader

    with AnyReader([bag]) as reader:
        conns = [c for c in reader.connections if c.topic == T.frame_meta_topic("right")]
        metas: list[Any] = [reader.deserialize(raw, c.msgtype) for c, _t, raw in reader.messages(conns)]
    assert len(metas) == 18 and metas[7].exposure_source == "chunk" and metas[0].exposure_source == "none"
    assert metas[3].mid_exposure_host_ns == T0_NS + 3 * PERIOD_NS + 4_000_000


# -- from the fake cameras ------------------------------------------------------------------------------------------

@pytest.mark.aravis
def test_fake_camera_recording_reads_every_exposure_back_and_stamps_mid_exposure(tmp_path: Path) -> None:
    """Two fake cameras software-triggered through ``bracketry.testing.simrun`` (a private network namespace): every
    recorded frame carries its exposure register read at its trigger, verify finds no mismatch, and each frame's
    mid-exposure time is its trigger time plus half its exposure."""
    from bracketry_rig.cameras.netns import netns_argv, netns_available
    from bracketry_testkit import missing_component

    reason = netns_available()
    if reason:
        missing_component(f"private network namespace unavailable: {reason}")
    out, summary_path = tmp_path / "rec", tmp_path / "summary.json"
    argv = [sys.executable, "-m", "bracketry.testing.simrun", "--out", str(out), "--summary", str(summary_path),
            "--fps", "10.0", "--seconds", "3", "--width", "64", "--height", "48"]
    res = subprocess.run(netns_argv(argv), capture_output=True, text=True, timeout=240)
    assert res.returncode == 0, res.stderr[-2000:]
    summary = json.loads(summary_path.read_text())
    report = verify_recording(out)
    files = sorted(out.glob("*.mcap"))
    events = {}
    for f in files:
        for msg in RecordingReader(f).messages({T.TRIGGER_TOPIC}):
            ev = decode(msg.schema_name, msg.data)
            events[int(ev.trigger_seq)] = ev
    assert len(events) == summary["fired"] == 30
    for side in T.SIDES:
        sr = report.sides[side]
        assert sr.frames > 0 and sr.exposure_mismatches == 0, report.problems
        assert sr.exposures_checked == sr.frames  # every recorded frame was read back and compared
        metas = [m for f in files for m in frame_metas(f, side)]
        assert len(metas) == sr.frames
        for m in metas:
            ev = events[int(m.trigger_seq)]
            assert m.exposure_source == "register" and m.exposure_us_read == m.exposure_us == ev.exposure_us
            assert m.trigger_host_ns == ev.t_start_host_ns
            assert m.mid_exposure_host_ns == ev.t_start_host_ns + ev.exposure_us * 500
