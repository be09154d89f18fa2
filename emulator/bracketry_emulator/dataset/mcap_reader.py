"""Reader of our MCAP recordings (spec: host/bracketry_base/recording/RECORDING.md), through the recorder's own
reader (``bracketry_base.recording.reader``, the one verify and export use: truncated files are read the same way
everywhere) and ``mcap_ros2``'s CDR decoders.

Per side: ``/stereo/<side>/image_raw`` (sensor_msgs/msg/Image, encoding ``bayer_rggb16``, 12 significant bits
LSB-aligned, header.stamp = frame time) and ``/stereo/<side>/frame_meta`` (bracketry_msgs/msg/FrameMeta with
``exposure_us`` and ``bracket_index``, same log time and header stamp as its image). Frames are paired with their
metadata by log time, then grouped into bracket sequences exactly like the BorealHDR tree, with the cycle order
given by ``bracket_index``. Images are decoded lazily (one chunk read per frame, at the offset found by the scan).
A recording split into several files is read as one when the folder of ``*.mcap`` files is given; a
``<stem>.repaired.mcap`` written by ``verify --repair`` replaces its truncated file.
"""

from __future__ import annotations

import functools
from collections import Counter
from pathlib import Path
from typing import Any

import numpy as np

from .grouping import group_sequences
from .model import Dataset, DatasetError, Frame

SIDES = ("left", "right")


def _image_topic(side: str) -> str:
    return f"/stereo/{side}/image_raw"


def _meta_topic(side: str) -> str:
    return f"/stereo/{side}/frame_meta"


def _stamp_ns(msg: Any) -> int:
    st = msg.header.stamp
    return int(st.sec) * 1_000_000_000 + int(st.nanosec)


