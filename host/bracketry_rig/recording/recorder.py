"""The recorder: paired frames, trigger events and rig status -> MCAP files, in a writer thread.

Producers call ``put_set`` / ``put_event`` / ``put_status`` (never blocking): items go to a bounded queue; when it is
full the item is dropped and counted in ``overflows`` (logged with its trigger_seq), never silently. The writer
thread serialises (CDR), hands messages to ``ChunkedMcapWriter`` (chunks <= ``chunk_max_age_s``, parallel
compression) and starts a new file every ``split_bytes`` or ``split_s``. A write error (disk full) stops recording
cleanly: the error is kept in ``error``, later items are counted as lost, and the file written so far stays readable.
"""

from __future__ import annotations

import contextlib
import errno
import logging
import math
import queue
import threading
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from mcap_ros2._dynamic import serialize_dynamic

from bracketry_base.recording import topics as T
from bracketry_base.recording.calibration import CALIBRATION_RECORD, camera_infos
from bracketry_base.recording.mcap_writer import ChunkedMcapWriter
from bracketry_base.recording.msgdefs import MSGDEFS, encode_image, stamp
from bracketry_rig.events import TriggerEvent
from bracketry_rig.pairing.pairer import PairedSet

log = logging.getLogger(__name__)


@dataclass
class RecorderConfig:
    """Recording parameters (sizes in bytes, times in seconds)."""

    compression: str = "zstd"
    level: int = 1
    chunk_max_bytes: int = 32 << 20
    chunk_max_age_s: float = 0.4
    threads: int = 2
    split_bytes: int = 4 << 30
    split_s: float = 600.0
    queue_max_items: int = 48
    fsync_interval_s: float | None = 0.0  # fsync (on a background thread) after every chunk
    sides: tuple[str, ...] = T.SIDES


@dataclass
class RecorderSummary:
    files: list[str] = field(default_factory=list)
    messages: int = 0
    frames_written: dict[str, int] = field(default_factory=dict)
    overflows: int = 0
    lost_after_error: int = 0
    error: str | None = None
    bytes_written: int = 0
    uncompressed_bytes: int = 0


def camera_info_message(t_ns: int, side: str, height: int, width: int,
                        calibration: dict[str, Any] | None = None) -> dict[str, Any]:
    """A sensor_msgs/msg/CameraInfo dict; intrinsics from ``calibration`` (keys d, k, r, p, distortion_model)."""
    cal = calibration or {}
    return {"header": {"stamp": stamp(t_ns), "frame_id": f"camera_{side}"}, "height": height, "width": width,
            "distortion_model": cal.get("distortion_model", ""), "d": list(cal.get("d", [])),
            "k": list(cal.get("k", [0.0] * 9)), "r": list(cal.get("r", [1, 0, 0, 0, 1, 0, 0, 0, 1])),
            "p": list(cal.get("p", [0.0] * 12)), "binning_x": 0, "binning_y": 0,
            "roi": {"x_offset": 0, "y_offset": 0, "height": 0, "width": 0, "do_rectify": False}}


#: ``FrameMeta.exposure_source`` values: the frame's ExposureTime chunk, the exposure register read at the software
#: trigger, nothing read back
EXPOSURE_SOURCES = ("chunk", "register", "none")


def _finite(value: Any) -> float | None:
    if value is None:
        return None
    value = float(value)
    return value if math.isfinite(value) else None


def exposure_read_back(reported_us: float | None, register_us: float | None) -> tuple[float, str]:
    """A frame's read-back exposure and its source: the chunk value when the camera sent one, else the register read
    at its trigger, else (NaN, ``none``)."""
    if (chunk := _finite(reported_us)) is not None:
        return chunk, "chunk"
    if (register := _finite(register_us)) is not None:
        return register, "register"
    return math.nan, "none"


def mid_exposure_host_ns(trigger_host_ns: int, exposure_us: float | None) -> int:
    """Mid-exposure in host time: the trigger start plus half the exposure (rounded to ns); -1 without an exposure."""
    if exposure_us is None or not math.isfinite(exposure_us) or exposure_us < 0:
        return -1
    return int(trigger_host_ns) + round(float(exposure_us) * 500.0)


