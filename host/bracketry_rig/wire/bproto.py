"""bproto v1: the bracketry serial wire codec (frames, CRC, COBS, message payloads, streaming decoder).

The single specification is ``firmware/protocol/PROTOCOL.md``; ``firmware/protocol/protocol_vectors.json`` holds the
shared test vectors that this module, the C codec and the MicroPython runtime all pass. The part between the
``BEGIN/END GENERATED`` markers (message types, codes, value-rule constants, payload layouts) is written by
``firmware/protocol/generate.py`` from ``firmware/protocol/messages.json`` (``make protocol``); the rest by hand.

This ONE module runs unchanged under CPython (host) and MicroPython (ESP32 panel, imported as ``import bproto``):
it uses only ``struct`` (``binascii.crc_hqx`` and the ``cobs`` package's C decoder are optional CPython speed-ups
with identical results, tested against the pure-Python code), no
dataclasses, no typing at runtime, no f-strings, no ``bytes.hex``.

Frame on the wire: ``COBS(body) + b"\\x00"`` with
``body = ver:u8 | type:u8 | seq:u16 | len:u16 | payload[len] | crc:u16`` (little-endian), ``crc`` =
CRC-16/CCITT-FALSE over ``ver..payload``.
"""

import struct

# BEGIN GENERATED constants by firmware/protocol/generate.py from messages.json: do not edit (make protocol)
VERSION = 1

MSG_HELLO = 0x01
MSG_ACK = 0x02
MSG_NACK = 0x03
MSG_HEARTBEAT = 0x04
MSG_PING = 0x05
MSG_PONG = 0x06
MSG_SET_BRACKETS = 0x10
MSG_START = 0x11
MSG_STOP = 0x12
MSG_TRIGGER = 0x20
MSG_PANEL_STATE = 0x30
MSG_BUTTON = 0x31

NACK_UNKNOWN_TYPE = 1
NACK_BAD_LENGTH = 2
NACK_BAD_VALUE = 3
NACK_BAD_STATE = 4

DEVICE_TRIGGER = 1
DEVICE_PANEL = 2

MAX_BRACKETS = 16
MIN_PERIOD_US = 1000
MAX_PERIOD_US = 1000000
MIN_EXPOSURE_US = 10
EXPOSURE_MARGIN_US = 200
UID_LEN = 12
PANEL_MESSAGE_LEN = 20

MSG_NAMES = {
    MSG_HELLO: "HELLO",
    MSG_ACK: "ACK",
    MSG_NACK: "NACK",
    MSG_HEARTBEAT: "HEARTBEAT",
    MSG_PING: "PING",
    MSG_PONG: "PONG",
    MSG_SET_BRACKETS: "SET_BRACKETS",
    MSG_START: "START",
    MSG_STOP: "STOP",
    MSG_TRIGGER: "TRIGGER",
    MSG_PANEL_STATE: "PANEL_STATE",
    MSG_BUTTON: "BUTTON",
}
NACK_NAMES = {
    NACK_UNKNOWN_TYPE: "UNKNOWN_TYPE",
    NACK_BAD_LENGTH: "BAD_LENGTH",
    NACK_BAD_VALUE: "BAD_VALUE",
    NACK_BAD_STATE: "BAD_STATE",
}

