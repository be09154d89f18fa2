"""CPython tests of the bproto codec: CRC, COBS (against the `cobs` package), payloads, frames, streaming decoder."""

from __future__ import annotations

import struct

import cobs.cobs as cobs_pkg
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from bracketry_rig.wire import bproto
from crc16_reference import crc16_bitwise


def test_wire_crc_check_value() -> None:
    assert bproto.crc16(b"123456789") == 0x29B1
    assert bproto.crc16_table(b"123456789") == 0x29B1
    assert bproto.crc16(b"") == 0xFFFF


@given(st.binary(max_size=300))
def test_wire_crc_matches_bitwise(data: bytes) -> None:
    assert bproto.crc16(data) == crc16_bitwise(data) == bproto.crc16_table(data)


@given(st.binary(max_size=800) | st.lists(st.sampled_from([b"\x00", b"\x01" * 253, b"\x02" * 254, b"\x03"]))
       .map(b"".join))
def test_wire_cobs_matches_package(data: bytes) -> None:
    enc = bproto.cobs_encode(data)
    assert enc == cobs_pkg.encode(data)
    assert b"\x00" not in enc
    assert bproto.cobs_decode(enc) == data == bproto.cobs_decode_py(enc) == bproto.cobs_decode(bytearray(enc))


@given(st.binary(max_size=600))
def test_wire_cobs_decode_agrees_with_package_on_anything(data: bytes) -> None:
    """The pure-Python decoder (MicroPython's) and the fast CPython path accept and reject exactly the same input."""
    try:
        expected = cobs_pkg.decode(data)
    except cobs_pkg.DecodeError:
        with pytest.raises(ValueError):
            bproto.cobs_decode(data)
        with pytest.raises(ValueError):
            bproto.cobs_decode_py(data)
    else:
        assert bproto.cobs_decode(data) == expected == bproto.cobs_decode_py(data)


def test_wire_frame_layout() -> None:
    frame = bproto.encode_frame(bproto.MSG_ACK, 0x1234, b"\x34\x12")
    assert frame.endswith(b"\x00") and frame.count(b"\x00") == 1
    body = cobs_pkg.decode(frame[:-1])
    assert body[:6] == struct.pack("<BBHH", 1, 2, 0x1234, 2)
    assert body[6:8] == b"\x34\x12"
    assert struct.unpack("<H", body[8:])[0] == crc16_bitwise(body[:8])
    assert len(bproto.encode_frame(0x7F, 1, b"\x01" * 255)) <= bproto.MAX_FRAME


def test_wire_encode_frame_rejects_bad_input() -> None:
    with pytest.raises(ValueError):
        bproto.encode_frame(bproto.MSG_PING, 1, b"\x00" * 256)
    with pytest.raises(ValueError):
        bproto.encode_frame(256, 1, b"")


def test_wire_max_frame_is_worst_case() -> None:
    worst = max(len(bproto.encode_frame(t, s, p)) for t in (1, 255) for s in (0, 0xFFFF)
                for p in (b"\x01" * 255, b"\xff" * 255, b"\x00" * 255))
    assert worst <= bproto.MAX_FRAME


def test_wire_hello_request_and_reply() -> None:
    assert bproto.pack_payload(bproto.MSG_HELLO, {}) == b""
    assert bproto.unpack_payload(bproto.MSG_HELLO, b"") == {}
    fields = {"device_kind": 1, "proto_minor": 0, "fw_major": 1, "fw_minor": 2, "fw_patch": 3,
              "uid": bytes(range(12)), "capabilities": 0x5}
    payload = bproto.pack_payload(bproto.MSG_HELLO, fields)
    assert len(payload) == 21
    assert bproto.unpack_payload(bproto.MSG_HELLO, payload) == fields


def test_wire_panel_message_padding() -> None:
    fields = {"cam_left": 2, "cam_right": 2, "trigger": 1, "imu": 0, "lidar": 0, "gnss": 3, "free_disk_mb": 1000,
              "fps_left_centi": 1000, "fps_right_centi": 998, "rec_seconds": 12, "message": "REC 12s"}
    payload = bproto.pack_payload(bproto.MSG_PANEL_STATE, fields)
    assert len(payload) == 38 and payload.endswith(b"REC 12s" + b" " * 13)
    assert bproto.unpack_payload(bproto.MSG_PANEL_STATE, payload) == fields
    with pytest.raises(ValueError):
        bproto.pack_payload(bproto.MSG_PANEL_STATE, {**fields, "message": "x" * 21})


@pytest.mark.parametrize("msg_type,fields", [
    (bproto.MSG_ACK, {"acked_seq": 65536}),
    (bproto.MSG_ACK, {"acked_seq": -1}),
    (bproto.MSG_ACK, {"acked_seq": 1.5}),
    (bproto.MSG_ACK, {}),
    (bproto.MSG_ACK, {"acked_seq": 1, "extra": 2}),
    (bproto.MSG_PING, {"host_time_ns": 1 << 64}),
    (bproto.MSG_SET_BRACKETS, {"period_us": 1000}),
    (bproto.MSG_SET_BRACKETS, {"period_us": 1000, "exposures_us": [1] * 63}),
    (0x7E, {}),
])
def test_wire_pack_rejects(msg_type: int, fields: dict) -> None:
    with pytest.raises(ValueError):
        bproto.pack_payload(msg_type, fields)


