"""MCAP recordings (sensor_msgs/Image bayer_rggb16 + FrameMeta) read as bracket sequences through mcap_ros2."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from bracketry_emulator.dataset import DatasetError, open_dataset
from emu_synthetic import BRACKETS_US, radiance_map, render

HEADER = """std_msgs/Header header
================================================================================
MSG: std_msgs/Header
builtin_interfaces/Time stamp
string frame_id
================================================================================
MSG: builtin_interfaces/Time
int32 sec
uint32 nanosec"""
IMAGE = HEADER.replace("std_msgs/Header header", """std_msgs/Header header
uint32 height
uint32 width
string encoding
uint8 is_bigendian
uint32 step
uint8[] data""", 1)
META = HEADER.replace("std_msgs/Header header", """std_msgs/Header header
uint32 trigger_seq
uint8 bracket_index
uint32 exposure_us""", 1)


def _write_recording(path: Path, frames: list[tuple[str, int, int, int, np.ndarray]]) -> None:
    """frames: (side, trigger_seq, bracket_index, t_ns, image)."""
    from mcap_ros2.writer import Writer

    with path.open("wb") as fh:
        w = Writer(fh)
        s_img = w.register_msgdef("sensor_msgs/msg/Image", IMAGE)
        s_meta = w.register_msgdef("bracketry_msgs/msg/FrameMeta", META)
        for side, seq, idx, t_ns, img in frames:
            hdr = {"stamp": {"sec": t_ns // 1_000_000_000, "nanosec": t_ns % 1_000_000_000}, "frame_id": side}
            w.write_message(f"/stereo/{side}/image_raw", s_img,
                            {"header": hdr, "height": img.shape[0], "width": img.shape[1], "encoding": "bayer_rggb16",
                             "is_bigendian": 0, "step": 2 * img.shape[1], "data": img.astype("<u2").tobytes()},
                            log_time=t_ns, publish_time=t_ns, sequence=seq)
            w.write_message(f"/stereo/{side}/frame_meta", s_meta,
                            {"header": hdr, "trigger_seq": seq, "bracket_index": idx,
                             "exposure_us": BRACKETS_US[idx]}, log_time=t_ns, publish_time=t_ns, sequence=seq)
        w.finish()


def test_emu_mcap_recording_grouped_like_tree(tmp_path: Path) -> None:
    irr = radiance_map(8, 12)
    rng = np.random.default_rng(0)
    frames = []
    t0 = 1_700_000_000_000_000_000
    # starts mid-cycle (bracket 3) like a real recording, 2 full cycles after it, one 16 ms frame of the right lost
    for k in range(3, 3 + 6 * 3):
        idx = k % 6
        t_ns = t0 + k * 45_454_545
        for side in ("left", "right"):
            if side == "right" and k == 3 + 6 + 4:
                continue
            frames.append((side, k, idx, t_ns, render(irr, BRACKETS_US[idx], rng)))
    rec = tmp_path / "rec.mcap"
    _write_recording(rec, frames)
    ds = open_dataset(rec)
    assert ds.kind == "mcap" and ds.sides == ("left", "right")
    seqs = ds.sequences()
    assert len(seqs) == 1  # cycle 1 complete on both; cycle 2 lost a right frame; the rest partial
    assert any("no match" in p for p in ds.problems)
    seq = seqs[0]
    assert seq.exposures_us == BRACKETS_US
    assert seq.timestamps_ns["left"] == seq.timestamps_ns["right"]
    assert seq.timestamps_ns["left"][1000] == t0 + 6 * 45_454_545
    imgs = seq.load("left")
    np.testing.assert_array_equal(imgs[8000], frames[2 * (6 + 3 - 3)][4])  # k = 9 -> bracket 3, left
    assert imgs[8000].dtype == np.uint16 and imgs[8000].shape == (8, 12)


def test_emu_mcap_errors(tmp_path: Path) -> None:
    bad = tmp_path / "bad.mcap"
    bad.write_bytes(b"\x89MCAP0\r\n garbage")
    with pytest.raises(DatasetError, match="MCAP"):
        open_dataset(bad)
    empty = tmp_path / "empty.mcap"
    _write_recording(empty, [])
    with pytest.raises(DatasetError, match="no camera frames"):
        open_dataset(empty)


def test_emu_reads_the_rig_recorder_output(tmp_path: Path) -> None:
    """A recording written by the rig's own Recorder (the CAMERAS helper's component) reads as bracket sequences."""
    import time
    from types import SimpleNamespace

    from bracketry_rig.events import TriggerEvent
    from bracketry_rig.pairing.pairer import PairedSet
    from bracketry_rig.recording.recorder import Recorder, RecorderConfig

    irr = radiance_map(24, 32)
    rng = np.random.default_rng(1)
    rec = Recorder(tmp_path, "emu", RecorderConfig(queue_max_items=1000),
                   metadata={"brackets_us": ",".join(map(str, BRACKETS_US))}).start()
    expected = {}
    for k in range(14):  # 2 full cycles + 2 frames
        t_ns = 1_700_000_000_000_000_000 + k * 45_454_000
        ev = TriggerEvent(7, k, k % 6, BRACKETS_US[k % 6], 1_000_000 + k * 45_454, t_ns)
        frames = {}
        for side in ("left", "right"):
            img = render(irr, BRACKETS_US[k % 6], rng)
            expected[(side, k)] = img
            frames[side] = SimpleNamespace(side=side, frame_id=k + 1, frame_index=k, skipped_ids=0, status="success",
                                           image=img, cam_timestamp_ns=k * 45_454_000, host_receive_ns=t_ns + 9_000_000,
                                           missing_packets=0, exposure_us_reported=None)
        assert rec.put_event(ev)
        assert rec.put_set(PairedSet(k, ev, frames, t_ns))
        time.sleep(0.001)
    rec.stop()
    ds = open_dataset(Path(rec.summary.files[0]))
    seqs = ds.sequences()
    assert len(seqs) == 2 and ds.sides == ("left", "right")
    assert seqs[1].timestamps_ns["right"][4000] == 1_700_000_000_000_000_000 + 8 * 45_454_000
    np.testing.assert_array_equal(seqs[1].load("right")[4000], expected[("right", 8)])
    assert any("incomplete" in p for p in ds.problems)  # the 2 trailing frames