# Fixed layouts: type -> (struct format, field names); "Ns" fields are bytes (zero padded) or,
# when named in _ASCII_FIELDS, printable ASCII text (space padded). An empty HELLO is the request.
_LAYOUTS = {
    MSG_HELLO: ("<BBBBB12sI", ("device_kind", "proto_minor", "fw_major", "fw_minor", "fw_patch", "uid",
                               "capabilities")),
    MSG_ACK: ("<H", ("acked_seq",)),
    MSG_NACK: ("<HB", ("acked_seq", "code")),
    MSG_HEARTBEAT: ("<IB", ("uptime_ms", "state")),
    MSG_PING: ("<Q", ("host_time_ns",)),
    MSG_PONG: ("<QQ", ("host_time_ns", "device_time_us")),
    MSG_START: ("<I", ("session_id",)),
    MSG_STOP: ("<", ()),
    MSG_TRIGGER: ("<IIBIQ", ("session_id", "trigger_seq", "bracket_index", "exposure_us", "t_start_us")),
    MSG_PANEL_STATE: ("<BBBBBBIHHI20s", ("cam_left", "cam_right", "trigger", "imu", "lidar", "gnss",
                                         "free_disk_mb", "fps_left_centi", "fps_right_centi", "rec_seconds",
                                         "message")),
    MSG_BUTTON: ("<BBH", ("button", "action", "event_seq")),
}
# Variable layouts: type -> (struct format of the fixed part, its field names, count field, array field,
# struct format of one item); the count field is not a dict field (it is the array's length).
_ARRAYS = {
    MSG_SET_BRACKETS: ("<IB", ("period_us",), "n", "exposures_us", "<I"),
}
_ASCII_FIELDS = ("message",)
# Per-field value ranges: type -> ((field name, largest value), ...)
_VALUE_MAX = {
    MSG_PANEL_STATE: (("cam_left", 4), ("cam_right", 4), ("trigger", 4), ("imu", 4), ("lidar", 4), ("gnss", 4)),
}
# END GENERATED constants

MAX_PAYLOAD = 255
HEADER_LEN = 6
CRC_LEN = 2
#: largest body: header + payload + crc (bytes)
MAX_BODY = HEADER_LEN + MAX_PAYLOAD + CRC_LEN
#: largest COBS-encoded body, without the 0x00 delimiter (bytes): one overhead byte per started 254-byte block
MAX_ENCODED = MAX_BODY + (MAX_BODY + 253) // 254
#: largest frame on the wire including the trailing 0x00 (bytes)
MAX_FRAME = MAX_ENCODED + 1

_WIDTH_BITS = {"B": 8, "H": 16, "I": 32, "Q": 64}


def _codes(fmt):
    """Struct codes of a format like ``<BBH`` or ``<B12sI`` as a list (``"12s"`` kept whole)."""
    out = []
    num = ""
    for ch in fmt[1:]:
        if "0" <= ch <= "9":
            num += ch
        else:
            out.append(num + ch)
            num = ""
    return out


_FIELD_CODES = {}
_SIZES = {}
for _t in _LAYOUTS:
    _FIELD_CODES[_t] = _codes(_LAYOUTS[_t][0])
    _SIZES[_t] = struct.calcsize(_LAYOUTS[_t][0]) if _LAYOUTS[_t][1] else 0


# ----------------------------------------------------------------------------------------------------------- CRC
def _make_table():
    table = []
    for i in range(256):
        c = i << 8
        for _ in range(8):
            c = ((c << 1) ^ 0x1021) if c & 0x8000 else (c << 1)
        table.append(c & 0xFFFF)
    return table


_CRC_TABLE = _make_table()


def crc16_table(data):
    """CRC-16/CCITT-FALSE of ``data`` (bytes-like) by table lookup: poly 0x1021, init 0xFFFF, no reflection."""
    crc = 0xFFFF
    t = _CRC_TABLE
    for b in data:
        crc = ((crc << 8) & 0xFF00) ^ t[(crc >> 8) ^ b]
    return crc


try:  # CPython: the same CRC in C (crc_hqx is CRC-CCITT with a caller-given init; 0xFFFF makes it CCITT-FALSE)
    from binascii import crc_hqx as _crc_hqx

    def crc16(data):
        """CRC-16/CCITT-FALSE of ``data`` (bytes-like) as an int 0..0xFFFF; ``crc16(b"123456789") == 0x29B1``."""
        return _crc_hqx(data, 0xFFFF)
except ImportError:  # MicroPython
    crc16 = crc16_table


# ---------------------------------------------------------------------------------------------------------- COBS
def cobs_encode(data):
    """Consistent Overhead Byte Stuffing of ``data`` (bytes-like) -> bytes without any 0x00 (no delimiter added).

    Byte-identical to the ``cobs`` PyPI package: ``b""`` -> ``b"\\x01"``; a final run of 254 non-zero bytes ends
    with the 0xFF block (no extra 0x01).
    """
    out = bytearray()
    segments = bytes(data).split(b"\x00")
    last = len(segments) - 1
    for i, seg in enumerate(segments):
        full = False
        while len(seg) >= 254:
            out.append(0xFF)
            out += seg[:254]
            seg = seg[254:]
            full = True
        if i == last and full and not seg:
            break
        out.append(len(seg) + 1)
        out += seg
    return bytes(out)


