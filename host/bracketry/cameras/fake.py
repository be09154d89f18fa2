"""A fake GigE Vision camera served from this process: ``Aravis.GvFakeCamera`` with our own pixels.

The camera is a real GVCP/GVSP server on ``address`` (UDP 3956 fixed per IP, so one camera per loopback address:
127.0.0.1, or 127.0.0.2/.3 inside a private network namespace, see ``bracketry.cameras.netns``). Clients open it by
IP with ``GigECamera`` exactly as a real camera.

Pixels come from ``image_source(exposure_us, width, height) -> uint16 (height, width)`` called for each frame in the
fake camera's thread with the exposure the camera had when the frame was triggered (its ExposureTimeAbs). They are
written through the C function ``arv_fake_camera_set_fill_pattern`` via ctypes (the PyGObject binding of that callback
crashes). Mono16 carries 12-bit codes unchanged (the fake has no BayerRG12 pixels); 8-bit formats get ``code >> 4``.
Each served frame's exposure is recorded in ``served_exposures_us`` (in serving order) so tests can read it.

Quirks of the Aravis 0.8.26 fake, handled by its users: the first TriggerSoftware after AcquisitionStart is often
lost (``bracketry.cameras.triggering.SoftwareTrigger.arm`` fires a marked priming trigger first); it polls one trigger
flag, so on a heavily loaded machine two triggers can merge into one frame (rendered with the later exposure);
its timestamps are host time (``Pairer(initial_alignment="host_time")``).
"""

from __future__ import annotations

import contextlib
import ctypes
import threading
from collections.abc import Callable
from typing import Any

import numpy as np

from bracketry.cameras.aravis_gi import CameraError, glib_error_message, load_aravis
from bracketry.cameras.pixels import PIXEL_FORMAT_CODES

ImageSource = Callable[[int, int, int], np.ndarray]

_FILL_CB = ctypes.CFUNCTYPE(None, ctypes.c_void_p, ctypes.c_void_p, ctypes.c_uint32, ctypes.c_uint32, ctypes.c_uint32)
#: ctypes callbacks must outlive the camera threads that call them; never freed (a few bytes per camera).
_KEEP_ALIVE: list[Any] = []


def ramp_source(exposure_us: int, width: int, height: int) -> np.ndarray:
    """Default pixels: a diagonal ramp of 12-bit codes scaled by the exposure (saturating at 4095)."""
    y, x = np.mgrid[0:height, 0:width]
    base = ((x + y) % 512).astype(np.float64) * 8.0
    return np.clip(base * (exposure_us / 8000.0), 0, 4095).astype(np.uint16)


class _Lib:
    """ctypes bindings of the few libaravis C functions the fill route needs."""

    def __init__(self) -> None:
        try:
            lib = ctypes.CDLL("libaravis-0.8.so.0")
        except OSError as exc:
            raise CameraError(f"libaravis-0.8.so.0 not loadable: {exc}") from exc
        lib.arv_buffer_get_data.restype = ctypes.c_void_p
        lib.arv_buffer_get_data.argtypes = [ctypes.c_void_p, ctypes.POINTER(ctypes.c_size_t)]
        lib.arv_buffer_get_image_width.restype = ctypes.c_int
        lib.arv_buffer_get_image_width.argtypes = [ctypes.c_void_p]
        lib.arv_buffer_get_image_height.restype = ctypes.c_int
        lib.arv_buffer_get_image_height.argtypes = [ctypes.c_void_p]
        lib.arv_fake_camera_set_fill_pattern.restype = None
        lib.arv_fake_camera_set_fill_pattern.argtypes = [ctypes.c_void_p, _FILL_CB, ctypes.c_void_p]
        self.lib = lib
        api = ctypes.pythonapi
        api.PyCapsule_GetPointer.restype = ctypes.c_void_p
        api.PyCapsule_GetPointer.argtypes = [ctypes.py_object, ctypes.c_char_p]
        self.capsule_pointer = api.PyCapsule_GetPointer


