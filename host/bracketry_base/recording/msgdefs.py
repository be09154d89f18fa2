"""ROS 2 message definitions used in recordings, and a fast CDR codec for ``sensor_msgs/msg/Image``.

The definitions are the text stored in each MCAP Schema record (``ros2msg`` encoding): the message followed by its
dependencies after ``=====`` separator lines (``MSG: pkg/Type``). Our own messages live in ``msg/*.msg`` next to
this module (package ``bracketry_msgs``); the standard ones are written out below.

The Image codec writes/reads the CDR (XCDR1, little endian) layout directly so that a 4.6 MB frame costs one copy;
it is checked against mcap_ros2's generic serializer in the tests.
"""

from __future__ import annotations

import struct
from dataclasses import dataclass
from pathlib import Path

import numpy as np

_MSG_DIR = Path(__file__).with_name("msg")
SEPARATOR = "=" * 80

TIME = "int32 sec\nuint32 nanosec\n"
HEADER = "builtin_interfaces/Time stamp\nstring frame_id\n"
IMAGE = ("std_msgs/Header header\nuint32 height\nuint32 width\nstring encoding\nuint8 is_bigendian\n"
         "uint32 step\nuint8[] data\n")
ROI = "uint32 x_offset\nuint32 y_offset\nuint32 height\nuint32 width\nbool do_rectify\n"
CAMERA_INFO = ("std_msgs/Header header\nuint32 height\nuint32 width\nstring distortion_model\nfloat64[] d\n"
               "float64[9] k\nfloat64[9] r\nfloat64[12] p\nuint32 binning_x\nuint32 binning_y\n"
               "sensor_msgs/RegionOfInterest roi\n")


def _with_deps(main: str, deps: list[tuple[str, str]]) -> str:
    parts = [main.rstrip("\n")]
    for name, text in deps:
        parts.append(f"{SEPARATOR}\nMSG: {name}\n{text.rstrip()}")
    return "\n".join(parts) + "\n"


def _own(name: str) -> str:
    return (_MSG_DIR / f"{name}.msg").read_text()


_HEADER_DEPS = [("std_msgs/Header", HEADER), ("builtin_interfaces/Time", TIME)]

#: schema name -> full ros2msg text (with dependencies)
MSGDEFS: dict[str, str] = {
    "sensor_msgs/msg/Image": _with_deps(IMAGE, _HEADER_DEPS),
    "sensor_msgs/msg/CameraInfo": _with_deps(CAMERA_INFO, [*_HEADER_DEPS, ("sensor_msgs/RegionOfInterest", ROI)]),
    "bracketry_msgs/msg/FrameMeta": _with_deps(_own("FrameMeta"), _HEADER_DEPS),
    "bracketry_msgs/msg/TriggerEvent": _own("TriggerEvent"),
    "bracketry_msgs/msg/RigStatus": _with_deps(_own("RigStatus"), _HEADER_DEPS),
}

#: bare .msg text of our own types (for rosbags' typestore registration)
OWN_MSG_TEXT: dict[str, str] = {f"bracketry_msgs/msg/{n}": _own(n) for n in ("FrameMeta", "TriggerEvent", "RigStatus")}


def stamp(t_ns: int) -> dict[str, int]:
    """A builtin_interfaces/Time dict from nanoseconds since the epoch."""
    sec, nanosec = divmod(int(t_ns), 1_000_000_000)
    return {"sec": sec, "nanosec": nanosec}


def _pad(n: int, align: int) -> int:
    return (-n) % align


def _cdr_string(s: str, offset: int) -> tuple[bytes, int]:
    """CDR string at ``offset`` (relative to the payload start): 4-aligned uint32 length incl. NUL, bytes, NUL."""
    raw = s.encode() + b"\x00"
    pad = _pad(offset, 4)
    out = b"\x00" * pad + struct.pack("<I", len(raw)) + raw
    return out, offset + len(out)


def encode_image(t_ns: int, frame_id: str, image: np.ndarray, encoding: str) -> list[bytes | memoryview]:
    """CDR parts of a sensor_msgs/msg/Image holding ``image`` (uint16 -> little-endian, 2 bytes per pixel).

    Returns a list of byte strings whose concatenation is the serialized message (the pixel part is a memoryview of
    the contiguous array, not a copy).
    """
    arr = np.ascontiguousarray(image)
    if arr.dtype.byteorder == ">":
        arr = arr.astype(arr.dtype.newbyteorder("<"))
    height, width = arr.shape[:2]
    step = arr.strides[0]
    sec, nanosec = divmod(int(t_ns), 1_000_000_000)
    head = struct.pack("<iI", sec, nanosec)
    off = len(head)
    s1, off = _cdr_string(frame_id, off)
    pad = b"\x00" * _pad(off, 4)
    off += len(pad)
    dims = struct.pack("<II", height, width)
    off += 8
    s2, off = _cdr_string(encoding, off)
    tail_pre = b"\x00" * _pad(off + 1, 4)
    body_end = struct.pack("<B", 0) + tail_pre + struct.pack("<II", step, arr.nbytes)
    prefix = b"\x00\x01\x00\x00" + head + s1 + pad + dims + s2 + body_end
    return [prefix, memoryview(arr.view(np.uint8).reshape(-1))]  # type: ignore[arg-type]


@dataclass
class DecodedImage:
    """A decoded Image: ``image`` is ``(height, width)`` uint16 for 16-bit encodings, uint8 for 8-bit ones."""

    stamp_ns: int
    frame_id: str
    encoding: str
    image: np.ndarray


def _read_string(buf: memoryview, off: int) -> tuple[str, int]:
    off += _pad(off - 4, 4)
    (n,) = struct.unpack_from("<I", buf, off)
    off += 4
    s = bytes(buf[off:off + n - 1]).decode()
    return s, off + n


def decode_image(data: bytes | memoryview) -> DecodedImage:
    """Decode a CDR sensor_msgs/msg/Image (little endian) without copying the pixels twice."""
    buf = memoryview(data)
    if bytes(buf[:2]) != b"\x00\x01":
        raise ValueError("only little-endian CDR images are supported")
    off = 4
    sec, nanosec = struct.unpack_from("<iI", buf, off)
    off += 8
    frame_id, off = _read_string(buf, off)
    off += _pad(off - 4, 4)
    height, width = struct.unpack_from("<II", buf, off)
    off += 8
    encoding, off = _read_string(buf, off)
    off += 1  # is_bigendian
    off += _pad(off - 4, 4)
    step, n = struct.unpack_from("<II", buf, off)
    off += 8
    pixels = np.frombuffer(buf[off:off + n], dtype=np.uint8)
    img: np.ndarray
    if encoding.endswith("16") and n == height * width * 2:
        img = pixels.view("<u2").reshape(height, width).astype(np.uint16)
    else:
        img = pixels.reshape(height, step).copy()
    return DecodedImage(sec * 1_000_000_000 + nanosec, frame_id, encoding, img)
