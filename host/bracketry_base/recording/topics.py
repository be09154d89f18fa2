"""Topic names and schema names of a recording (the recording spec is RECORDING.md next to this module)."""

from __future__ import annotations

SIDES = ("left", "right")
IMAGE_ENCODING = "bayer_rggb16"
FORMAT_NAME = "bracketry-recording"
FORMAT_VERSION = "1"
METADATA_NAME = "bracketry"


def image_topic(side: str) -> str:
    return f"/stereo/{side}/image_raw"


def camera_info_topic(side: str) -> str:
    return f"/stereo/{side}/camera_info"


def frame_meta_topic(side: str) -> str:
    return f"/stereo/{side}/frame_meta"


TRIGGER_TOPIC = "/trigger/events"
STATUS_TOPIC = "/rig/status"

SCHEMA_IMAGE = "sensor_msgs/msg/Image"
SCHEMA_CAMERA_INFO = "sensor_msgs/msg/CameraInfo"
SCHEMA_FRAME_META = "bracketry_msgs/msg/FrameMeta"
SCHEMA_TRIGGER = "bracketry_msgs/msg/TriggerEvent"
SCHEMA_STATUS = "bracketry_msgs/msg/RigStatus"


def topic_schemas(sides: tuple[str, ...] = SIDES) -> dict[str, str]:
    """topic -> schema name, in the order channels are registered."""
    out: dict[str, str] = {}
    for side in sides:
        out[image_topic(side)] = SCHEMA_IMAGE
        out[camera_info_topic(side)] = SCHEMA_CAMERA_INFO
        out[frame_meta_topic(side)] = SCHEMA_FRAME_META
    out[TRIGGER_TOPIC] = SCHEMA_TRIGGER
    out[STATUS_TOPIC] = SCHEMA_STATUS
    return out