def cobs_decode_py(data):
    """Inverse of :func:`cobs_encode`: bytes-like without 0x00 -> bytes. ValueError on a 0x00 or a truncated block."""
    data = bytes(data)
    if b"\x00" in data:
        raise ValueError("COBS: zero byte in input")
    n = len(data)
    out = bytearray()
    i = 0
    while i < n:
        code = data[i]
        end = i + code
        if end > n:
            raise ValueError("COBS: block runs past the end")
        out += data[i + 1:end]
        i = end
        if code < 0xFF and i < n:
            out.append(0)
    return bytes(out)


cobs_decode = cobs_decode_py
try:  # CPython: the same decoding in C from the `cobs` package (a core dependency); tested equal on all inputs
    from cobs.cobs import DecodeError as _CobsDecodeError
    from cobs.cobs import decode as _cobs_c_decode

    def cobs_decode(data):
        """Inverse of :func:`cobs_encode`: bytes-like without 0x00 -> bytes. ValueError on a 0x00 or a truncated
        block (same results as :func:`cobs_decode_py`)."""
        try:
            return _cobs_c_decode(data)
        except _CobsDecodeError as exc:
            raise ValueError("COBS: " + str(exc)) from None
except ImportError:  # MicroPython
    pass


# --------------------------------------------------------------------------------------------------------- frames
def encode_frame(msg_type, seq, payload=b""):
    """One wire frame: ``COBS(body) + b"\\x00"``. ``msg_type`` 0..255, ``seq`` wraps into 0..65535.

    ValueError if ``msg_type`` is out of range or ``payload`` is longer than 255 bytes.
    """
    if not 0 <= msg_type <= 0xFF:
        raise ValueError("msg_type out of range 0..255")
    n = len(payload)
    if n > MAX_PAYLOAD:
        raise ValueError("payload longer than 255 bytes")
    body = bytearray(struct.pack("<BBHH", VERSION, msg_type, seq & 0xFFFF, n))
    body += payload
    body += struct.pack("<H", crc16(body))
    return cobs_encode(body) + b"\x00"


class Frame:
    """A decoded, CRC-checked frame: ``ver`` (int), ``msg_type`` (int), ``seq`` (int 0..65535), ``payload`` (bytes)."""

    def __init__(self, ver, msg_type, seq, payload):
        self.ver = ver
        self.msg_type = msg_type
        self.seq = seq
        self.payload = payload

    def __eq__(self, other):
        return (isinstance(other, Frame) and self.ver == other.ver and self.msg_type == other.msg_type
                and self.seq == other.seq and self.payload == other.payload)

    def __hash__(self):
        return hash((self.ver, self.msg_type, self.seq, self.payload))

    def __repr__(self):
        return "Frame(ver={}, msg_type=0x{:02x} {}, seq={}, payload={!r})".format(
            self.ver, self.msg_type, MSG_NAMES.get(self.msg_type, "?"), self.seq, self.payload)


def parse_body(body):
    """Check one COBS-decoded body (bytes). Returns ``(Frame, None)`` or ``(None, reason)``.

    ``reason`` is the name of the counter the rejection increments: ``"length_errors"`` (shorter than 8 bytes, or
    the ``len`` field disagrees with the body size or exceeds 255), ``"crc_errors"``, ``"version_errors"``.
    The CRC is checked before the ``len`` field and before the version.
    """
    n = len(body)
    if n < HEADER_LEN + CRC_LEN:
        return None, "length_errors"
    if crc16(body[:n - 2]) != (body[n - 2] | (body[n - 1] << 8)):
        return None, "crc_errors"
    ver, msg_type, seq, length = struct.unpack_from("<BBHH", body, 0)
    if length > MAX_PAYLOAD or length != n - HEADER_LEN - CRC_LEN:
        return None, "length_errors"
    if ver != VERSION:
        return None, "version_errors"
    return Frame(ver, msg_type, seq, bytes(body[HEADER_LEN:n - 2])), None