def frame_meta_message(pset: PairedSet, side: str, frame: Any) -> dict[str, Any]:
    """The bracketry_msgs/msg/FrameMeta dict of one frame of a paired set."""
    ev = pset.event
    reported = getattr(frame, "exposure_us_reported", None)
    read_us, source = exposure_read_back(reported, getattr(frame, "exposure_us_register", None))
    trigger_ns = ev.t_start_host_ns if ev is not None and ev.t_start_host_ns is not None else pset.stamp_ns
    n_frames = sum(f is not None for f in pset.frames.values())
    return {
        "header": {"stamp": stamp(pset.stamp_ns), "frame_id": f"camera_{side}"},
        "trigger_seq": pset.trigger_seq & 0xFFFFFFFF,
        "bracket_index": ev.bracket_index if ev is not None else 255,
        "exposure_us": ev.exposure_us if ev is not None else 0,
        "exposure_us_reported": float(reported) if reported is not None else math.nan,
        "cam_frame_id": int(frame.frame_id),
        "cam_frame_index": max(0, int(frame.frame_index)),
        "cam_timestamp_ns": int(frame.cam_timestamp_ns),
        "host_receive_ns": int(frame.host_receive_ns),
        "trigger_host_ns": int(ev.t_start_host_ns) if ev is not None and ev.t_start_host_ns is not None else -1,
        "trigger_device_us": int(ev.t_start_device_us) if ev is not None else 0,
        "missing_packets": int(getattr(frame, "missing_packets", 0) or 0),
        "skipped_ids": int(getattr(frame, "skipped_ids", 0) or 0),
        "status": str(frame.status),
        "has_trigger_event": ev is not None,
        "paired": n_frames == len(pset.frames) and ev is not None,
        "note": pset.notes.get(side, ""),
        "exposure_us_read": read_us,
        "exposure_source": source,
        "mid_exposure_host_ns": mid_exposure_host_ns(trigger_ns,
                                                     ev.exposure_us if ev is not None else _finite(read_us)),
    }


def current_frame_meta(meta: Any) -> dict[str, Any]:
    """A decoded FrameMeta of any version of the recording format as a dict of the current definition: fields a
    recording made before them lacks are derived from the stored ones as the recorder would have written them
    (``exposure_us_read`` from the chunk value, ``mid_exposure_host_ns`` from the trigger time and exposure)."""
    out: dict[str, Any] = {
        "header": {"stamp": {"sec": int(meta.header.stamp.sec), "nanosec": int(meta.header.stamp.nanosec)},
                   "frame_id": str(meta.header.frame_id)}}
    for name in ("trigger_seq", "bracket_index", "exposure_us", "exposure_us_reported", "cam_frame_id",
                 "cam_frame_index", "cam_timestamp_ns", "host_receive_ns", "trigger_host_ns", "trigger_device_us",
                 "missing_packets", "skipped_ids", "status", "has_trigger_event", "paired", "note"):
        out[name] = getattr(meta, name)
    if hasattr(meta, "exposure_source"):
        out.update(exposure_us_read=float(meta.exposure_us_read), exposure_source=str(meta.exposure_source),
                   mid_exposure_host_ns=int(meta.mid_exposure_host_ns))
        return out
    read_us, source = exposure_read_back(float(meta.exposure_us_reported), None)
    stamp_ns = int(meta.header.stamp.sec) * 1_000_000_000 + int(meta.header.stamp.nanosec)
    trigger_ns = int(meta.trigger_host_ns) if int(meta.trigger_host_ns) >= 0 else stamp_ns
    exposure = float(meta.exposure_us) if meta.has_trigger_event else _finite(read_us)
    out.update(exposure_us_read=read_us, exposure_source=source,
               mid_exposure_host_ns=mid_exposure_host_ns(trigger_ns, exposure))
    return out


def current_status(status: Any) -> dict[str, Any]:
    """A decoded RigStatus of any version of the recording format as a dict of the current definition (fields a
    recording made before them lacks: 0, as the recorder writes a count it has none of)."""
    out: dict[str, Any] = {
        "header": {"stamp": {"sec": int(status.header.stamp.sec), "nanosec": int(status.header.stamp.nanosec)},
                   "frame_id": str(status.header.frame_id)}}
    for key in STATUS_FIELDS:
        out[key] = getattr(status, key, 0)
    return out


def trigger_message(ev: TriggerEvent) -> dict[str, Any]:
    return {"session_id": ev.session_id & 0xFFFFFFFF, "trigger_seq": ev.trigger_seq & 0xFFFFFFFF,
            "bracket_index": ev.bracket_index, "exposure_us": ev.exposure_us,
            "t_start_device_us": ev.t_start_device_us,
            "t_start_host_ns": ev.t_start_host_ns if ev.t_start_host_ns is not None else -1}


