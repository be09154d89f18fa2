"""A fake GigE Vision camera served from this process: ``Aravis.GvFakeCamera`` with our own pixels.

The camera is a real GVCP/GVSP server on ``address`` (UDP 3956 fixed per IP, so one camera per loopback address:
127.0.0.1, or 127.0.0.2/.3 inside a private network namespace, see ``bracketry_rig.cameras.netns``). Clients open it by
IP with ``GigECamera`` exactly as a real camera.

Pixels come from ``image_source(exposure_us, width, height) -> uint16 (height, width)`` called for each frame in the
fake camera's thread with the exposure the camera had when the frame was triggered (its ExposureTimeAbs). They are
written through the C function ``arv_fake_camera_set_fill_pattern`` via ctypes (the PyGObject binding of that callback
crashes). Mono16 carries 12-bit codes unchanged (the fake has no BayerRG12 pixels); 8-bit formats get ``code >> 4``.
Each served frame's exposure is recorded in ``served_exposures_us`` (in serving order) so tests can read it.

Deterministic where the Aravis fake is not: a ``bracketry_rig.cameras.fake_relay.FakeCameraRelay`` owns the camera's
public GVCP port. At start the fake's own GVCP socket (bound to ``address``:3956) is replaced, under its file
descriptor, by one on an ephemeral port of the same address, and the relay binds ``address``:3956 in front of it; so
any address works (127.0.0.1 in the host namespace too). Through the relay:

- each frame is stamped with its trigger's time (kernel receive time of the TriggerSoftware write, host real time)
  and rendered with the exposure the camera had at the trigger, not at the fill (the fake fills at its next poll);
- a trigger arriving before the previous one was filled is held until it was, so triggers never merge;
- a trigger the fake never filled is counted (``relay.triggers_lost``, read by clients in ``REG_TRIGGERS_LOST``);
- GVSP packet loss is decided per packet by ``fake_relay.packet_lost(seed, serial, block_id, packet_id, ratio)``
  (the fake's own ``gvsp-lost-ratio``, from GLib's global unseeded RNG, stays 0): same seed, same lost packets.

The fake itself still polls its trigger flag at ``trigger_poll_hz`` (its thread spins during the last < 1 ms of each
poll period while acquiring: ~1 ms / period of a core, see ``DEFAULT_TRIGGER_POLL_HZ``); only the fill latency
depends on it, not stamps, exposures or merging.

Quirk of the Aravis 0.8.26 fake, handled by its users: the first TriggerSoftware after AcquisitionStart is often
lost (``bracketry_rig.cameras.triggering.SoftwareTrigger.arm`` fires a marked priming trigger first); its timestamps are
host time (``Pairer(initial_alignment="host_time")``).
"""

from __future__ import annotations

import contextlib
import ctypes
import os
import socket
import threading
from collections.abc import Callable
from typing import Any

import numpy as np

from bracketry_rig.cameras.aravis_gi import CameraError, glib_error_message, load_aravis
from bracketry_rig.cameras.fake_relay import GVCP_PORT, REG_TRIGGER_MODE, REG_TRIGGER_SOURCE, FakeCameraRelay
from bracketry_rig.cameras.pixels import PIXEL_FORMAT_CODES

ImageSource = Callable[[int, int, int], np.ndarray]

_FILL_CB = ctypes.CFUNCTYPE(None, ctypes.c_void_p, ctypes.c_void_p, ctypes.c_uint32, ctypes.c_uint32, ctypes.c_uint32)
#: ctypes callbacks must outlive the camera threads that call them; never freed (a few bytes per camera).
_KEEP_ALIVE: list[Any] = []
#: the fake's trigger poll rate: a frame is filled within one period (+ the fill) after its trigger, well inside
#: the rig's 45 ms pulse period at 22 fps (so triggers are normally never held). While acquiring, the fake's thread
#: spins the last < 1 ms of every period (its g_poll timeout is in whole ms): ~1 ms/period of a core. Measured, one
#: fake acquiring without triggers, machine load ~12 on 2 cores (so CPU% is what it got, runnable% = on CPU + waiting
#: for one): 1000 Hz 20-21 % CPU / 58-65 % runnable; 100 Hz 4-5 % / 17-21 %; 50 Hz 2 % / 6 %; not
#: acquiring: 0 % at any rate. The relay's thread blocks in select (0 % idle).
DEFAULT_TRIGGER_POLL_HZ = 100.0
#: default seed of the relay's packet loss
DEFAULT_SEED = 29


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
        lib.arv_buffer_set_timestamp.restype = None
        lib.arv_buffer_set_timestamp.argtypes = [ctypes.c_void_p, ctypes.c_uint64]
        lib.arv_buffer_get_frame_id.restype = ctypes.c_uint64
        lib.arv_buffer_get_frame_id.argtypes = [ctypes.c_void_p]
        lib.arv_fake_camera_set_fill_pattern.restype = None
        lib.arv_fake_camera_set_fill_pattern.argtypes = [ctypes.c_void_p, _FILL_CB, ctypes.c_void_p]
        self.lib = lib
        api = ctypes.pythonapi
        api.PyCapsule_GetPointer.restype = ctypes.c_void_p
        api.PyCapsule_GetPointer.argtypes = [ctypes.py_object, ctypes.c_char_p]
        self.capsule_pointer = api.PyCapsule_GetPointer


