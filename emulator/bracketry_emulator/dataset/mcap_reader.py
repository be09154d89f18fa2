"""Reader of our MCAP recordings (spec: host/bracketry/recording/RECORDING.md), through ``mcap`` + ``mcap_ros2``.

Per side: ``/stereo/<side>/image_raw`` (sensor_msgs/msg/Image, encoding ``bayer_rggb16``, 12 significant bits
LSB-aligned, header.stamp = frame time) and ``/stereo/<side>/frame_meta`` (bracketry_msgs/msg/FrameMeta with
``exposure_us`` and ``bracket_index``, same log time and header stamp as its image). Frames are paired with their
metadata by log time, then grouped into bracket sequences exactly like the BorealHDR tree,
with the cycle order given by ``bracket_index``. Images are decoded lazily (one indexed seek per frame). A recording
split into several files is read as one when the folder of ``*.mcap`` files is given.
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


def _load_frame(path: Path, topic: str, log_time_ns: int) -> np.ndarray:
    from mcap.reader import make_reader
    from mcap_ros2.decoder import DecoderFactory

    source = f"{path}:{topic}@{log_time_ns}"
    try:
        with path.open("rb") as fh:
            reader = make_reader(fh, decoder_factories=[DecoderFactory()])
            try:  # mcap >= 1.3 names the inclusive bounds; older versions only have start_time/end_time
                found = reader.iter_decoded_messages(topics=[topic], starting_at=log_time_ns, ending_at=log_time_ns)
            except TypeError:
                found = reader.iter_decoded_messages(topics=[topic], start_time=log_time_ns, end_time=log_time_ns + 1)
            for _schema, _channel, message, decoded in found:
                if message.log_time == log_time_ns:
                    return image_from_ros(decoded, source)
    except DatasetError:
        raise
    except Exception as exc:  # corrupt chunk, truncated file, bad CDR
        raise DatasetError(f"cannot read image {source}: {exc}") from exc
    raise DatasetError(f"image not found: {source}")


def _scan_file(path: Path, sides: tuple[str, ...], problems: list[str]
               ) -> tuple[dict[str, list[Frame]], dict[str, Counter[tuple[int, int]]]]:
    from mcap.reader import make_reader
    from mcap_ros2.decoder import DecoderFactory

    frames: dict[str, list[Frame]] = {s: [] for s in sides}
    order_votes: dict[str, Counter[tuple[int, int]]] = {s: Counter() for s in sides}
    metas: dict[str, dict[int, Any]] = {s: {} for s in sides}
    images: dict[str, set[int]] = {s: set() for s in sides}  # log times of the image messages
    meta_topics = {_meta_topic(s): s for s in sides}
    image_topics = {_image_topic(s): s for s in sides}
    try:
        with path.open("rb") as fh:
            reader = make_reader(fh, decoder_factories=[DecoderFactory()])
            for _schema, channel, message, decoded in reader.iter_decoded_messages(topics=list(meta_topics)):
                metas[meta_topics[channel.topic]][message.log_time] = decoded
        with path.open("rb") as fh:
            reader = make_reader(fh)
            for _schema, channel, message in reader.iter_messages(topics=list(image_topics)):
                images[image_topics[channel.topic]].add(message.log_time)
    except Exception as exc:
        raise DatasetError(f"unreadable MCAP file {path}: {exc}") from exc
    for side in sides:
        for log_time in sorted(images[side]):
            meta = metas[side].get(log_time)
            if meta is None:
                problems.append(f"{side}: image at log time {log_time} in {path.name} has no frame_meta; skipped")
                continue
            exposure_us = int(meta.exposure_us)
            t_ns = _stamp_ns(meta)
            loader = functools.partial(_load_frame, path, _image_topic(side), log_time)
            frames[side].append(Frame(side, exposure_us, t_ns, f"{path.name}:{_image_topic(side)}@{t_ns}", loader))
            order_votes[side][(int(getattr(meta, "bracket_index", 0)), exposure_us)] += 1
        orphan_meta = set(metas[side]) - set(images[side])
        if orphan_meta:
            problems.append(f"{side}: {len(orphan_meta)} frame_meta without image in {path.name}")
    return frames, order_votes


def open_mcap(path: Path, sides: tuple[str, ...] | None = None, *, tolerance_ns: int = 2_000_000) -> Dataset:
    """Open one MCAP recording file, or a folder of its split ``*.mcap`` files."""
    files = sorted(path.glob("*.mcap")) if path.is_dir() else [path]
    if not files:
        raise DatasetError(f"no .mcap file in {path}")
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