STATUS_FIELDS = ("fps_left", "fps_right", "frames_left", "frames_right", "drops_left", "drops_right",
                 "incomplete_left", "incomplete_right", "unpaired", "missing_packets_left", "missing_packets_right",
                 "queue_overflows", "temperature_left_c", "temperature_right_c", "free_disk_mb", "lost_triggers_left",
                 "lost_triggers_right")


class Recorder:
    """Writes ``out_dir/<name>_<NNN>.mcap`` files from a bounded queue in its own thread."""

    def __init__(self, out_dir: str | Path, name: str, config: RecorderConfig | None = None, *,
                 metadata: dict[str, str] | None = None, calibration: dict[str, dict[str, Any]] | None = None,
                 calibration_files: dict[str, str] | None = None) -> None:
        self.out_dir = Path(out_dir)
        self.name = name
        self.config = config or RecorderConfig()
        self.metadata = dict(metadata or {})
        #: the stereo calibration carried by every file (``bracketry_base.recording.calibration``: {file name: text})
        self.calibration_files = dict(calibration_files or {})
        self.calibration = calibration or (camera_infos(self.calibration_files) if self.calibration_files else {})
        self.summary = RecorderSummary(frames_written={s: 0 for s in self.config.sides})
        self._queue: queue.Queue[tuple[str, Any] | None] = queue.Queue(maxsize=self.config.queue_max_items)
        self._thread: threading.Thread | None = None
        self._failed = threading.Event()
        self._writer: ChunkedMcapWriter | None = None
        self._channels: dict[str, int] = {}
        self._encoders = {name: serialize_dynamic(name, text)[name] for name, text in MSGDEFS.items()}
        self._file_index = 0
        self._file_started = 0.0
        self._lock = threading.Lock()

    @property
    def error(self) -> str | None:
        return self.summary.error

    @property
    def overflows(self) -> int:
        return self.summary.overflows

    def start(self) -> Recorder:
        self.out_dir.mkdir(parents=True, exist_ok=True)
        self._open_file()
        self._thread = threading.Thread(target=self._run, name="recorder", daemon=True)
        self._thread.start()
        return self

    # -- producers --------------------------------------------------------------------------------------------------
    def _put(self, kind: str, item: Any, what: str, timeout_s: float | None = None) -> bool:
        if self._failed.is_set():
            with self._lock:
                self.summary.lost_after_error += 1
            return False
        try:
            if timeout_s is None:
                self._queue.put_nowait((kind, item))
            else:
                self._queue.put((kind, item), timeout=timeout_s)
            return True
        except queue.Full:
            with self._lock:
                self.summary.overflows += 1
            log.error("recorder queue full: %s dropped", what)
            return False

    def put_set(self, pset: PairedSet, timeout_s: float | None = None) -> bool:
        """Queue a paired set (its frames, frame metas and camera infos); never blocks unless ``timeout_s`` is given
        (offline tools and benchmarks may wait for room; the live path must not)."""
        return self._put("set", pset, f"trigger_seq {pset.trigger_seq}", timeout_s)

    def put_event(self, event: TriggerEvent, timeout_s: float | None = None) -> bool:
        """Queue a TRIGGER event (non-blocking unless ``timeout_s``)."""
        return self._put("event", event, f"trigger event {event.trigger_seq}", timeout_s)

    def put_status(self, status: dict[str, Any]) -> bool:
        """Queue a rig status (keys of ``STATUS_FIELDS``; missing ones are 0/NaN) stamped ``t_ns`` or now."""
        return self._put("status", status, "rig status")

    # -- writer thread -----------------------------------------------------------------------------------------------
    def _file_path(self) -> Path:
        return self.out_dir / f"{self.name}_{self._file_index:03d}.mcap"

    def _open_file(self) -> None:
        cfg = self.config
        path = self._file_path()
        w = ChunkedMcapWriter(path, compression=cfg.compression, level=cfg.level,
                              chunk_max_bytes=cfg.chunk_max_bytes, chunk_max_age_s=cfg.chunk_max_age_s,
                              threads=cfg.threads, fsync_interval_s=cfg.fsync_interval_s)
        schema_ids = {name: w.register_schema(name, text.encode()) for name, text in MSGDEFS.items()}
        self._channels = {topic: w.register_channel(topic, schema_ids[schema])
                          for topic, schema in T.topic_schemas(cfg.sides).items()}
        w.add_metadata(T.METADATA_NAME, {"format": T.FORMAT_NAME, "version": T.FORMAT_VERSION,
                                         "sides": ",".join(cfg.sides), "file_index": str(self._file_index),
                                         "image_encoding": T.IMAGE_ENCODING, **self.metadata})
        if self.calibration_files:
            w.add_metadata(CALIBRATION_RECORD, self.calibration_files)
        self._writer = w
        self._file_started = time.monotonic()
        self.summary.files.append(str(path))

    def _maybe_split(self) -> None:
        w = self._writer
        assert w is not None
        if w.bytes_written >= self.config.split_bytes or time.monotonic() - self._file_started >= self.config.split_s:
            self._finish_file()
            self._file_index += 1
            self._open_file()

    def _finish_file(self) -> None:
        w, self._writer = self._writer, None
        if w is not None:
            w.finish()
            self.summary.bytes_written += w.bytes_written
            self.summary.uncompressed_bytes += w.uncompressed_bytes

    def _write(self, topic: str, schema: str, message: dict[str, Any] | list, t_ns: int, seq: int = 0) -> None:
        assert self._writer is not None
        data = message if isinstance(message, list) else self._encoders[schema](message)
        self._writer.add_message(self._channels[topic], int(t_ns), data, sequence=seq)
        self.summary.messages += 1

    def _write_set(self, pset: PairedSet) -> None:
        for side, frame in pset.frames.items():
            if frame is None:
                continue
            t = pset.stamp_ns
            seq = pset.trigger_seq
            if frame.image is not None:
                self._write(T.image_topic(side), T.SCHEMA_IMAGE,
                            encode_image(t, f"camera_{side}", frame.image, T.IMAGE_ENCODING), t, seq)
                self._write(T.camera_info_topic(side), T.SCHEMA_CAMERA_INFO,
                            camera_info_message(t, side, frame.image.shape[0], frame.image.shape[1],
                                                self.calibration.get(side)), t, seq)
                self.summary.frames_written[side] = self.summary.frames_written.get(side, 0) + 1
            self._write(T.frame_meta_topic(side), T.SCHEMA_FRAME_META, frame_meta_message(pset, side, frame), t, seq)

    def _write_status(self, status: dict[str, Any]) -> None:
        t = int(status.get("t_ns", time.time_ns()))
        msg: dict[str, Any] = {"header": {"stamp": stamp(t), "frame_id": "rig"}}
        for key in STATUS_FIELDS:
            default: Any = math.nan if key.endswith(("_c", "fps_left", "fps_right")) else 0
            value = status.get(key, default)
            msg[key] = default if value is None else value
        with self._lock:
            msg["queue_overflows"] = self.summary.overflows
        self._write(T.STATUS_TOPIC, T.SCHEMA_STATUS, msg, t)

    def _run(self) -> None:
        while True:
            try:
                item = self._queue.get(timeout=0.1)
            except queue.Empty:
                item = ("tick", None)
            if item is None:
                break
            if self._failed.is_set():
                with self._lock:
                    self.summary.lost_after_error += item[0] != "tick"
                continue
            kind, payload = item
            try:
                if kind == "set":
                    self._write_set(payload)
                elif kind == "event":
                    ev = payload
                    t = ev.t_start_host_ns if ev.t_start_host_ns is not None else time.time_ns()
                    self._write(T.TRIGGER_TOPIC, T.SCHEMA_TRIGGER, trigger_message(ev), t, ev.trigger_seq)
                elif kind == "status":
                    self._write_status(payload)
                assert self._writer is not None
                self._writer.tick()
                self._maybe_split()
            except OSError as exc:
                self._fail(exc)

    def _fail(self, exc: OSError) -> None:
        what = "disk full" if exc.errno == errno.ENOSPC else (exc.strerror or str(exc))
        self.summary.error = f"recording stopped: {what} while writing {self._file_path()}"
        log.error(self.summary.error)
        self._failed.set()
        w, self._writer = self._writer, None
        if w is not None:
            self.summary.bytes_written += w.bytes_written
            with contextlib.suppress(OSError):
                w.close()

    def stop(self, timeout_s: float = 60.0) -> RecorderSummary:
        """Write what is queued, finish the file (summary + footer) and return the summary."""
        if self._thread is not None:
            self._queue.put(None)
            self._thread.join(timeout=timeout_s)
            self._thread = None
        if not self._failed.is_set():
            try:
                self._finish_file()
            except OSError as exc:
                self._fail(exc)
        return self.summary
