"""MCAP writing and reading: CDR image codec, independent readers, truncation at any byte, queue overflow, verify."""

from __future__ import annotations

import dataclasses
import json
import time
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest

from bracketry.cli import main as cli_main
from bracketry_base.recording import topics as T
from bracketry_base.recording.mcap_writer import ChunkedMcapWriter
from bracketry_base.recording.msgdefs import MSGDEFS, decode_image, encode_image, stamp
from bracketry_base.recording.reader import RecordingReader, UnreadableRecordingError
from bracketry_base.recording.verify import recording_files, repair_recording, segment_folders, verify_recording
from bracketry_rig.events import TriggerEvent
from bracketry_rig.pairing.pairer import PairedSet
from bracketry_rig.recording.recorder import Recorder, RecorderConfig

pytestmark = pytest.mark.filterwarnings("ignore::DeprecationWarning:mcap_ros2.reader")

H, W = 24, 32
BRACKETS = [1000, 2000, 4000, 8000, 16000, 32000]


def image(seq: int, side: str) -> np.ndarray:
    rng = np.random.default_rng(seq * 2 + (side == "right"))
    return rng.integers(0, 4096, size=(H, W), dtype=np.uint16)


def make_set(k: int, *, drop: str | None = None, status: str = "success", event: bool = True,
             reported_us: float | None = None) -> PairedSet:
    ev = TriggerEvent(7, k, k % 6, BRACKETS[k % 6], 1_000_000 + k * 45_454, 1_700_000_000_000_000_000 + k * 45_454_000)
    frames = {}
    for side in T.SIDES:
        if side == drop:
            frames[side] = None
            continue
        frames[side] = SimpleNamespace(side=side, frame_id=k + 1, frame_index=k, skipped_ids=0, status=status,
                                       image=image(k, side) if status == "success" else None,
                                       cam_timestamp_ns=k * 45_454_000, host_receive_ns=ev.t_start_host_ns + 9_000_000,
                                       missing_packets=0 if status == "success" else 3,
                                       exposure_us_reported=reported_us)
    return PairedSet(k, ev if event else None, frames, ev.t_start_host_ns)


def record(tmp: Path, n: int, **kw) -> tuple[Path, Recorder]:  # type: ignore[no-untyped-def]
    metadata = {"brackets_us": ",".join(map(str, BRACKETS)), "fps": "22.0"}
    rec = Recorder(tmp, "t", RecorderConfig(queue_max_items=1000, **kw), metadata=metadata).start()
    for k in range(n):
        pset = make_set(k)
        if pset.event is not None:
            assert rec.put_event(pset.event)
        assert rec.put_set(pset)
        if k % 10 == 0:
            rec.put_status({"frames_left": k})
        time.sleep(0.001)
    rec.stop()
    return Path(rec.summary.files[0]), rec


def test_image_codec_matches_mcap_ros2_serializer() -> None:
    from mcap_ros2._dynamic import serialize_dynamic

    enc = serialize_dynamic(T.SCHEMA_IMAGE, MSGDEFS[T.SCHEMA_IMAGE])[T.SCHEMA_IMAGE]
    img = image(3, "left")
    for frame_id in ("camera_left", "c", "abc", "abcd"):
        ref = enc({"header": {"stamp": stamp(1_234_567_890_123), "frame_id": frame_id}, "height": H, "width": W,
                   "encoding": "bayer_rggb16", "is_bigendian": 0, "step": W * 2, "data": img.tobytes()})
        mine = b"".join(bytes(p) for p in encode_image(1_234_567_890_123, frame_id, img, "bayer_rggb16"))
        assert mine == ref
        back = decode_image(mine)
        assert back.stamp_ns == 1_234_567_890_123 and back.frame_id == frame_id
        assert np.array_equal(back.image, img)


def test_recording_is_read_by_mcap_ros2_and_rosbags(tmp_path: Path) -> None:
    path, rec = record(tmp_path, 30)
    assert rec.summary.error is None and rec.summary.overflows == 0
    from mcap_ros2.reader import read_ros2_messages

    left = [m for m in read_ros2_messages(str(path), topics=[T.image_topic("left")])]
    assert len(left) == 30
    for k, m in enumerate(left):
        assert m.ros_msg.encoding == "bayer_rggb16" and (m.ros_msg.height, m.ros_msg.width) == (H, W)
        assert np.array_equal(np.frombuffer(m.ros_msg.data, "<u2").reshape(H, W), image(k, "left"))
    from rosbags.highlevel import AnyReader

    with AnyReader([path]) as reader:
        counts = {c.topic: c.msgcount for c in reader.connections}
        metas = [reader.deserialize(raw, c.msgtype)
                 for c, _t, raw in reader.messages([c for c in reader.connections
                                                    if c.topic == T.frame_meta_topic("right")])]
    assert counts[T.image_topic("right")] == 30 and counts[T.TRIGGER_TOPIC] == 30
    assert [m.trigger_seq for m in metas] == list(range(30))
    assert metas[4].exposure_us == 16000 and metas[4].paired and metas[4].status == "success"


