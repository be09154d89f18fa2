"""The shared test vectors of bproto v1 (``firmware/protocol/protocol_vectors.json``): build, load, export for C.

The JSON file is frozen: every codec (C, CPython, MicroPython) is tested against the committed file, and a test
checks that :func:`build_vectors` still reproduces it, so a change of the wire format is always deliberate
(regenerate with ``python -m bracketry_rig.wire.vectors --write``).

JSON layout (all byte strings are lower-case hex):

- ``crc16``: ``[{"data": hex, "crc": int}]``
- ``cobs``: ``[{"decoded": hex, "encoded": hex}]`` (encoded without the 0x00 delimiter)
- ``valid``: ``[{"name", "msg_type", "type_name", "seq", "fields", "payload": hex, "frame": hex}]``; in ``fields``
  ``uid`` is hex, ``message`` a str, ``exposures_us`` a list.
- ``streams``: ``[{"name", "description", "chunks": [hex], "frames": [{"msg_type", "seq", "payload": hex}],
  "stats": {counter: int}}]``: feed the chunks in order to a fresh decoder, expect exactly these frames and counters.
- ``payload_errors``: ``[{"name", "msg_type", "payload": hex, "nack": int}]``: ``unpack_payload`` raises ValueError
  and a device answers NACK ``nack`` (1 UNKNOWN_TYPE, 2 BAD_LENGTH).
- ``set_brackets_checks``: ``[{"period_us", "exposures_us", "nack": 0|3}]``.
"""

from __future__ import annotations

import argparse
import json
import random
from pathlib import Path
from typing import Any

from bracketry_base import paths
from bracketry_rig.wire import bproto

COUNTERS = ("frames_ok", "crc_errors", "length_errors", "cobs_errors", "version_errors", "overflows",
            "bytes_discarded")


def vectors_path() -> Path:
    """Path of the committed ``firmware/protocol/protocol_vectors.json``."""
    return paths.firmware_dir() / "protocol" / "protocol_vectors.json"


def load_vectors(path: Path | None = None) -> dict[str, Any]:
    """The vectors as a dict (see the module docstring for the layout)."""
    return json.loads((path or vectors_path()).read_text())


def fields_to_json(fields: dict[str, Any]) -> dict[str, Any]:
    """Fields dict of :func:`bproto.unpack_payload` -> JSON-able dict (bytes as hex)."""
    return {k: (v.hex() if isinstance(v, bytes | bytearray) else v) for k, v in fields.items()}


