"""One GigE Vision camera through Aravis: open by IP (or device id), configure a profile, stream in our own thread.

Buffers come from a pool pushed to the Aravis stream; our thread pops them (never the Aravis receive-thread
callback, aravis#218), copies/unpacks the pixels into a ``Frame`` and pushes the buffer back at once. Stream
statistics (completed, failures, underruns, missing and resent packets) are read from the stream after each frame so
that every frame carries the missing-packet count that arrived with it.
"""

from __future__ import annotations

import contextlib
import logging
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from bracketry_base.errors import BracketryError
from bracketry_base.ipv4 import unicast_ipv4
from bracketry_rig.cameras.aravis_gi import CameraError, glib_error_message, load_aravis
from bracketry_rig.cameras.frame_ids import FrameIdUnwrapper
from bracketry_rig.cameras.pixels import PIXEL_FORMAT_NAMES, payload_to_image
from bracketry_rig.cameras.profiles import (
    CameraSettings,
    ConfigReport,
    apply_writes,
    probe_features,
    profile_kind,
    profile_writes,
)
from bracketry_rig.cameras.triggering import ExposureReadbacks, TriggerStamps

log = logging.getLogger(__name__)

#: how long opening a camera waits for the GigE Vision control privilege (heartbeat timeout 3 s + margin), seconds
CONTROL_WAIT_S = 5.0
#: retry period while waiting for the control privilege, seconds
CONTROL_POLL_S = 0.25

#: Aravis stream statistics we report (name in ``get_info_uint64_by_name``)
STREAM_COUNTERS = ("n_completed_buffers", "n_failures", "n_underruns", "n_missing_packets", "n_resent_packets",
                   "n_aborted_buffers", "n_timeouts")


@dataclass
class Frame:
    """One image delivered by a camera.

    Attributes:
        side: camera name (``left``/``right``).
        frame_id: raw 16-bit GVSP block id (1..65535).
        frame_index: frame number since the stream started (0 = first frame), from the unwrapped ids: skipped ids
            (frames the camera sent but we never received) advance it too.
        skipped_ids: ids missing right before this frame (0 normally, -1 for a repeated/backwards id).
        status: ``success`` or the Aravis buffer status in lower case (``missing_packets``, ``timeout``, ...).
        image: ``(height, width)`` uint16 codes (12-bit formats LSB-aligned), or None when the buffer has no pixels.
        cam_timestamp_ns: the camera's timestamp of the frame (GVSP leader, or the Timestamp chunk), camera clock ns.
        host_receive_ns: host ``time.time_ns()`` when our thread popped the buffer.
        missing_packets: stream's missing-packet counter increase since the previous frame.
        exposure_us_reported: exposure the camera reports for this frame (ExposureTime chunk), None without chunks.
        counter_value: the CounterValue chunk (trigger counter), None without chunks.
        exposure_us_register: the exposure register read back at this frame's software trigger (set by the recording
            session once the frame is paired with its pulse, from ``GigECamera.exposure_readbacks``), None otherwise.
        trigger_seq: the pulse its own trigger stamp shows (set by the recording session from
            ``GigECamera.trigger_stamps`` for a camera that stamps frames with its trigger's receive time, see
            ``bracketry_rig.cameras.triggering``), None when unknown.
    """

    side: str
    frame_id: int
    frame_index: int
    skipped_ids: int
    status: str
    image: np.ndarray | None
    width: int
    height: int
    pixel_format: str
    cam_timestamp_ns: int
    host_receive_ns: int
    missing_packets: int = 0
    exposure_us_reported: float | None = None
    counter_value: int | None = None
    exposure_us_register: float | None = None
    trigger_seq: int | None = None