def test_every_truncation_reads_a_prefix(tmp_path: Path) -> None:
    path, _ = record(tmp_path, 40, chunk_max_bytes=20_000)
    data = path.read_bytes()
    full = len(list(RecordingReader(path).messages()))
    previous = 0
    cut = tmp_path / "cut.mcap"
    for size in [*range(64, len(data), max(1, len(data) // 60)), len(data) - 1]:
        cut.write_bytes(data[:size])
        reader = RecordingReader(cut)
        n = len(list(reader.messages()))
        assert reader.report.truncated
        assert previous <= n <= full
        previous = n
    assert previous > 0.8 * full
    with pytest.raises(UnreadableRecordingError):
        cut.write_bytes(b"not an mcap")
        list(RecordingReader(cut).messages())


def test_chunks_close_by_age(tmp_path: Path) -> None:
    w = ChunkedMcapWriter(tmp_path / "age.mcap", chunk_max_bytes=1 << 30, chunk_max_age_s=0.05)
    sid = w.register_schema(T.SCHEMA_TRIGGER, MSGDEFS[T.SCHEMA_TRIGGER].encode())
    cid = w.register_channel(T.TRIGGER_TOPIC, sid)
    w.add_message(cid, 1, b"\x00\x01\x00\x00" + bytes(32))
    time.sleep(0.1)
    w.tick()
    w._drain(block=True)
    # the chunk is on disk although the file is not finished and the chunk was far below its size limit
    reader = RecordingReader(tmp_path / "age.mcap")
    assert len(list(reader.messages())) == 1 and reader.report.truncated
    w.finish()


def test_queue_overflow_is_counted_never_silent(tmp_path: Path) -> None:
    rec = Recorder(tmp_path, "o", RecorderConfig(queue_max_items=2))
    rec.start()
    # the writer thread runs, but 500 sets offered at once overflow a 2-item queue
    accepted = sum(rec.put_set(make_set(k)) for k in range(500))
    rec.stop()
    assert rec.summary.overflows == 500 - accepted > 0


def test_verify_clean_and_problems_and_cli_exit_codes(tmp_path: Path, capsys) -> None:  # type: ignore[no-untyped-def]
    clean, _ = record(tmp_path / "clean", 60)
    report = verify_recording(clean)
    assert report.ok, report.problems
    assert report.sides["left"].frames == 60 and report.first_seq == 0 and report.last_seq == 59

    rec = Recorder(tmp_path / "bad", "b", RecorderConfig(queue_max_items=1000),
                   metadata={"brackets_us": ",".join(map(str, BRACKETS)), "fps": "22.0"}).start()
    for k in range(60):
        pset = make_set(k, drop="left" if k == 10 else None, status="missing_packets" if k == 20 else "success",
                        event=k != 30, reported_us=BRACKETS[k % 6] * (1.5 if k == 40 else 1.004))  # < 0.5 %: ok
        if k == 50:  # the trigger repeated a bracket: the cycle is broken
            pset.event = dataclasses.replace(pset.event, bracket_index=0)
        if pset.event is not None:
            rec.put_event(pset.event)
        rec.put_set(pset)
    rec.stop()
    bad = Path(rec.summary.files[0])
    r = verify_recording(bad)
    assert not r.ok
    assert r.sides["left"].seqs["drops"] == [10] and r.sides["right"].drops == 0
    assert r.sides["left"].seqs["incomplete"] == [20] and r.sides["right"].seqs["incomplete"] == [20]
    assert r.sides["left"].missing_packets == 3
    assert r.events_missing_seqs == [30]
    assert r.sides["left"].seqs["bracket_order_breaks"][0] == 50 == r.sides["right"].seqs["bracket_order_breaks"][0]
    assert r.sides["left"].seqs["exposure_mismatches"] == [40] == r.sides["right"].seqs["exposure_mismatches"]

    assert cli_main(["verify", str(clean)]) == 0
    capsys.readouterr()
    assert cli_main(["verify", str(bad), "--json"]) == 1
    doc = json.loads(capsys.readouterr().out)
    assert doc["reports"][0]["sides"]["left"]["seqs"]["drops"] == [10]
    assert cli_main(["verify", str(tmp_path / "missing.mcap")]) == 2
    junk = tmp_path / "junk.mcap"
    junk.write_bytes(b"hello")
    assert cli_main(["verify", str(junk), str(clean)]) == 2


def test_verify_json_and_repair_of_a_truncated_file(tmp_path: Path, capsys) -> None:  # type: ignore[no-untyped-def]
    path, _ = record(tmp_path, 80, chunk_max_bytes=30_000)
    data = path.read_bytes()
    cut = tmp_path / "cut.mcap"
    cut.write_bytes(data[: int(len(data) * 0.6)])
    capsys.readouterr()
    assert cli_main(["verify", str(cut), "--json", "--repair"]) == 1
    doc = json.loads(capsys.readouterr().out)
    rep = doc["reports"][0]
    assert rep["truncated"] and rep["readable"] and not rep["ok"]
    # the truncated file's frames verify clean apart from the lost tail
    assert rep["sides"]["left"]["drops"] == 0 and rep["sides"]["right"]["unpaired"] == 0
    repaired = Path(doc["repaired"][0]["repaired"])
    assert repaired.exists()
    from mcap.reader import make_reader

    with repaired.open("rb") as f:
        summary = make_reader(f).get_summary()
    assert summary is not None and summary.statistics.message_count == doc["repaired"][0]["messages"]
    r2 = verify_recording(repaired)
    assert not r2.truncated and r2.sides["left"].drops == 0
    with pytest.raises(Exception, match="never overwrites"):
        repair_recording(cut, cut)


def test_daemon_recording_root_with_segments_and_a_repaired_file(tmp_path: Path, capsys) -> None:  # type: ignore[no-untyped-def]
    root = tmp_path / "rec_1"
    record(root / "seg00", 40)
    cut_path, _ = record(root / "seg01", 80, chunk_max_bytes=30_000)  # the power went: seg01 is truncated
    cut_path.write_bytes(cut_path.read_bytes()[: int(cut_path.stat().st_size * 0.6)])
    assert recording_files(root / "seg01") == [cut_path]
    assert segment_folders(root) == [root / "seg00", root / "seg01"] and segment_folders(root / "seg00") == []

    capsys.readouterr()
    assert cli_main(["verify", str(root), "--json", "--repair"]) == 1  # each segment checked on its own
    doc = json.loads(capsys.readouterr().out)
    assert [Path(r["recording"]).name for r in doc["reports"]] == ["seg00", "seg01"]
    assert doc["reports"][0]["ok"] and doc["reports"][1]["truncated"]
    repaired = Path(doc["repaired"][0]["repaired"])
    assert repaired.parent == root / "seg01" and repaired.name.endswith(".repaired.mcap")

    # the repaired copy now stands in for the truncated file: its frames are read once, not twice
    assert recording_files(root / "seg01") == [repaired]
    r = verify_recording(root / "seg01")
    assert r.sides["left"].frames == r.last_seq - r.first_seq + 1 and r.sides["left"].drops == 0
    assert not any("two frames" in p for p in r.problems), r.problems
    assert r.tail_lost >= 0 and not r.truncated

    out = tmp_path / "tree"
    assert cli_main(["export", str(root), "--out", str(out), "-q"]) == 0
    assert sorted(p.name for p in out.iterdir()) == ["seg00", "seg01"]
    assert len(list((out / "seg00" / "camera_left").rglob("*.png"))) == 40
    assert cli_main(["export", str(root), "--format", "rosbag1", "--out", str(tmp_path / "x.bag")]) != 0
    assert "segments" in capsys.readouterr().err


def test_rosbag1_export_carries_the_camera_temperature_of_rig_status(tmp_path: Path) -> None:
    from rosbags.highlevel import AnyReader

    rec = Recorder(tmp_path / "r", "t", RecorderConfig(queue_max_items=1000),
                   metadata={"brackets_us": ",".join(map(str, BRACKETS)), "fps": "22.0"}).start()
    for k in range(12):
        if k == 6:  # the 1 Hz status arrives mid-recording: frames before it have no reading yet
            assert rec.put_status({"temperature_left_c": 41.5, "temperature_right_c": 39.0})
            time.sleep(0.01)
        pset = make_set(k)
        assert rec.put_event(pset.event) and rec.put_set(pset)
        time.sleep(0.01)
    rec.stop()
    bag = tmp_path / "r.bag"
    assert cli_main(["export", str(rec.summary.files[0]), "--format", "rosbag1", "--out", str(bag)]) == 0
    temps = {}
    with AnyReader([bag]) as reader:
        for side, topic in (("left", "/stereo/camera1/metadata"), ("right", "/stereo/camera2/metadata")):
            conns = [c for c in reader.connections if c.topic == topic]
            temps[side] = [reader.deserialize(raw, c.msgtype).DeviceTemperature
                           for c, _t, raw in reader.messages(conns)]
    for side, value in (("left", 41.5), ("right", 39.0)):
        assert len(temps[side]) == 12
        assert all(np.isnan(t) for t in temps[side][:6]) and temps[side][6:] == [value] * 6, temps[side]