def _move_gvcp_socket(address: str) -> tuple[str, int]:
    """Give the fake's GVCP socket (this process's UDP socket bound to ``address``:3956) a new socket bound to an
    ephemeral port of ``address``, under the same file descriptor (``dup2``), and free ``address``:3956 for the
    relay. Returns the new socket's address."""
    target = None
    for name in os.listdir("/proc/self/fd"):
        try:
            if not os.readlink(f"/proc/self/fd/{name}").startswith("socket:"):
                continue
            probe = socket.socket(fileno=os.dup(int(name)))
        except OSError:
            continue
        with probe, contextlib.suppress(OSError):
            if (probe.family == socket.AF_INET and probe.type == socket.SOCK_DGRAM
                    and probe.getsockname() == (address, GVCP_PORT)):
                target = int(name)
        if target is not None:
            break
    if target is None:
        raise CameraError(f"fake camera on {address}: its GVCP socket was not found")
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as new:
        new.bind((address, 0))
        new.setblocking(False)  # as GSocket keeps its descriptors
        moved = new.getsockname()
        os.dup2(new.fileno(), target, inheritable=False)
    # the fake's thread may sit in g_poll on the old socket (<= 100 ms): one datagram wakes it, so it lets go
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as wake:
        wake.sendto(bytes(8), (address, GVCP_PORT))
    return str(moved[0]), int(moved[1])


class FakeCameraServer:
    """An in-process fake GigE camera on ``address`` serving ``image_source`` pixels.

    Args:
        address: IPv4 address that must exist on an interface (127.0.0.1, or one added in a private namespace).
        serial: serial number; the device id is ``Aravis-Fake-<serial>``.
        image_source: pixels per frame (see module doc); ``ramp_source`` by default.
        lost_packet_ratio: fraction of GVSP packets lost (0..1), for loss tests; which ones is fixed by ``seed``.
        trigger_poll_hz: how often the fake polls its trigger flag (fill latency <= 1/rate + the fill).
        seed: seed of the packet loss (same seed, serial and frames: the same packets lost).
    """

    def __init__(self, address: str = "127.0.0.1", serial: str = "BRKT0001", *,
                 image_source: ImageSource | None = None, lost_packet_ratio: float = 0.0,
                 trigger_poll_hz: float = DEFAULT_TRIGGER_POLL_HZ, seed: int = DEFAULT_SEED) -> None:
        self.address = address
        self.serial = serial
        self.image_source: ImageSource = image_source or ramp_source
        self.lost_packet_ratio = lost_packet_ratio
        self.trigger_poll_hz = trigger_poll_hz
        self.seed = seed
        self.served_exposures_us: list[int] = []
        #: (frame id, timestamp ns, exposure µs) of every served frame, in serving order
        self.served_frames: list[tuple[int, int, int]] = []
        self.fill_errors = 0
        self._lock = threading.Lock()
        self._gv: Any = None
        self.relay: FakeCameraRelay | None = None

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
        try:
            moved = _move_gvcp_socket(self.address)
            self.relay = FakeCameraRelay(self.address, moved, self._read_register, serial=self.serial,
                                         seed=self.seed, lost_ratio=self.lost_packet_ratio).start()
        except (OSError, CameraError) as exc:
            self.stop()
            raise CameraError(f"fake camera on {self.address}: relay: {exc}") from exc
        return self

    def _read_register(self, address: int) -> int:
        ok, value = self._fake.read_register(address)
        return int(value) if ok else 0

    def _fill(self, buffer: int, _user: int, exposure_us: int, _gain: int, pixel_format: int) -> None:
        relay = self.relay
        try:
            self._fill_frame(relay, buffer, exposure_us, pixel_format)
        finally:
            if relay is not None:
                relay.fill_done()

    def _software_triggered(self) -> bool:
        """The fake acquires in software-trigger mode (its frames are filled for triggers only)."""
        return bool(self._read_register(REG_TRIGGER_MODE) == 1 and self._read_register(REG_TRIGGER_SOURCE) == 1)

    def _fill_frame(self, relay: FakeCameraRelay | None, buffer: int, exposure_us: int, pixel_format: int) -> None:
        trigger = relay.take_trigger(self._software_triggered()) if relay is not None else None
        lib = self._lib
        if trigger is not None:  # stamped and exposed at its trigger, not now
            exposure_us = trigger.exposure_us
            lib.arv_buffer_set_timestamp(buffer, trigger.t_ns)
        try:
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
        except Exception:
            with self._lock:
                self.fill_errors += 1
        with self._lock:
            self.served_exposures_us.append(int(exposure_us))
            self.served_frames.append((int(lib.arv_buffer_get_frame_id(buffer)),
                                       int(trigger.t_ns) if trigger is not None else 0, int(exposure_us)))

    def exposures(self) -> list[int]:
        """Exposure (µs) of every frame served so far, in serving order."""
        with self._lock:
            return list(self.served_exposures_us)

    def frames(self) -> list[tuple[int, int, int]]:
        """(frame id, trigger time ns or 0 for a frame not triggered through the relay, exposure µs) of every frame
        served so far, in serving order."""
        with self._lock:
            return list(self.served_frames)

    def set_lost_packet_ratio(self, ratio: float) -> None:
        """Change the GVSP packet-loss ratio (0..1): it applies to streams started after it (see ``fake_relay``)."""
        self.lost_packet_ratio = ratio
        if self.relay is not None:
            self.relay.lost_ratio = float(ratio)

    def stop(self) -> None:
        """Drop the camera (its thread ends when the object is disposed), then its relay."""
        gv, self._gv = self._gv, None
        if gv is not None:
            with contextlib.suppress(Exception):
                gv.run_dispose()
            del gv
        relay, self.relay = self.relay, None
        if relay is not None:
            relay.stop()

    def __enter__(self) -> FakeCameraServer:
        return self.start() if self._gv is None else self

    def __exit__(self, *exc: object) -> None:
        self.stop()
