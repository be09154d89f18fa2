"""Decode stored CDR messages into Python objects (mcap_ros2's dynamic decoders, cached per schema)."""

from __future__ import annotations

from typing import Any

from mcap_ros2._dynamic import generate_dynamic

from bracketry_base.recording.msgdefs import MSGDEFS, DecodedImage, decode_image

_DECODERS: dict[tuple[str, str | None], Any] = {}


def decode(schema_name: str, data: bytes | memoryview, schema_text: str | None = None) -> Any:
    """Decode one message of ``schema_name`` (attribute access, e.g. ``msg.trigger_seq``)."""
    key = (schema_name, schema_text or None)
    decoder = _DECODERS.get(key)
    if decoder is None:
        text = schema_text or MSGDEFS[schema_name]
        decoder = generate_dynamic(schema_name, text)[schema_name]
        _DECODERS[key] = decoder
    return decoder(bytes(data))


def decode_image_msg(data: bytes | memoryview) -> DecodedImage:
    """Decode a sensor_msgs/msg/Image quickly (pixels as a numpy array)."""
    return decode_image(data)