def test_wire_unpack_rejects_wrong_length_and_unknown_type() -> None:
    with pytest.raises(ValueError):
        bproto.unpack_payload(bproto.MSG_ACK, b"\x01")
    with pytest.raises(ValueError):
        bproto.unpack_payload(bproto.MSG_SET_BRACKETS, struct.pack("<IBI", 5000, 2, 100))
    with pytest.raises(ValueError):
        bproto.unpack_payload(0x7E, b"")
    assert bproto.nack_code_for(0x7E, b"") == bproto.NACK_UNKNOWN_TYPE
    assert bproto.nack_code_for(bproto.MSG_START, b"\x01") == bproto.NACK_BAD_LENGTH
    assert bproto.nack_code_for(bproto.MSG_STOP, b"") == 0


def test_wire_panel_message_must_be_printable_ascii_both_ways() -> None:
    fields = {name: 0 for name in bproto.unpack_payload(bproto.MSG_PANEL_STATE, bytes(bproto._SIZES[
        bproto.MSG_PANEL_STATE] - 20) + b" " * 20)}
    fields["message"] = "READY"
    payload = bproto.pack_payload(bproto.MSG_PANEL_STATE, fields)
    assert bproto.unpack_payload(bproto.MSG_PANEL_STATE, payload)["message"] == "READY"
    bad = payload[:-20] + b"\xe9t\xe9" + b" " * 17
    with pytest.raises(bproto.PayloadValueError):
        bproto.unpack_payload(bproto.MSG_PANEL_STATE, bad)
    assert bproto.nack_code_for(bproto.MSG_PANEL_STATE, bad) == bproto.NACK_BAD_VALUE
    with pytest.raises(ValueError, match="printable ASCII"):
        bproto.pack_payload(bproto.MSG_PANEL_STATE, {**fields, "message": b"\x07bell"})


@pytest.mark.parametrize("period_us,exposures_us,ok", [
    (1000, [10, 800], True), (1000, [801], False), (999, [10], False), (1_000_000, [999_800], True),
    (1_000_001, [10], False), (5000, [9], False), (5000, [], False), (50_000, [10] * 16, True),
    (50_000, [10] * 17, False)])
def test_wire_set_brackets_rules(period_us: int, exposures_us: list[int], ok: bool) -> None:
    assert (bproto.check_set_brackets(period_us, exposures_us) == 0) is ok


def test_wire_decoder_split_and_garbage() -> None:
    f1 = bproto.encode_message(bproto.MSG_START, 1, {"session_id": 7})
    f2 = bproto.encode_message(bproto.MSG_STOP, 2)
    stream = b"\x00garbage\xff\x00" + f1 + b"\x13\x37\x00" + f2
    dec = bproto.Decoder()
    frames = [f for i in range(len(stream)) for f in dec.feed(stream[i:i + 1])]
    assert [(f.msg_type, f.seq) for f in frames] == [(bproto.MSG_START, 1), (bproto.MSG_STOP, 2)]
    assert dec.stats["frames_ok"] == 2 and dec.errors == 2


def test_wire_decoder_overflow_resyncs() -> None:
    dec = bproto.Decoder()
    assert dec.feed(b"\x01" * 1000) == []
    ok = bproto.encode_message(bproto.MSG_PING, 9, {"host_time_ns": 5})
    frames = dec.feed(b"\x00" + ok)
    assert len(frames) == 1 and frames[0].seq == 9
    assert dec.stats["overflows"] == 1 and dec.stats["bytes_discarded"] == 1000


def test_wire_type_by_name() -> None:
    assert bproto.type_by_name("ping") == bproto.MSG_PING
    assert bproto.type_by_name("0x31") == bproto.MSG_BUTTON
    with pytest.raises(ValueError):
        bproto.type_by_name("nope")


@settings(max_examples=50)
@given(st.binary(max_size=2000))
def test_wire_decoder_never_raises(data: bytes) -> None:
    dec = bproto.Decoder()
    frames = dec.feed(data)
    s = dec.stats
    assert s["frames_ok"] == len(frames)
    # every delivered or rejected frame but an overflow ends at a 0x00; an overflow takes > MAX_ENCODED bytes
    assert s["frames_ok"] + dec.errors - s["overflows"] <= data.count(0)
    assert s["overflows"] <= len(data) // (bproto.MAX_ENCODED + 1)
    assert s["bytes_discarded"] <= len(data) - data.count(0)
    # the same bytes one at a time: the same frames and counters
    one = bproto.Decoder()
    assert [f for i in range(len(data)) for f in one.feed(data[i:i + 1])] == frames
    assert one.stats == s