class FakeCameraServer:
    """An in-process fake GigE camera on ``address`` serving ``image_source`` pixels.

    Args:
        address: IPv4 address that must exist on an interface (127.0.0.1, or one added in a private namespace).
        serial: serial number; the device id is ``Aravis-Fake-<serial>``.
        image_source: pixels per frame (see module doc); ``ramp_source`` by default.
        lost_packet_ratio: fraction of GVSP packets the camera drops (0..1), for loss tests.
        trigger_poll_hz: how often the fake polls its trigger register (latency ~1/rate).
    """

    def __init__(self, address: str = "127.0.0.1", serial: str = "BRKT0001", *,
                 image_source: ImageSource | None = None, lost_packet_ratio: float = 0.0,
                 trigger_poll_hz: float = 1000.0) -> None:
        self.address = address
        self.serial = serial
        self.image_source: ImageSource = image_source or ramp_source
        self.lost_packet_ratio = lost_packet_ratio
        self.trigger_poll_hz = trigger_poll_hz
        self.served_exposures_us: list[int] = []
        self.fill_errors = 0
        self._lock = threading.Lock()
        self._gv: Any = None

    @property
    def device_id(self) -> str:
        return f"Aravis-Fake-{self.serial}"

    def start(self) -> FakeCameraServer:
        Aravis = load_aravis()
        try:
            gv = Aravis.GvFakeCamera.new(self.address, self.serial)
        except Exception as exc:
            raise CameraError(f"fake camera on {self.address}: {glib_error_message(exc)}") from exc
        if gv is None or not gv.is_running():
            raise CameraError(f"fake camera on {self.address} did not start (is the address on an interface?)")
        if self.lost_packet_ratio:
            gv.set_property("gvsp-lost-ratio", float(self.lost_packet_ratio))
        fake = gv.get_fake_camera()
        fake.set_trigger_frequency(float(self.trigger_poll_hz))
        lib = _Lib()
        pointer = lib.capsule_pointer(fake.__gpointer__, None)
        callback = _FILL_CB(self._fill)
        _KEEP_ALIVE.append(callback)
        lib.lib.arv_fake_camera_set_fill_pattern(pointer, callback, None)
        self._lib = lib.lib
        self._gv = gv
        self._fake = fake
        return self

    def _fill(self, buffer: int, _user: int, exposure_us: int, _gain: int, pixel_format: int) -> None:
        try:
            lib = self._lib
            size = ctypes.c_size_t(0)
            data = lib.arv_buffer_get_data(buffer, ctypes.byref(size))
            width = lib.arv_buffer_get_image_width(buffer)
            height = lib.arv_buffer_get_image_height(buffer)
            image = np.asarray(self.image_source(int(exposure_us), width, height))
            if image.shape != (height, width):
                raise ValueError(f"image_source gave {image.shape}, camera wants {(height, width)}")
            if pixel_format == PIXEL_FORMAT_CODES["Mono16"]:
                raw = np.ascontiguousarray(image, dtype="<u2")
            else:
                raw = np.ascontiguousarray(np.clip(image.astype(np.uint16) >> 4, 0, 255), dtype=np.uint8)
            if data:
                ctypes.memmove(data, raw.ctypes.data, raw.nbytes)
            with self._lock:
                self.served_exposures_us.append(int(exposure_us))
        except Exception:
            with self._lock:
                self.fill_errors += 1
                self.served_exposures_us.append(int(exposure_us))

    def exposures(self) -> list[int]:
        """Exposure (µs) of every frame served so far, in serving order."""
        with self._lock:
            return list(self.served_exposures_us)

    def set_lost_packet_ratio(self, ratio: float) -> None:
        """Change the GVSP packet-loss ratio while running (0..1)."""
        self.lost_packet_ratio = ratio
        if self._gv is not None:
            self._gv.set_property("gvsp-lost-ratio", float(ratio))

    def stop(self) -> None:
        """Drop the camera (its threads end when the object is disposed)."""
        gv, self._gv = self._gv, None
        if gv is not None:
            with contextlib.suppress(Exception):
                gv.run_dispose()
            del gv

    def __enter__(self) -> FakeCameraServer:
        return self.start() if self._gv is None else self

    def __exit__(self, *exc: object) -> None:
        self.stop()