# One or more example messages per type: (name, msg_type, seq, fields)
_VALID: list[tuple[str, int, int, dict[str, Any]]] = [
    ("hello_request", bproto.MSG_HELLO, 0, {}),
    ("hello_trigger", bproto.MSG_HELLO, 1, {"device_kind": 1, "proto_minor": 0, "fw_major": 1, "fw_minor": 0,
                                            "fw_patch": 3, "uid": bytes.fromhex("3a0021000d51333035383535"),
                                            "capabilities": 0x3}),
    ("hello_panel", bproto.MSG_HELLO, 0, {"device_kind": 2, "proto_minor": 0, "fw_major": 0, "fw_minor": 4,
                                          "fw_patch": 0, "uid": bytes.fromhex("24a160c3b2f4") + bytes(6),
                                          "capabilities": 0}),
    ("ack", bproto.MSG_ACK, 17, {"acked_seq": 42}),
    ("ack_seq_wrap", bproto.MSG_ACK, 65535, {"acked_seq": 65535}),
    ("nack_unknown_type", bproto.MSG_NACK, 3, {"acked_seq": 7, "code": bproto.NACK_UNKNOWN_TYPE}),
    ("nack_bad_length", bproto.MSG_NACK, 4, {"acked_seq": 8, "code": bproto.NACK_BAD_LENGTH}),
    ("nack_bad_value", bproto.MSG_NACK, 5, {"acked_seq": 9, "code": bproto.NACK_BAD_VALUE}),
    ("nack_bad_state", bproto.MSG_NACK, 6, {"acked_seq": 10, "code": bproto.NACK_BAD_STATE}),
    ("heartbeat_idle", bproto.MSG_HEARTBEAT, 100, {"uptime_ms": 123456, "state": 0}),
    ("heartbeat_running", bproto.MSG_HEARTBEAT, 101, {"uptime_ms": 0xFFFFFFFF, "state": 1}),
    ("ping", bproto.MSG_PING, 256, {"host_time_ns": 1_700_000_000_123_456_789}),
    ("pong", bproto.MSG_PONG, 9, {"host_time_ns": 1_700_000_000_123_456_789, "device_time_us": 987_654_321}),
    ("pong_max", bproto.MSG_PONG, 10, {"host_time_ns": 2**64 - 1, "device_time_us": 2**64 - 1}),
    ("set_brackets_six", bproto.MSG_SET_BRACKETS, 20, {"period_us": 50_000,
                                                        "exposures_us": [1000, 2000, 4000, 8000, 16000, 32000]}),
    ("set_brackets_one", bproto.MSG_SET_BRACKETS, 21, {"period_us": 1000, "exposures_us": [800]}),
    ("set_brackets_sixteen", bproto.MSG_SET_BRACKETS, 22, {"period_us": 1_000_000,
                                                            "exposures_us": [10 + 1000 * i for i in range(16)]}),
    ("start", bproto.MSG_START, 30, {"session_id": 0xDEADBEEF}),
    ("stop", bproto.MSG_STOP, 31, {}),
    ("trigger", bproto.MSG_TRIGGER, 500, {"session_id": 0xDEADBEEF, "trigger_seq": 0, "bracket_index": 0,
                                          "exposure_us": 1000, "t_start_us": 12_345_678}),
    ("trigger_late", bproto.MSG_TRIGGER, 501, {"session_id": 1, "trigger_seq": 4_000_000_000, "bracket_index": 5,
                                               "exposure_us": 32000, "t_start_us": 2**40 + 17}),
    ("panel_state", bproto.MSG_PANEL_STATE, 1000, {"cam_left": 2, "cam_right": 2, "trigger": 2, "imu": 1, "lidar": 0,
                                                   "gnss": 3, "free_disk_mb": 812_345, "fps_left_centi": 1000,
                                                   "fps_right_centi": 998, "rec_seconds": 3723,
                                                   "message": "REC 01:02:03"}),
    ("panel_state_empty_message", bproto.MSG_PANEL_STATE, 1001, {"cam_left": 0, "cam_right": 1, "trigger": 4,
                                                                 "imu": 0, "lidar": 0, "gnss": 0, "free_disk_mb": 0,
                                                                 "fps_left_centi": 0, "fps_right_centi": 0,
                                                                 "rec_seconds": 0, "message": ""}),
    ("button_record_short", bproto.MSG_BUTTON, 2, {"button": 2, "action": 1, "event_seq": 5}),
    ("button_sensors_long", bproto.MSG_BUTTON, 3, {"button": 1, "action": 2, "event_seq": 65535}),
]


def _frame_json(frame: bproto.Frame) -> dict[str, Any]:
    return {"msg_type": frame.msg_type, "seq": frame.seq, "payload": frame.payload.hex()}


def _raw_body_frame(body: bytes) -> bytes:
    return bproto.cobs_encode(body) + b"\x00"


def _body(ver: int, msg_type: int, seq: int, length: int, payload: bytes, crc: int | None = None) -> bytes:
    head = bytes([ver, msg_type]) + seq.to_bytes(2, "little") + length.to_bytes(2, "little") + payload
    c = bproto.crc16(head) if crc is None else crc
    return head + c.to_bytes(2, "little")


