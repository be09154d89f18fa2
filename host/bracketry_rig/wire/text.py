"""Human-readable text for bproto frames: hex parsing, ``field=value`` parsing, one-line frame descriptions."""

from __future__ import annotations

import json
import re
import string
from typing import Any

from bracketry_rig.wire import bproto

_STATE_NAMES = {0: "OFF", 1: "IDLE", 2: "REC", 3: "ERR", 4: "CAL"}
_DEVICE_KINDS = {bproto.DEVICE_TRIGGER: "trigger", bproto.DEVICE_PANEL: "panel"}
_PANEL_STATE_KEYS = ("cam_left", "cam_right", "trigger", "imu", "lidar", "gnss")


def parse_hex(text: str) -> bytes:
    """Bytes from a hex string; spaces, colons, commas, newlines and ``0x`` prefixes are ignored.

    ValueError with a one-line reason if anything else is present or the digit count is odd.
    """
    cleaned = re.sub(r"0[xX]", "", text)
    cleaned = re.sub(r"[\s:,\-]", "", cleaned)
    bad = [c for c in cleaned if c not in string.hexdigits]
    if bad:
        raise ValueError(f"not hex: unexpected character {bad[0]!r}")
    if len(cleaned) % 2:
        raise ValueError("not hex: odd number of hex digits")
    return bytes.fromhex(cleaned)


def looks_like_hex_text(data: bytes) -> bool:
    """True if ``data`` is printable text made only of hex digits and separators (a hex dump, not a capture)."""
    try:
        text = data.decode("ascii")
    except UnicodeDecodeError:
        return False
    try:
        parse_hex(text)
    except ValueError:
        return False
    return bool(text.strip())


def _parse_int(name: str, value: str) -> int:
    try:
        return int(value.replace("_", ""), 0)
    except ValueError:
        raise ValueError(f"field {name}: {value!r} is not an integer") from None


def parse_fields(msg_type: int, assignments: list[str]) -> dict[str, Any]:
    """Fields dict of ``msg_type`` from ``["name=value", ...]`` (ints in decimal or 0x hex, ``exposures_us`` as a
    comma list, ``uid`` as hex, ``message`` as text, panel states also as OFF/IDLE/REC/ERR/CAL).

    ValueError naming the expected fields when a name is unknown, missing or a value malformed.
    """
    names = bproto.field_names(msg_type)
    out: dict[str, Any] = {}
    for item in assignments:
        if "=" not in item:
            raise ValueError(f"expected name=value, got {item!r} (fields of {bproto.MSG_NAMES[msg_type]}: "
                             f"{', '.join(names) or 'none'})")
        name, value = item.split("=", 1)
        name = name.strip()
        if name not in names:
            raise ValueError(f"unknown field {name!r} for {bproto.MSG_NAMES[msg_type]} "
                             f"(fields: {', '.join(names) or 'none'})")
        if name == "exposures_us":
            out[name] = [_parse_int(name, v) for v in value.split(",") if v.strip()]
        elif name == "uid":
            out[name] = parse_hex(value)
        elif name == "message":
            out[name] = value
        elif name in _PANEL_STATE_KEYS and value.upper() in _STATE_NAMES.values():
            out[name] = next(k for k, v in _STATE_NAMES.items() if v == value.upper())
        else:
            out[name] = _parse_int(name, value)
    if msg_type == bproto.MSG_HELLO and not out:
        return out
    missing = [n for n in names if n not in out]
    if missing:
        raise ValueError(f"missing field(s) for {bproto.MSG_NAMES[msg_type]}: {', '.join(missing)}")
    return out


def _value_text(name: str, value: Any, msg_type: int) -> str:
    if isinstance(value, bytes | bytearray):
        return value.hex()
    if name == "message":
        return json.dumps(value)
    if name == "code" and msg_type == bproto.MSG_NACK:
        return f"{value}({bproto.NACK_NAMES.get(value, '?')})"
    if name in _PANEL_STATE_KEYS and msg_type == bproto.MSG_PANEL_STATE:
        return f"{value}({_STATE_NAMES.get(value, '?')})"
    if name == "device_kind" and msg_type == bproto.MSG_HELLO:
        return f"{value}({_DEVICE_KINDS.get(value, '?')})"
    if isinstance(value, list):
        return ",".join(str(v) for v in value)
    return str(value)


def describe_frame(frame: bproto.Frame) -> str:
    """One line: ``seq=5 ACK acked_seq=4`` (unknown type or bad payload: the payload in hex and the reason)."""
    name = bproto.MSG_NAMES.get(frame.msg_type, f"0x{frame.msg_type:02x}")
    head = f"seq={frame.seq} {name}"
    try:
        fields = bproto.unpack_payload(frame.msg_type, frame.payload)
    except ValueError as exc:
        return f"{head} payload={frame.payload.hex() or '-'} ({exc})"
    if frame.msg_type == bproto.MSG_HELLO and not fields:
        return f"{head} (request)"
    return " ".join([head, *(f"{k}={_value_text(k, v, frame.msg_type)}" for k, v in fields.items())])


def frame_to_json(frame: bproto.Frame) -> dict[str, Any]:
    """JSON-able dict of a frame: type, type_name, seq, payload (hex), fields (or error)."""
    out: dict[str, Any] = {"type": frame.msg_type, "type_name": bproto.MSG_NAMES.get(frame.msg_type),
                           "seq": frame.seq, "payload": frame.payload.hex()}
    try:
        fields = bproto.unpack_payload(frame.msg_type, frame.payload)
        out["fields"] = {k: (v.hex() if isinstance(v, bytes | bytearray) else v) for k, v in fields.items()}
    except ValueError as exc:
        out["error"] = str(exc)
    return out


def describe_stats(stats: dict[str, int]) -> str:
    """``3 frames ok, 1 rejected (crc_errors=1), 17 bytes discarded``."""
    errs = {k: v for k, v in stats.items() if k not in ("frames_ok", "bytes_discarded") and v}
    detail = f" ({', '.join(f'{k}={v}' for k, v in errs.items())})" if errs else ""
    return (f"{stats['frames_ok']} frames ok, {sum(errs.values())} rejected{detail}, "
            f"{stats['bytes_discarded']} bytes discarded")