def decode_frame(data):
    """Decode exactly one frame (bytes-like, with or without its trailing 0x00) -> Frame; ValueError otherwise."""
    data = bytes(data)
    if data and data[-1] == 0:
        data = data[:-1]
    if len(data) > MAX_ENCODED:
        raise ValueError("frame longer than the largest valid frame")
    body = cobs_decode(data)
    frame, reason = parse_body(body)
    if frame is None:
        raise ValueError("bad frame: " + str(reason))
    return frame


STAT_NAMES = ("frames_ok", "crc_errors", "length_errors", "cobs_errors", "version_errors", "overflows",
              "bytes_discarded")


class Decoder:
    """Streaming frame decoder: feed any chunks of bytes, get the valid frames; never raises on garbage.

    Bytes are buffered up to the next 0x00. A buffer longer than ``MAX_ENCODED`` bytes counts one overflow and is
    discarded up to the next 0x00. Empty frames (consecutive 0x00) are ignored silently: a sender may prefix a 0x00 to
    flush line noise. ``stats`` counts frames_ok, crc_errors, length_errors, cobs_errors, version_errors, overflows
    and bytes_discarded (encoded bytes of every rejected frame, without the delimiters).
    """

    def __init__(self):
        self._buf = bytearray()
        self._overflow = False
        self.stats = {}
        for name in STAT_NAMES:
            self.stats[name] = 0

    @property
    def errors(self):
        """Number of rejected frames (all error counters except bytes_discarded)."""
        s = self.stats
        return s["crc_errors"] + s["length_errors"] + s["cobs_errors"] + s["version_errors"] + s["overflows"]

    def reset(self):
        """Drop any partial frame (counters are kept)."""
        self._buf = bytearray()
        self._overflow = False

    def _append(self, chunk):
        if not chunk:
            return
        if self._overflow:
            self.stats["bytes_discarded"] += len(chunk)
            return
        if len(self._buf) + len(chunk) > MAX_ENCODED:
            self.stats["overflows"] += 1
            self.stats["bytes_discarded"] += len(self._buf) + len(chunk)
            self._buf = bytearray()
            self._overflow = True
            return
        self._buf += chunk

    def _end(self, frames):
        if self._overflow:
            self._overflow = False
            return
        buf = self._buf
        if not buf:
            return
        self._buf = bytearray()
        try:
            body = cobs_decode(buf)
        except ValueError:
            self.stats["cobs_errors"] += 1
            self.stats["bytes_discarded"] += len(buf)
            return
        frame, reason = parse_body(body)
        if frame is None:
            self.stats[reason] += 1
            self.stats["bytes_discarded"] += len(buf)
            return
        self.stats["frames_ok"] += 1
        frames.append(frame)

    def feed(self, data):
        """Consume bytes-like ``data``; return the list of valid :class:`Frame` completed by it (maybe empty)."""
        if not isinstance(data, (bytes, bytearray)):
            data = bytes(data)
        frames = []
        n = len(data)
        start = 0
        while start < n:
            z = data.find(b"\x00", start)
            if z < 0:
                self._append(data[start:])
                break
            self._append(data[start:z])
            self._end(frames)
            start = z + 1
        return frames


# ------------------------------------------------------------------------------------------------------- payloads
def _check_int(name, value, bits):
    if not isinstance(value, int) or isinstance(value, bool):
        raise ValueError("field " + name + " must be an int")
    if value < 0 or value >= (1 << bits):
        raise ValueError("field " + name + " out of range for " + str(bits) + " bits")


class PayloadValueError(ValueError):
    """A payload of the right length holding a value its type does not allow (a device answers NACK BAD_VALUE)."""


def _is_printable_ascii(data):
    return all(32 <= b <= 126 for b in data)


def _as_fixed_bytes(name, value, size, pad):
    if isinstance(value, str):
        for ch in value:
            if ord(ch) > 126 or ord(ch) < 32:
                raise ValueError("field " + name + " must be printable ASCII")
        value = value.encode()
    elif not isinstance(value, (bytes, bytearray)):
        raise ValueError("field " + name + " must be bytes or str")
    elif pad == b" " and not _is_printable_ascii(value):
        raise ValueError("field " + name + " must be printable ASCII")
    if len(value) > size:
        raise ValueError("field " + name + " longer than " + str(size) + " bytes")
    return bytes(value) + pad * (size - len(value))