def _streams() -> list[dict[str, Any]]:
    ping = bproto.encode_message(bproto.MSG_PING, 1, {"host_time_ns": 123_456_789})
    ack = bproto.encode_message(bproto.MSG_ACK, 2, {"acked_seq": 1})
    trig = bproto.encode_message(bproto.MSG_TRIGGER, 3, {"session_id": 9, "trigger_seq": 1, "bracket_index": 1,
                                                         "exposure_us": 2000, "t_start_us": 1_000_000})
    stop = bproto.encode_message(bproto.MSG_STOP, 4)
    body_ping = bproto.cobs_decode(ping[:-1])
    bad_crc_body = body_ping[:-2] + bytes([body_ping[-2] ^ 0x01, body_ping[-1]])
    flipped_payload = bytearray(body_ping)
    flipped_payload[8] ^= 0x80
    unknown_type = bproto.encode_frame(0x7E, 5, b"\x01\x02")
    wrong_len_ack = bproto.encode_frame(bproto.MSG_ACK, 6, b"\x01")
    out: list[dict[str, Any]] = []

    def add(name: str, description: str, chunks: list[bytes]) -> None:
        dec = bproto.Decoder()
        frames = [f for c in chunks for f in dec.feed(c)]
        out.append({"name": name, "description": description, "chunks": [c.hex() for c in chunks],
                    "frames": [_frame_json(f) for f in frames], "stats": {k: dec.stats[k] for k in COUNTERS}})

    add("one_frame", "a single valid frame", [ping])
    add("leading_delimiter", "a 0x00 before a frame (flush) is ignored, not an error", [b"\x00" + ping])
    add("empty_frames", "consecutive 0x00 are ignored", [b"\x00\x00\x00", ack, b"\x00\x00"])
    add("back_to_back", "several frames in one read", [ping + ack + trig + stop])
    add("split_every_byte", "a frame split into one-byte reads", [bytes([b]) for b in trig])
    add("split_across_reads", "two frames split at odd places across three reads",
        [ping[:3], ping[3:] + ack[:5], ack[5:]])
    add("bad_crc", "CRC byte flipped: dropped, counted in crc_errors", [_raw_body_frame(bad_crc_body)])
    add("bad_crc_payload_bit", "one payload bit flipped: crc_errors, then a good frame is still decoded",
        [_raw_body_frame(bytes(flipped_payload)), ack])
    add("truncated_frame", "a frame cut short (the rest lost) then a delimiter: dropped, next frame decoded",
        [ping[: len(ping) // 2] + b"\x00", ack])
    add("truncated_cobs_block", "the last COBS block is shorter than its code says: cobs_errors",
        [bytes([0x09, 0x01, 0x02]) + b"\x00"])
    add("too_short_body", "a body shorter than header + CRC: length_errors", [_raw_body_frame(b"\x01\x02\x03")])
    add("length_field_mismatch", "len says 3 but 2 payload bytes follow (CRC valid): length_errors",
        [_raw_body_frame(_body(1, bproto.MSG_ACK, 1, 3, b"\x01\x00"))])
    add("length_field_over_255", "len field 256 (CRC valid, short body): length_errors",
        [_raw_body_frame(_body(1, 0x7E, 1, 256, b"\x01\x02"))])
    add("payload_over_255", "a 256-byte payload with len 256 and a valid CRC is too long to buffer: overflows",
        [_raw_body_frame(_body(1, 0x7E, 1, 256, bytes(range(256)))), ack])
    add("wrong_version", "ver = 2 with a valid CRC: version_errors", [_raw_body_frame(_body(2, bproto.MSG_ACK, 1, 2,
                                                                                           b"\x01\x00"))])
    add("over_long", "300 non-zero bytes without a delimiter: one overflow, resync at the next 0x00",
        [b"\x55" * 300, b"\x00" + ack])
    add("over_long_split", "an over-long run across reads counts one overflow", [b"\x11" * 200, b"\x22" * 200,
                                                                                  b"\x33" * 10 + b"\x00", stop])
    add("max_size_frame", "the largest valid frame (255-byte payload) is accepted",
        [bproto.encode_frame(0x7E, 7, bytes((i * 7 + 1) % 256 for i in range(255)))])
    add("garbage_between_frames", "line noise between valid frames is dropped and counted",
        [ping + b"\xde\xad\xbe\xef\x00" + ack + b"\x03\xff\x00" + trig])
    add("garbage_without_delimiter_before_frame", "noise glued to the front of a frame spoils only that frame",
        [b"\x41\x42" + ping, ack])
    add("unknown_type_is_a_valid_frame", "an unknown type passes the frame layer (the device NACKs it)",
        [unknown_type])
    add("wrong_payload_length_is_a_valid_frame", "an ACK with a 1-byte payload passes the frame layer",
        [wrong_len_ack])
    rng = random.Random(20261122)
    noise = bytes(rng.randrange(256) for _ in range(400))
    add("noise_with_delimiters", "short noise frames (valid COBS, too short, bad COBS) between frames",
        [b"\x00\x05\x00\x02\x01\x00\xff\xff\x00\x01\x01\x01\x01\x01\x01\x01\x01\x00" + stop])
    add("random_noise_then_frame", "400 pseudo-random bytes, a delimiter, then a valid frame is recovered",
        [noise, b"\x00" + trig])
    return out


def _payload_errors() -> list[dict[str, Any]]:
    rows = [
        ("unknown_type", 0x7E, b"\x01\x02", bproto.NACK_UNKNOWN_TYPE),
        ("unknown_type_empty", 0x13, b"", bproto.NACK_UNKNOWN_TYPE),
        ("ack_too_short", bproto.MSG_ACK, b"\x01", bproto.NACK_BAD_LENGTH),
        ("ping_too_long", bproto.MSG_PING, bytes(9), bproto.NACK_BAD_LENGTH),
        ("start_empty", bproto.MSG_START, b"", bproto.NACK_BAD_LENGTH),
        ("stop_with_payload", bproto.MSG_STOP, b"\x00", bproto.NACK_BAD_LENGTH),
        ("hello_partial", bproto.MSG_HELLO, bytes(5), bproto.NACK_BAD_LENGTH),
        ("set_brackets_short", bproto.MSG_SET_BRACKETS, b"\x10\x27\x00", bproto.NACK_BAD_LENGTH),
        ("set_brackets_count_mismatch", bproto.MSG_SET_BRACKETS, (5000).to_bytes(4, "little") + b"\x02"
         + (100).to_bytes(4, "little"), bproto.NACK_BAD_LENGTH),
        ("panel_state_short", bproto.MSG_PANEL_STATE, bytes(37), bproto.NACK_BAD_LENGTH),
        ("panel_state_message_not_ascii", bproto.MSG_PANEL_STATE, bytes(18) + b"\xe9t\xe9" + b" " * 17,
         bproto.NACK_BAD_VALUE),
        ("button_long", bproto.MSG_BUTTON, bytes(5), bproto.NACK_BAD_LENGTH),
    ]
    return [{"name": n, "msg_type": t, "payload": p.hex(), "nack": c} for n, t, p, c in rows]


def _set_brackets_checks() -> list[dict[str, Any]]:
    cases = [(50_000, [1000, 2000, 4000, 8000, 16000, 32000]), (1000, [10, 800]), (1000, [801]), (999, [10]),
             (1_000_000, [999_800]), (1_000_001, [10]), (5000, [9]), (5000, []), (50_000, [10] * 16),
             (50_000, [10] * 17), (0, [10])]
    return [{"period_us": p, "exposures_us": e, "nack": bproto.check_set_brackets(p, e)} for p, e in cases]


def build_vectors() -> dict[str, Any]:
    """Build the vectors from the reference definitions above (the committed JSON must equal this)."""
    crc = [{"data": d.hex(), "crc": bproto.crc16(d)} for d in (b"123456789", b"", b"\x00", b"\xff" * 4,
                                                               bytes(range(256)))]
    cobs_cases = [b"", b"\x00", b"\x00\x00", b"\x11\x22\x00\x33", b"\x11\x22\x33\x44", b"\x11\x00\x00\x00",
                  bytes(range(1, 255)), bytes(range(0, 255)), bytes(range(1, 256)), bytes(range(2, 256)) + b"\x00",
                  bytes(range(3, 256)) + b"\x00\x01", b"\x01" * 254 + b"\x00" + b"\x02" * 10, b"\x07" * 600]
    cobs = [{"decoded": d.hex(), "encoded": bproto.cobs_encode(d).hex()} for d in cobs_cases]
    valid = []
    for name, msg_type, seq, fields in _VALID:
        payload = bproto.pack_payload(msg_type, fields)
        valid.append({"name": name, "msg_type": msg_type, "type_name": bproto.MSG_NAMES[msg_type], "seq": seq,
                      "fields": fields_to_json(fields), "payload": payload.hex(),
                      "frame": bproto.encode_frame(msg_type, seq, payload).hex()})
    return {"protocol": "bproto", "version": bproto.VERSION, "max_frame": bproto.MAX_FRAME, "crc16": crc,
            "cobs": cobs, "valid": valid, "streams": _streams(), "payload_errors": _payload_errors(),
            "set_brackets_checks": _set_brackets_checks()}


def dumps(vectors: dict[str, Any]) -> str:
    """Canonical JSON text of the vectors (what is committed)."""
    return json.dumps(vectors, indent=1) + "\n"


def _c_field_value(name: str, value: Any) -> str:
    """One JSON field value (see :func:`fields_to_json`) as the C harness reads it: ints in decimal, ``uid`` hex,
    ``message`` as the hex of its ASCII text, ``exposures_us`` comma separated; ``-`` for an empty string/list."""
    if isinstance(value, bool) or not isinstance(value, int | str | list):
        raise ValueError(f"field {name}: no C text form for {value!r}")
    if isinstance(value, int):
        return str(value)
    if isinstance(value, list):
        return ",".join(str(int(e)) for e in value) or "-"
    text = value.encode("ascii").hex() if name == "message" else value
    return text or "-"


def c_message_line(msg_type: int, seq: int, frame_hex: str, payload_hex: str, fields: dict[str, Any]) -> str:
    """``M`` line of the C harness: a valid frame and the decoded ``fields`` (JSON form, as in ``valid``)."""
    parts = [f"M {msg_type} {seq} {frame_hex} {payload_hex or '-'}"]
    parts += [f"{k}={_c_field_value(k, v)}" for k, v in fields.items()]
    return " ".join(parts)


def c_payload_line(msg_type: int, payload_hex: str, nack: int) -> str:
    """``P`` line of the C harness: a payload of ``msg_type`` and the NACK code its check must give (0 = valid)."""
    return f"P {msg_type} {payload_hex or '-'} {nack}"


def to_c_text(vectors: dict[str, Any]) -> str:
    """Line format read by ``firmware/protocol/c/bproto_test.c`` (one record per line, hex without spaces):

    ``C <data hex|-> <crc>``, ``B <decoded hex|-> <encoded hex>`` (COBS), ``E <type> <seq> <payload hex|->
    <frame hex>`` (encode), ``M <type> <seq> <frame hex> <payload hex|-> <field>=<value>...`` (a valid frame with
    its decoded fields: the harness decodes and unpacks it, compares every field, packs the fields and the decoded
    struct and compares the bytes; values as :func:`_c_field_value`), ``S <name>`` starts a stream, ``K <chunk
    hex>`` a chunk, ``F <type> <seq> <payload hex|->`` an expected frame, ``X <frames_ok> <crc> <length> <cobs>
    <version> <overflows> <discarded>`` ends it, ``P <type> <payload hex|-> <nack>`` (payload checks: the C
    ``bproto_unpack_msg`` must return ``nack``), ``R <period_us> <nack> <exposure_us>...`` (bracket checks).
    """
    def h(s: str) -> str:
        return s if s else "-"

    lines = [f"C {h(c['data'])} {c['crc']}" for c in vectors["crc16"]]
    lines += [f"B {h(c['decoded'])} {h(c['encoded'])}" for c in vectors["cobs"]]
    lines += [f"E {v['msg_type']} {v['seq']} {h(v['payload'])} {v['frame']}" for v in vectors["valid"]]
    lines += [c_message_line(v["msg_type"], v["seq"], v["frame"], v["payload"], v["fields"])
              for v in vectors["valid"]]
    for s in vectors["streams"]:
        lines.append(f"S {s['name']}")
        lines += [f"K {h(c)}" for c in s["chunks"]]
        lines += [f"F {f['msg_type']} {f['seq']} {h(f['payload'])}" for f in s["frames"]]
        lines.append("X " + " ".join(str(s["stats"][k]) for k in COUNTERS))
    lines += [c_payload_line(p["msg_type"], p["payload"], p["nack"]) for p in vectors["payload_errors"]]
    lines += [c_payload_line(v["msg_type"], v["payload"], 0) for v in vectors["valid"]]
    lines += [f"R {r['period_us']} {r['nack']} " + " ".join(str(e) for e in r["exposures_us"])
              for r in vectors["set_brackets_checks"]]
    return "\n".join(lines) + "\n"


def main(argv: list[str] | None = None) -> int:
    """``python -m bracketry_rig.wire.vectors [--write | --c-text]``: check, rewrite, or export the vectors."""
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--write", action="store_true", help="rewrite the committed JSON from build_vectors()")
    ap.add_argument("--c-text", action="store_true", help="print the C harness line format of the committed JSON")
    args = ap.parse_args(argv)
    if args.write:
        vectors_path().write_text(dumps(build_vectors()))
        print(f"wrote {vectors_path()}")
        return 0
    if args.c_text:
        print(to_c_text(load_vectors()), end="")
        return 0
    same = vectors_path().read_text() == dumps(build_vectors())
    print("vectors up to date" if same else "vectors differ from build_vectors(): run with --write")
    return 0 if same else 1


if __name__ == "__main__":
    raise SystemExit(main())
