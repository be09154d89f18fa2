"""Export a recording as a ROS 1 bag (``rosbags``), with an upstream-compatible metadata message.

Topics: ``/stereo/left|right/image_raw`` (sensor_msgs/Image, bayer_rggb16), ``/stereo/left|right/camera_info``,
``/stereo/left|right/frame_meta`` (our FrameMeta), ``/trigger/events``, and for the upstream drop checker
(``check_bag_bracketing.py``) ``/stereo/camera1/metadata`` (left) and ``/stereo/camera2/metadata`` (right) of type
``norlab_basler_camera_driver/metadata_msg``: ``Header header, int32 FrameId, int64 Timestamp, float32 ExposureTime
(microseconds, the commanded pulse width as in the version that script reads), float32 DeviceTemperature`` (°C:
the camera's last temperature in ``/rig/status`` before the frame, NaN before the first or when it has none).
Frame times are the recording's (image stamps = trigger start, as the BorealHDR names); each frame's mid-exposure
time is in its frame_meta (``mid_exposure_host_ns``; derived for recordings made before that field).
"""

from __future__ import annotations

import os
from pathlib import Path
from typing import Any

from bracketry_base.errors import BracketryError
from bracketry_base.recording import topics as T
from bracketry_base.recording.decode import decode
from bracketry_base.recording.msgdefs import MSGDEFS, OWN_MSG_TEXT
from bracketry_base.recording.reader import RecordingReader
from bracketry_base.recording.verify import recording_files
from bracketry_rig.recording.recorder import current_frame_meta, current_status

UPSTREAM_METADATA_TYPE = "norlab_basler_camera_driver/msg/metadata_msg"
UPSTREAM_METADATA_MSG = "std_msgs/Header header\nint32 FrameId\nint64 Timestamp\nfloat32 ExposureTime\n" \
                        "float32 DeviceTemperature\n"
UPSTREAM_TOPICS = {"left": "/stereo/camera1/metadata", "right": "/stereo/camera2/metadata"}


def export_rosbag1(recording: str | Path, out_bag: str | Path, *, overwrite: bool = False) -> dict[str, int]:
    """Write ``out_bag`` (an existing one only with ``overwrite``, replaced once the new bag is complete; its folder
    must exist); returns message counts per topic."""
    try:
        from rosbags.rosbag1 import Writer  # noqa: F401  (checked here: a one-line error when missing)
        from rosbags.typesys import Stores, get_types_from_msg, get_typestore
    except ImportError as exc:
        raise BracketryError("rosbag1 export needs rosbags (pip install -e '.[host]')") from exc
    out = Path(out_bag)
    if out.exists() and not overwrite:
        raise BracketryError(f"{out} exists (add --overwrite to replace it)")
    if not out.parent.is_dir():
        raise BracketryError(f"folder {out.parent} does not exist (create it first)")
    store = get_typestore(Stores.ROS1_NOETIC)  # ROS 1 wire format: Header has seq
    cdr_store = get_typestore(Stores.ROS2_HUMBLE)  # our stored CDR messages
    types = {}
    for name, text in OWN_MSG_TEXT.items():
        types.update(get_types_from_msg(text, name))
    cdr_store.register(types)
    types.update(get_types_from_msg(UPSTREAM_METADATA_MSG, UPSTREAM_METADATA_TYPE))
    store.register(types)
    counts: dict[str, int] = {}
    files = recording_files(recording)
    tmp = out.with_name(f".{out.name}.partial")
    tmp.unlink(missing_ok=True)
    try:
        _write_bag(tmp, files, store, cdr_store, counts)
    except BaseException:
        tmp.unlink(missing_ok=True)
        raise
    os.replace(tmp, out)
    return counts


def _write_bag(tmp: Path, files: list[Path], store: Any, cdr_store: Any, counts: dict[str, int]) -> None:
    from mcap_ros2._dynamic import serialize_dynamic
    from rosbags.rosbag1 import Writer

    Header = store.types["std_msgs/msg/Header"]
    Time = store.types["builtin_interfaces/msg/Time"]
    Meta = store.types[UPSTREAM_METADATA_TYPE]

    def header(msg_header: Any, seq: int = 0) -> Any:
        st = msg_header.stamp  # type: ignore[attr-defined]
        return Header(seq=seq, stamp=Time(sec=st.sec, nanosec=st.nanosec),
                      frame_id=msg_header.frame_id)  # type: ignore[attr-defined]

    with Writer(tmp) as writer:
        conns: dict[str, Any] = {}

        def conn(topic: str, msgtype: str) -> Any:
            if topic not in conns:
                conns[topic] = writer.add_connection(topic, msgtype, typestore=store)
            return conns[topic]

        def write(topic: str, msgtype: str, t_ns: int, msg: Any) -> None:
            writer.write(conn(topic, msgtype), t_ns, store.serialize_ros1(msg, msgtype))
            counts[topic] = counts.get(topic, 0) + 1

        temperature_c = {"left": float("nan"), "right": float("nan")}  # latest /rig/status reading per camera
        encode_meta = serialize_dynamic(T.SCHEMA_FRAME_META, MSGDEFS[T.SCHEMA_FRAME_META])[T.SCHEMA_FRAME_META]
        encode_status = serialize_dynamic(T.SCHEMA_STATUS, MSGDEFS[T.SCHEMA_STATUS])[T.SCHEMA_STATUS]
        for path in files:
            reader = RecordingReader(path)
            for raw in reader.messages():
                data = bytes(raw.data)
                stored = reader.schemas.get(reader.channels[raw.channel_id][1], ("", "", ""))[2] or None
                if raw.schema_name == T.SCHEMA_STATUS:
                    st = decode(raw.schema_name, data, stored)
                    for s in temperature_c:
                        temperature_c[s] = float(getattr(st, f"temperature_{s}_c", float("nan")))
                    if stored is not None and stored != MSGDEFS[T.SCHEMA_STATUS]:
                        data = encode_status(current_status(st))  # a recording made before the last fields
                if raw.schema_name == T.SCHEMA_FRAME_META:
                    m = decode(raw.schema_name, data, stored)
                    if stored is not None and stored != MSGDEFS[T.SCHEMA_FRAME_META]:
                        # a recording made before the read-back fields: the bag's frame_meta has today's definition
                        data = encode_meta(current_frame_meta(m))
                    side = raw.topic.split("/")[2]
                    meta = Meta(header=header(m.header, int(m.trigger_seq)), FrameId=int(m.cam_frame_id),
                                Timestamp=int(m.cam_timestamp_ns), ExposureTime=float(m.exposure_us),
                                DeviceTemperature=temperature_c.get(side, float("nan")))
                    write(UPSTREAM_TOPICS.get(side, f"/stereo/{side}/metadata"), UPSTREAM_METADATA_TYPE,
                          raw.log_time, meta)
                # CDR (ROS 2) -> ROS 1 wire format by rosbags (adds the ROS 1 Header.seq)
                writer.write(conn(raw.topic, raw.schema_name), raw.log_time,
                             cdr_store.cdr_to_ros1(data, raw.schema_name))
                counts[raw.topic] = counts.get(raw.topic, 0) + 1