def _pack_array(msg_type, fields):
    head_fmt, head_names, _count_name, array_name, item_fmt = _ARRAYS[msg_type]
    name = MSG_NAMES[msg_type]
    keys = list(head_names)
    keys.append(array_name)
    for key in fields:
        if key not in keys:
            raise ValueError("unknown field " + str(key) + " for " + name)
    for key in keys:
        if key not in fields:
            raise ValueError(name + " needs " + ", ".join(keys))
    items = fields[array_name]
    if not isinstance(items, (list, tuple)):
        raise ValueError("field " + array_name + " must be a list of ints")
    head_size = struct.calcsize(head_fmt)
    item_size = struct.calcsize(item_fmt)
    if len(items) > (MAX_PAYLOAD - head_size) // item_size:
        raise ValueError("too many " + array_name + " for one payload")
    values = []
    for key, code in zip(head_names, _codes(head_fmt)):
        _check_int(key, fields[key], _WIDTH_BITS[code])
        values.append(fields[key])
    values.append(len(items))
    out = bytearray(struct.pack(head_fmt, *values))
    bits = _WIDTH_BITS[item_fmt[1:]]
    for v in items:
        _check_int(array_name, v, bits)
        out += struct.pack(item_fmt, v)
    return bytes(out)


def _unpack_array(msg_type, payload):
    head_fmt, head_names, count_name, array_name, item_fmt = _ARRAYS[msg_type]
    name = MSG_NAMES[msg_type]
    head_size = struct.calcsize(head_fmt)
    item_size = struct.calcsize(item_fmt)
    n = len(payload)
    if n < head_size:
        raise ValueError(name + " payload shorter than " + str(head_size) + " bytes")
    values = struct.unpack_from(head_fmt, payload, 0)
    count = values[-1]
    if n != head_size + item_size * count:
        raise ValueError(name + " payload length does not match its " + count_name)
    out = {}
    for key, v in zip(head_names, values):
        out[key] = v
    out[array_name] = [struct.unpack_from(item_fmt, payload, head_size + item_size * i)[0] for i in range(count)]
    return out


def pack_payload(msg_type, fields):
    """Payload bytes of ``msg_type`` from a dict of its fields (names as in PROTOCOL.md).

    HELLO with an empty/None ``fields`` is the request (empty payload); STOP is empty; SET_BRACKETS takes
    ``period_us`` and ``exposures_us`` (list of ints, 0..62 entries; device-side value rules are separate, see
    :func:`check_set_brackets` and :func:`check_values`). ``uid`` is bytes (<= 12, zero padded), ``message`` str or
    bytes (<= 20 ASCII, space padded). Missing fields, extra fields, wrong types or out-of-range values raise
    ValueError.
    """
    if fields is None:
        fields = {}
    if msg_type == MSG_HELLO and not fields:
        return b""
    if msg_type in _ARRAYS:
        return _pack_array(msg_type, fields)
    if msg_type not in _LAYOUTS:
        raise ValueError("unknown message type " + str(msg_type))
    fmt, names = _LAYOUTS[msg_type]
    for key in fields:
        if key not in names:
            raise ValueError("unknown field " + str(key) + " for " + MSG_NAMES[msg_type])
    values = []
    for name, code in zip(names, _FIELD_CODES[msg_type]):
        if name not in fields:
            raise ValueError("missing field " + name + " for " + MSG_NAMES[msg_type])
        v = fields[name]
        if code[-1] == "s":
            v = _as_fixed_bytes(name, v, int(code[:-1]), b" " if name in _ASCII_FIELDS else b"\x00")
        else:
            _check_int(name, v, _WIDTH_BITS[code])
        values.append(v)
    if not names:
        return b""
    return struct.pack(fmt, *values)