def image_from_ros(msg: Any, source: str) -> np.ndarray:
    """A decoded sensor_msgs/Image (bayer_rggb16 or mono16) -> uint16 HxW; DatasetError when it is not 12-bit."""
    enc = str(msg.encoding)
    if enc not in ("bayer_rggb16", "mono16"):
        raise DatasetError(f"{source}: image encoding {enc!r}, expected bayer_rggb16")
    h, w, step = int(msg.height), int(msg.width), int(msg.step)
    raw = np.frombuffer(bytes(msg.data), dtype=">u2" if msg.is_bigendian else "<u2")
    if step < 2 * w or raw.size * 2 < step * h:
        raise DatasetError(f"{source}: truncated image data ({raw.size * 2} bytes for {h}x{w}, step {step})")
    img = raw[: step // 2 * h].reshape(h, step // 2)[:, :w].astype(np.uint16)
    if int(img.max(initial=0)) > 4095:
        raise DatasetError(f"{source}: values above 4095 (not 12-bit LSB-aligned)")
    return img


def _load_frame(path: Path, record_offset: int, channel_id: int, log_time_ns: int, topic: str) -> np.ndarray:
    from bracketry_base.recording.decode import decode
    from bracketry_base.recording.reader import RecordingReader

    source = f"{path}:{topic}@{log_time_ns}"
    try:
        data = RecordingReader(path).message_at(record_offset, channel_id, log_time_ns)
        if data is None:
            raise DatasetError(f"image not found: {source}")
        return image_from_ros(decode("sensor_msgs/msg/Image", data), source)
    except DatasetError:
        raise
    except Exception as exc:  # corrupt chunk, bad CDR
        raise DatasetError(f"cannot read image {source}: {exc}") from exc


def _scan_file(path: Path, sides: tuple[str, ...], problems: list[str]
               ) -> tuple[dict[str, list[Frame]], dict[str, Counter[tuple[int, int]]]]:
    """One pass over the file with the recorder's own reader (``bracketry_base.recording.reader``), the one verify and
    export use: a truncated file (kill -9, power loss) is read up to its last whole record, like they do."""
    from bracketry_base.recording.decode import decode
    from bracketry_base.recording.reader import RecordingReader

    frames: dict[str, list[Frame]] = {s: [] for s in sides}
    order_votes: dict[str, Counter[tuple[int, int]]] = {s: Counter() for s in sides}
    metas: dict[str, dict[int, Any]] = {s: {} for s in sides}
    images: dict[str, dict[int, tuple[int, int]]] = {s: {} for s in sides}  # log time -> (record offset, channel)
    meta_topics = {_meta_topic(s): s for s in sides}
    image_topics = {_image_topic(s): s for s in sides}
    try:
        reader = RecordingReader(path)
        for msg in reader.messages(set(meta_topics) | set(image_topics)):
            if msg.topic in image_topics:
                images[image_topics[msg.topic]][msg.log_time] = (msg.record_offset, msg.channel_id)
            else:
                schema = reader.schemas.get(reader.channels[msg.channel_id][1], ("", "", ""))
                metas[meta_topics[msg.topic]][msg.log_time] = decode(msg.schema_name, msg.data, schema[2] or None)
    except Exception as exc:
        reason = " ".join(str(exc).split()) or type(exc).__name__
        raise DatasetError(f"unreadable MCAP file {path}: {reason}") from exc
    if reader.report.truncated:
        problems.append(f"{path.name} is truncated (read up to its last whole record"
                        f"{'; ' + reader.report.problems[0] if reader.report.problems else ''})")
    for side in sides:
        for log_time in sorted(images[side]):
            meta = metas[side].get(log_time)
            if meta is None:
                problems.append(f"{side}: image at log time {log_time} in {path.name} has no frame_meta; skipped")
                continue
            exposure_us = int(meta.exposure_us)
            t_ns = _stamp_ns(meta)
            offset, channel_id = images[side][log_time]
            loader = functools.partial(_load_frame, path, offset, channel_id, log_time, _image_topic(side))
            frames[side].append(Frame(side, exposure_us, t_ns, f"{path.name}:{_image_topic(side)}@{t_ns}", loader))
            order_votes[side][(int(getattr(meta, "bracket_index", 0)), exposure_us)] += 1
        orphan_meta = set(metas[side]) - set(images[side])
        if orphan_meta:
            problems.append(f"{side}: {len(orphan_meta)} frame_meta without image in {path.name}")
    return frames, order_votes


def open_mcap(path: Path, sides: tuple[str, ...] | None = None, *, tolerance_ns: int = 2_000_000) -> Dataset:
    """Open one MCAP recording file, or a folder of its split ``*.mcap`` files."""
    from bracketry_base.recording.verify import recording_files

    try:
        files = recording_files(path)  # a <stem>.repaired.mcap replaces its truncated file, as in verify and export
    except Exception as exc:
        raise DatasetError(str(exc)) from exc
    wanted = tuple(sides) if sides else SIDES
    problems: list[str] = []
    frames_by_side: dict[str, list[Frame]] = {s: [] for s in wanted}
    votes: dict[str, Counter[tuple[int, int]]] = {s: Counter() for s in wanted}
    for f in files:
        fr, v = _scan_file(f, wanted, problems)
        for s in wanted:
            frames_by_side[s].extend(fr[s])
            votes[s].update(v[s])
    present = tuple(s for s in wanted if frames_by_side[s])
    if not present:
        raise DatasetError(f"no camera frames (topics /stereo/<side>/image_raw + frame_meta) in {path}")
    if sides is not None and len(present) != len(wanted):
        missing = [s for s in wanted if s not in present]
        raise DatasetError(f"no frames of side(s) {', '.join(missing)} in {path}")
    order = _cycle_order(votes[present[0]])
    sequences, group_problems = group_sequences({s: frames_by_side[s] for s in present}, tolerance_ns=tolerance_ns,
                                                order=order)
    problems.extend(group_problems)
    if not sequences:
        detail = f" ({problems[0]})" if problems else ""
        raise DatasetError(f"no complete bracket sequence in {path}{detail}")
    calib = path.parent / "calibration" if path.is_file() else path / "calibration"
    return Dataset(path=path, kind="mcap", sides=present, calibration_dir=calib if calib.is_dir() else None,
                   groundtruth_path=None, _sequences=sequences, problems=problems)


def _cycle_order(votes: Counter[tuple[int, int]]) -> tuple[int, ...] | None:
    """Exposures in bracket-table order (most common exposure per bracket_index), or None when inconsistent."""
    per_index: dict[int, Counter[int]] = {}
    for (idx, exp), n in votes.items():
        per_index.setdefault(idx, Counter())[exp] += n
    order = tuple(per_index[i].most_common(1)[0][0] for i in sorted(per_index))
    return order if len(set(order)) == len(order) and len(order) >= 2 else None