@dataclass
class StreamStats:
    """Counters of one stream since ``start()``: Aravis's own plus ours (frames delivered, skipped ids)."""

    counters: dict[str, int] = field(default_factory=dict)
    frames: int = 0
    frames_incomplete: int = 0
    skipped_ids: int = 0
    pop_timeouts: int = 0

    def as_dict(self) -> dict[str, int]:
        return {**self.counters, "frames": self.frames, "frames_incomplete": self.frames_incomplete,
                "skipped_ids": self.skipped_ids, "pop_timeouts": self.pop_timeouts}


def rmem_max_bytes() -> int | None:
    """``net.core.rmem_max`` (largest socket receive buffer an unprivileged setsockopt gets), or None."""
    try:
        return int(Path("/proc/sys/net/core/rmem_max").read_text().strip())
    except (OSError, ValueError):
        return None


def socket_buffer_bytes(payload_bytes: int, frames: int = 4) -> int:
    """Receive socket buffer to request: ``frames`` whole payloads (at least 1 MiB)."""
    return max(1 << 20, payload_bytes * frames)


class GigECamera:
    """A GigE Vision camera opened by IP address (unicast only) or, with ``allow_discovery``, by device id.

    Device ids are resolved by Aravis's device list, which broadcasts discovery on every interface: only allowed
    inside a private network namespace (pass ``allow_discovery=True`` there).
    """

    def __init__(self, address: str | None = None, *, device_id: str | None = None, side: str = "camera",
                 allow_discovery: bool = False, control_wait_s: float = CONTROL_WAIT_S) -> None:
        if not address and not device_id:
            raise CameraError(f"camera {side}: give an IP address or a device id")
        if device_id and not address and not allow_discovery:
            raise CameraError(f"camera {side}: opening by device id {device_id!r} needs discovery (broadcast); "
                              "give its IP address, or allow discovery inside a private network namespace")
        if address and not allow_discovery:
            try:  # a name would be resolved by Aravis through a discovery broadcast on every interface
                unicast_ipv4(address)
            except BracketryError as exc:
                raise CameraError(f"camera {side}: {exc}") from None
        self.side = side
        self.address = address
        self.device_id = device_id
        self._aravis = load_aravis()
        target = address or device_id
        try:
            self._camera = self._aravis.Camera.new(target)
        except Exception as exc:
            raise CameraError(f"camera {side}: cannot open {target}: {glib_error_message(exc)}") from exc
        if self._camera is None:
            raise CameraError(f"camera {side}: cannot open {target}")
        self._device = self._camera.get_device()
        self._take_control(control_wait_s)
        self._stream: Any = None
        self._thread: threading.Thread | None = None
        self._running = threading.Event()
        self._stats = StreamStats()
        self._stats_lock = threading.Lock()
        self._settings: CameraSettings | None = None
        self._chunk_parser: Any = None
        self._chunks_on = False
        self._counter_names: tuple[str, ...] = ()
        #: exposure register read back at each software trigger, by trigger_seq (``SoftwareTrigger`` fills it)
        self.exposure_readbacks = ExposureReadbacks()
        #: host time of each software trigger sent, by trigger_seq (``SoftwareTrigger`` fills it)
        self.trigger_stamps = TriggerStamps()
        self._first_stream = True  # no stream started on this connection yet (see ``start``)

    def _take_control(self, wait_s: float) -> None:
        """Hold the GigE Vision control privilege (writes and streaming need it), waiting up to ``wait_s`` seconds.

        A controller that died without releasing it (our own daemon after SIGKILL) keeps it until the camera's
        heartbeat timeout (GevHeartbeatTimeout, 3 s by default on the fake and on Basler cameras) runs out; Aravis
        then opens the camera read-only, so we retry ``take_control`` until the privilege is free.
        """
        dev = self._device
        if not hasattr(dev, "is_controller") or dev.is_controller():
            return
        deadline = time.monotonic() + max(wait_s, 0.0)
        while True:
            with contextlib.suppress(Exception):
                if dev.take_control() and dev.is_controller():
                    log.info("camera %s: control privilege taken over after the previous controller's timeout",
                             self.side)
                    return
            if time.monotonic() >= deadline:
                break
            time.sleep(CONTROL_POLL_S)
        raise CameraError(f"camera {self.side}: another application controls the camera at "
                          f"{self.address or self.device_id} (GigE Vision control privilege still held after "
                          f"{wait_s:.1f} s); close it or wait for its heartbeat timeout")

    # -- identity and features -------------------------------------------------------------------------------------
    def check_identity(self, expected: str) -> None:
        """Raise CameraError unless the camera reports ``expected`` as its device id or serial number (catches
        swapped cables or a replaced camera behind a configured address)."""
        info = self.info()
        if expected not in (info.get("device_id"), info.get("serial")):
            raise CameraError(f"camera {self.side}: the camera at {self.address} is "
                              f"{info.get('serial') or info.get('device_id')!r}, not the configured device_id "
                              f"{expected!r} (swapped cables?)")

    @property
    def device(self) -> Any:
        """The ``Aravis.Device`` (GenICam feature access)."""
        return self._device

    def info(self) -> dict[str, Any]:
        """Vendor, model, serial number, device id and address."""
        cam = self._camera

        def safe(fn: Callable[[], Any]) -> Any:
            try:
                return fn()
            except Exception:
                return None

        return {"side": self.side, "address": self.address, "vendor": safe(cam.get_vendor_name),
                "model": safe(cam.get_model_name), "serial": safe(cam.get_device_serial_number),
                "device_id": safe(cam.get_device_id) or self.device_id,
                "pixel_formats": safe(lambda: list(cam.dup_available_pixel_formats_as_strings())) or []}

    def probe(self) -> dict[str, Any]:
        """Identity plus the probed features (availability, value, enumeration values)."""
        return {**self.info(), "features": probe_features(self._device)}

    def configure(self, settings: CameraSettings) -> ConfigReport:
        """Write the profile's features and read each back. Call ``report.raise_if_mismatch()`` before recording."""
        report = apply_writes(self._device, self.side, settings.profile, profile_writes(settings))
        self._settings = settings
        self._chunks_on = any(r.name == "ChunkModeActive" and r.status == "ok" for r in report.results)
        if self._chunks_on:
            try:
                self._chunk_parser = self._camera.create_chunk_parser()
            except Exception:
                self._chunk_parser = None
        return report

    def _exposure_feature(self) -> str:
        return "ExposureTimeAbs" if self._device.get_feature("ExposureTime") is None else "ExposureTime"

    def set_exposure_us(self, exposure_us: float) -> None:
        """Set the exposure timed by the camera itself (fake camera: ExposureTimeAbs; Basler Timed mode)."""
        self._device.set_float_feature_value(self._exposure_feature(), float(exposure_us))

    def read_exposure_us(self) -> float:
        """The exposure register (ExposureTime, or ExposureTimeAbs on the fake camera) as the camera holds it: one
        GVCP read (Aravis does not cache registers), so the value the camera took, rounded to its granularity."""
        return float(self._device.get_float_feature_value(self._exposure_feature()))

    def software_trigger(self) -> None:
        """Fire one software trigger (TriggerSource Software)."""
        self._device.execute_command("TriggerSoftware")

    def read_lost_triggers(self) -> int | None:
        """Software triggers the camera lost so far (its profile's ``lost_triggers_register``, one GVCP read; poll at
        ~1 Hz), None when its profile keeps no such count or the read failed."""
        if self._settings is None:
            return None
        register = profile_kind(self._settings.profile).lost_triggers_register
        if register is None:
            return None
        try:
            return int(self._device.read_register(register))
        except Exception as exc:
            log.debug("camera %s: lost-trigger count unreadable: %s", self.side, glib_error_message(exc))
            return None

    def read_temperature_c(self) -> float | None:
        """DeviceTemperature in °C, or None when the camera has none (poll at ~1 Hz, not per frame)."""
        if self._device.get_feature("DeviceTemperature") is None:
            return None
        try:
            return float(self._device.get_float_feature_value("DeviceTemperature"))
        except Exception:
            return None

    # -- streaming -------------------------------------------------------------------------------------------------
    def start(self, on_frame: Callable[[Frame], None], *, n_buffers: int = 16, socket_buffer: int | None = None,
              packet_resend: bool = True, keep_pixels: bool = True) -> None:
        """Create the stream with ``n_buffers`` buffers, start acquisition and the popping thread.

        ``on_frame`` runs in our thread for every buffer (incomplete ones included, with ``image`` None when the
        buffer has no usable pixels); it must be quick (hand the frame to a queue).
        """
        if self._thread is not None:
            raise CameraError(f"camera {self.side}: already streaming")
        Aravis = self._aravis
        try:
            payload = int(self._camera.get_payload())
            self._stream = self._camera.create_stream(None, None)
        except Exception as exc:
            raise CameraError(f"camera {self.side}: cannot create the stream: {glib_error_message(exc)}") from exc
        if self._stream is None:
            raise CameraError(f"camera {self.side}: cannot create the stream")
        self._counter_names = self._available_counters()
        self._tune_stream(payload, socket_buffer, packet_resend)
        for _ in range(n_buffers):
            self._stream.push_buffer(Aravis.Buffer.new_allocate(payload))
        self._unwrapper = FrameIdUnwrapper()
        self.exposure_readbacks.clear()  # a new stream's pulses are numbered from 0 again
        self.trigger_stamps.clear()
        self._last_missing = 0
        self._stats = StreamStats()
        self._running.set()
        self._keep_pixels = keep_pixels
        self._thread = threading.Thread(target=self._pop_loop, args=(on_frame,), name=f"cam-{self.side}",
                                        daemon=True)
        self._thread.start()
        try:
            if self._first_stream:
                # an acquisition a controller killed mid-recording left running keeps streaming to that controller's
                # port: stopped first (once, on the first stream of this connection), the acquisition started now
                # streams to the destination written above
                self._first_stream = False
                with contextlib.suppress(Exception):
                    self._camera.stop_acquisition()
            self._camera.start_acquisition()
        except Exception as exc:
            self.stop()
            raise CameraError(f"camera {self.side}: cannot start acquisition: {glib_error_message(exc)}") from exc

    def _tune_stream(self, payload: int, socket_buffer: int | None, packet_resend: bool) -> None:
        Aravis = self._aravis
        stream = self._stream
        if not hasattr(Aravis, "GvStream") or not isinstance(stream, Aravis.GvStream):
            return
        want = socket_buffer if socket_buffer is not None else socket_buffer_bytes(payload)
        limit = rmem_max_bytes()
        if limit is not None and want > limit:
            log.warning("camera %s: socket buffer %d B wanted but net.core.rmem_max is %d B "
                        "(raise it with sysctl -w net.core.rmem_max=%d)", self.side, want, limit, want)
        try:
            stream.set_property("socket-buffer", Aravis.GvStreamSocketBuffer.FIXED)
            stream.set_property("socket-buffer-size", int(want))
            stream.set_property("packet-resend", Aravis.GvStreamPacketResend.ALWAYS if packet_resend
                                else Aravis.GvStreamPacketResend.NEVER)
        except Exception as exc:  # a tuning failure must not stop streaming, but is said
            log.warning("camera %s: stream tuning failed: %s", self.side, glib_error_message(exc))

    def _available_counters(self) -> tuple[str, ...]:
        try:
            names = {self._stream.get_info_name(i) for i in range(int(self._stream.get_n_infos()))}
        except Exception:
            return ()
        return tuple(n for n in STREAM_COUNTERS if n in names)

    def _read_counters(self) -> dict[str, int]:
        out: dict[str, int] = {}
        if self._stream is None:
            return out
        for name in self._counter_names:
            try:
                out[name] = int(self._stream.get_info_uint64_by_name(name))
            except Exception:
                continue
        return out

    def _pop_loop(self, on_frame: Callable[[Frame], None]) -> None:
        Aravis = self._aravis
        stream = self._stream
        while self._running.is_set():
            buf = stream.timeout_pop_buffer(100_000)
            if buf is None:
                with self._stats_lock:
                    self._stats.pop_timeouts += 1
                continue
            host_ns = time.time_ns()
            try:
                frame = self._to_frame(buf, host_ns, Aravis)
            finally:
                stream.push_buffer(buf)
            try:
                on_frame(frame)
            except Exception:  # the consumer's bug must not kill acquisition silently
                log.exception("camera %s: frame consumer failed", self.side)

    def _to_frame(self, buf: Any, host_ns: int, Aravis: Any) -> Frame:
        status_enum = buf.get_status()
        status = "success" if status_enum == Aravis.BufferStatus.SUCCESS else \
            status_enum.value_nick.replace("-", "_")
        frame_id = int(buf.get_frame_id())
        index, skipped = self._unwrapper.update(frame_id)
        counters = self._read_counters()
        missing_total = counters.get("n_missing_packets", 0)
        missing = max(0, missing_total - self._last_missing)
        self._last_missing = missing_total
        image = None
        width = height = 0
        pixel_format = ""
        if status == "success" and self._keep_pixels:
            try:
                width, height = int(buf.get_image_width()), int(buf.get_image_height())
                code = int(buf.get_image_pixel_format())
                pixel_format = PIXEL_FORMAT_NAMES.get(code, hex(code))
                data = buf.get_data()
                if data and width and height:
                    image = payload_to_image(data, pixel_format, width, height)
            except Exception as exc:
                log.warning("camera %s: frame %d unreadable: %s", self.side, frame_id, exc)
                image = None
        exposure = counter = None
        cam_ts = int(buf.get_timestamp())
        if self._chunks_on and self._chunk_parser is not None and status == "success":
            exposure, counter, chunk_ts = self._parse_chunks(buf)
            if chunk_ts:
                cam_ts = chunk_ts
        with self._stats_lock:
            self._stats.counters = counters
            self._stats.frames += 1
            self._stats.frames_incomplete += status != "success"
            self._stats.skipped_ids += max(0, skipped)
        return Frame(side=self.side, frame_id=frame_id, frame_index=index, skipped_ids=skipped, status=status,
                     image=image, width=width, height=height, pixel_format=pixel_format, cam_timestamp_ns=cam_ts,
                     host_receive_ns=host_ns, missing_packets=missing, exposure_us_reported=exposure,
                     counter_value=counter)

    def _parse_chunks(self, buf: Any) -> tuple[float | None, int | None, int | None]:
        parser = self._chunk_parser

        def get(kind: str, name: str) -> Any:
            try:
                return parser.get_float_value(buf, name) if kind == "f" else parser.get_integer_value(buf, name)
            except Exception:
                return None

        exposure = get("f", "ChunkExposureTime")
        counter = get("i", "ChunkCounterValue")
        ts = get("i", "ChunkTimestamp")
        return (float(exposure) if exposure is not None else None, int(counter) if counter is not None else None,
                int(ts) if ts else None)

    def stats(self) -> StreamStats:
        """A snapshot of the stream counters."""
        with self._stats_lock:
            return StreamStats(dict(self._stats.counters), self._stats.frames, self._stats.frames_incomplete,
                               self._stats.skipped_ids, self._stats.pop_timeouts)

    def stop(self) -> None:
        """Stop acquisition and the popping thread (idempotent)."""
        try:
            self._camera.stop_acquisition()
        except Exception as exc:
            log.warning("camera %s: stop_acquisition failed: %s", self.side, glib_error_message(exc))
        self._running.clear()
        if self._thread is not None:
            self._thread.join(timeout=5.0)
            self._thread = None
        if self._stream is not None:
            with self._stats_lock:
                self._stats.counters = self._read_counters()
            self._stream = None

    def close(self) -> None:
        self.stop()
        self._device = None
        self._camera = None

    def __enter__(self) -> GigECamera:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()