def unpack_payload(msg_type, payload):
    """Dict of the fields of ``msg_type`` from its payload bytes; ValueError on an unknown type or a wrong length,
    :class:`PayloadValueError` (a ValueError) on a value the type does not allow (a non-ASCII ``message``).

    HELLO with an empty payload (the request) gives ``{}``; ``uid`` is 12 bytes; ``message`` is a str with the
    trailing spaces removed; SET_BRACKETS gives ``period_us`` and ``exposures_us`` (list). Value ranges are checked
    separately (:func:`check_values`, :func:`check_set_brackets`).
    """
    payload = bytes(payload)
    n = len(payload)
    if msg_type == MSG_HELLO and n == 0:
        return {}
    if msg_type in _ARRAYS:
        return _unpack_array(msg_type, payload)
    if msg_type not in _LAYOUTS:
        raise ValueError("unknown message type")
    fmt, names = _LAYOUTS[msg_type]
    if n != _SIZES[msg_type]:
        raise ValueError("wrong payload length for " + MSG_NAMES[msg_type] + ": " + str(n) + " != "
                         + str(_SIZES[msg_type]))
    out = {}
    if not names:
        return out
    values = struct.unpack(fmt, payload)
    for name, v in zip(names, values):
        if name in _ASCII_FIELDS:
            if not _is_printable_ascii(v):
                raise PayloadValueError("field " + name + " must be printable ASCII")
            v = bytes(v).decode().rstrip(" ")
        elif isinstance(v, (bytes, bytearray)):
            v = bytes(v)
        out[name] = v
    return out


def encode_message(msg_type, seq, fields=None):
    """Frame (bytes, with trailing 0x00) of ``msg_type`` with ``seq`` and the packed ``fields`` dict."""
    return encode_frame(msg_type, seq, pack_payload(msg_type, fields))


def nack_code_for(msg_type, payload):
    """The NACK code a device answers for a structurally bad command (unknown type, wrong length, a value its type
    does not allow), or 0 if it is well formed."""
    if msg_type not in _LAYOUTS and msg_type not in _ARRAYS:
        return NACK_UNKNOWN_TYPE
    try:
        unpack_payload(msg_type, payload)
    except PayloadValueError:
        return NACK_BAD_VALUE
    except ValueError:
        return NACK_BAD_LENGTH
    return 0


def check_set_brackets(period_us, exposures_us):
    """0 if a SET_BRACKETS request is acceptable, else NACK_BAD_VALUE.

    Rules: 1 <= n <= 16, 1000 <= period_us <= 1000000, every exposure_us >= 10 and exposure_us + 200 <= period_us.
    """
    n = len(exposures_us)
    if n < 1 or n > MAX_BRACKETS:
        return NACK_BAD_VALUE
    if period_us < MIN_PERIOD_US or period_us > MAX_PERIOD_US:
        return NACK_BAD_VALUE
    for e in exposures_us:
        if e < MIN_EXPOSURE_US or e + EXPOSURE_MARGIN_US > period_us:
            return NACK_BAD_VALUE
    return 0


def check_values(msg_type, fields):
    """0 if the unpacked ``fields`` of ``msg_type`` are within their value ranges (PANEL_STATE states <= 4; for
    SET_BRACKETS :func:`check_set_brackets`), else NACK_BAD_VALUE."""
    if msg_type in _ARRAYS:
        return check_set_brackets(fields["period_us"], fields["exposures_us"])
    for name, top in _VALUE_MAX.get(msg_type, ()):
        if fields[name] > top:
            return NACK_BAD_VALUE
    return 0


def type_by_name(name):
    """Message type int from its name (``"PING"``, case-insensitive) or a number string (``"0x05"``, ``"5"``)."""
    up = name.upper()
    for t in MSG_NAMES:
        if MSG_NAMES[t] == up:
            return t
    try:
        v = int(name, 0)
    except ValueError:
        raise ValueError("unknown message type " + name) from None
    if not 0 <= v <= 255:
        raise ValueError("message type out of range 0..255")
    return v


def field_names(msg_type):
    """Field names of ``msg_type`` in payload order (SET_BRACKETS: period_us, exposures_us)."""
    if msg_type in _ARRAYS:
        names = list(_ARRAYS[msg_type][1])
        names.append(_ARRAYS[msg_type][3])
        return tuple(names)
    if msg_type not in _LAYOUTS:
        raise ValueError("unknown message type")
    return _LAYOUTS[msg_type][1]
