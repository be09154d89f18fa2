"""An event-driven UDP relay in front of an in-process Aravis fake camera: triggers stamped, exposures latched, GVSP
packet loss seeded.

``FakeCameraServer`` puts one in front of each ``Aravis.GvFakeCamera``. The relay owns the camera's public GVCP port
(``address``:3956); the fake's own GVCP socket is moved to an ephemeral port of the same address (see
``FakeCameraServer``). Every client (one GVCP socket: a process's ``ArvGvDevice``) gets its own upstream socket, so
the fake still tells controllers apart (control privilege, heartbeat take-over work as on the bare fake).

What the relay adds to the fake's behaviour:

- **Trigger time and exposure.** A WRITEREG of TriggerSoftware=1 is a trigger: its time is the kernel's receive time
  of the packet on the relay's socket (``SO_TIMESTAMPNS``, host real time in ns; ``time.time_ns()`` when the kernel
  gives none) and its exposure the fake's ExposureTime register then (the client got the ack of every earlier write
  before it sent the trigger). The fake polls its trigger flag and fills the frame later; the fill takes the trigger
  (``take_trigger``) and stamps and renders the frame with it.
- **No merged triggers.** The fake has one trigger flag: a trigger that arrives while the previous one is not filled
  yet is held (its ack is the fake's, so the client waits) and forwarded when the fill takes the previous one. So two
  triggers never merge into one frame, whatever the fake's poll rate or the machine's load. A trigger the fake never
  fills (e.g. written by a client without control) is dropped after ``trigger_expiry_s``; one still unfilled when a
  new acquisition starts (the last trigger before an AcquisitionStop that came first) is dropped then, so it never
  holds the new acquisition's triggers (the camera would deliver nothing for ``trigger_expiry_s``: 2 s, the daemon's
  stall limit).
- **Lost triggers counted.** A trigger forwarded to the fake waits for the fill in progress, however long it lasts
  (its expiry counts only from the end of that fill, ``fill_done``): a fill lasting seconds (a starved host, frames
  not yet rendered) neither expires the trigger behind it nor lets the next one merge with it. A trigger the fake
  never fills (expired, or dropped when a new acquisition starts) is counted in ``triggers_lost`` (a fill no trigger
  of the relay's was waiting for, whose frame carries the fake's own stamp, in ``fills_untriggered``); a client reads
  ``triggers_lost`` in the
  camera's register ``REG_TRIGGERS_LOST`` (the relay answers it; the ``aravis_fake`` profile names it), so a lost
  software trigger reaches the recording as its own kind (``RigStatus.lost_triggers_*``, ``bracketry verify``),
  never as a silent drop.
- **Seeded packet loss.** When a loss ratio is set (> 0 when the client writes the stream destination), the client's
  stream destination writes (SCDA 0x0D18, SCP 0x0D00 port bits) are rewritten so the fake streams to the relay
  (read-backs show the client's values); the relay forwards each GVSP packet to the client unless
  ``packet_lost(seed, serial, block_id, packet_id, ratio)`` says it is lost: a hash, so the same seed loses the same
  packets of the same frames in every run, independent of the other cameras and of timing. Without loss the fake
  streams straight to the client, as a camera does: no Python thread (and so no scheduling delay on a loaded host)
  lies on the frames' path. Set the ratio before the stream starts.

Triggers written while the fake is not acquiring in software-trigger mode are forwarded unrecorded (the fake fills
them, if ever, at its next acquisition; such a frame keeps the fake's own stamp and exposure).
"""

from __future__ import annotations

import contextlib
import hashlib
import logging
import selectors
import socket
import struct
import threading
import time
import zlib
from collections import deque
from collections.abc import Callable
from dataclasses import dataclass

from bracketry_rig.cameras.profiles import FAKE_LOST_TRIGGERS_REGISTER
from bracketry_rig.cameras.triggering import PRIMING_EXPOSURE_US

log = logging.getLogger(__name__)

GVCP_PORT = 3956
CMD_READREG, ACK_READREG, CMD_WRITEREG, ACK_WRITEREG = 0x0080, 0x0081, 0x0082, 0x0083
#: GigE Vision bootstrap registers of stream channel 0: port (host port in the low 16 bits), destination address
REG_SCP, REG_SCDA = 0x0D00, 0x0D18
#: the Aravis fake camera's registers (arvfakecamera.h; the same addresses in its GenICam XML)
REG_EXPOSURE_US, REG_ACQUISITION, REG_TRIGGER_MODE, REG_TRIGGER_SOURCE, REG_TRIGGER_SOFTWARE = (
    0x120, 0x124, 0x300, 0x304, 0x30C)
#: the relay's own register: software triggers the fake camera lost (``FakeCameraRelay.triggers_lost``), read-only. In
#: the fake's memory (0x10000 bytes, arvfakecamera.h) but named by none of its features, so a read reaches the fake and
#: the relay puts its count into the answer.
REG_TRIGGERS_LOST = FAKE_LOST_TRIGGERS_REGISTER
_SO_TIMESTAMPNS = getattr(socket, "SO_TIMESTAMPNS", 35)  # Linux; not exported by every Python build
_MAX_CLIENTS = 32


def packet_lost(seed: int, serial: str, block_id: int, packet_id: int, ratio: float) -> bool:
    """Whether GVSP packet ``packet_id`` of frame ``block_id`` of camera ``serial`` is lost at ``ratio`` (0..1):
    a pure function of its arguments (blake2b of seed, CRC-32 of the serial, block id, packet id)."""
    if ratio <= 0.0:
        return False
    key = struct.pack("<QIII", seed & 0xFFFF_FFFF_FFFF_FFFF, zlib.crc32(serial.encode()), block_id, packet_id)
    u = int.from_bytes(hashlib.blake2b(key, digest_size=8).digest(), "little") / 2.0**64
    return u < ratio


@dataclass(frozen=True)
class Trigger:
    """A software trigger as the camera saw it: receive time (host real time, ns) and the exposure then (µs)."""

    t_ns: int
    exposure_us: int


@dataclass
class _Forwarded:
    trigger: Trigger
    at_s: float  # monotonic time it was forwarded to the fake


def _registers(packet: bytes) -> list[tuple[int, int]]:
    """(address, value) pairs of a WRITEREG command."""
    n = (len(packet) - 8) // 8
    return [struct.unpack_from(">II", packet, 8 + 8 * i) for i in range(n)]


class FakeCameraRelay:
    """The relay of one fake camera (see module doc).

    Args:
        address: the camera's public address (the relay binds ``address``:3956 and its GVSP socket there).
        fake_gvcp: where the fake's GVCP socket now listens (address, port).
        read_register: reads one of the fake's registers (its ``read_register``), thread-safe.
        serial, seed, lost_ratio: the packet-loss rule (``packet_lost``).
        trigger_expiry_s: a forwarded trigger the fake, not filling, left unfilled this long is dropped and counted
            lost (the fake rejected it).
        clock_s: the relay's monotonic clock in seconds (tests inject one).
    """

    def __init__(self, address: str, fake_gvcp: tuple[str, int], read_register: Callable[[int], int], *,
                 serial: str, seed: int, lost_ratio: float = 0.0, trigger_expiry_s: float = 2.0,
                 clock_s: Callable[[], float] = time.monotonic) -> None:
        self._clock_s = clock_s
        self.address = address
        self.fake_gvcp = fake_gvcp
        self.read_register = read_register
        self.serial = serial
        self.seed = seed
        self.lost_ratio = lost_ratio
        self.trigger_expiry_s = trigger_expiry_s
        #: (block_id, packet_id) of every GVSP packet dropped, in order (tests compare runs with it)
        self.dropped: list[tuple[int, int]] = []
        self.triggers_held = 0
        self.triggers_expired = 0
        #: triggers still unfilled when the next acquisition started, dropped then (module docstring)
        self.triggers_dropped_at_start = 0
        #: fills of an acquisition in software-trigger mode that found no trigger of the relay's waiting
        self.fills_untriggered = 0
        self._lock = threading.Lock()
        self._outstanding: _Forwarded | None = None  # forwarded to the fake, not filled yet (at most one)
        self._filling = False  # a fill is in progress (between take_trigger and fill_done)
        self._lost = 0  # see triggers_lost
        self._held: deque[tuple[socket.socket, bytes, Trigger]] = deque()
        self._recent_triggers: deque[tuple[tuple[str, int], int]] = deque(maxlen=64)  # (client, req_id)
        self._reads: dict[tuple[tuple[str, int], int], list[int]] = {}  # pending READREG: addresses
        self._client_scda: bytes | None = None
        self._client_scp: int | None = None
        self._stream_dest: tuple[str, int] | None = None
        self._upstream: dict[tuple[str, int], socket.socket] = {}  # client -> its upstream socket (LRU order)
        self._client_of: dict[int, tuple[str, int]] = {}  # upstream fd -> client
        self._sel = selectors.DefaultSelector()
        self._thread: threading.Thread | None = None
        self._stopping = False
        self._public: socket.socket | None = None
        self._gvsp: socket.socket | None = None
        self._wake_r, self._wake_w = socket.socketpair()

    # ------------------------------------------------------------------------------------------------ life cycle
    def start(self, bind_timeout_s: float = 2.0) -> FakeCameraRelay:
        public = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        public.setsockopt(socket.SOL_SOCKET, _SO_TIMESTAMPNS, 1)
        deadline = time.monotonic() + bind_timeout_s
        while True:  # the fake's old GVCP socket is released when its thread's current poll returns (<= 100 ms)
            try:
                public.bind((self.address, GVCP_PORT))
                break
            except OSError:
                if time.monotonic() > deadline:
                    public.close()
                    raise
                time.sleep(0.01)
        gvsp = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        gvsp.bind((self.address, 0))
        gvsp.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, 4 << 20)
        for s in (public, gvsp, self._wake_r):
            s.setblocking(False)
        self._public, self._gvsp = public, gvsp
        self._sel.register(public, selectors.EVENT_READ, self._on_client)
        self._sel.register(gvsp, selectors.EVENT_READ, self._on_gvsp)
        self._sel.register(self._wake_r, selectors.EVENT_READ, None)
        self._thread = threading.Thread(target=self._run, name=f"fake-relay-{self.serial}", daemon=True)
        self._thread.start()
        return self

    def stop(self) -> None:
        self._stopping = True
        with contextlib.suppress(OSError):
            self._wake_w.send(b"x")
        if self._thread is not None:
            self._thread.join(5.0)
        for key in list(self._sel.get_map().values()):
            key.fileobj.close()  # type: ignore[union-attr]
        self._sel.close()
        self._wake_w.close()

    @property
    def stream_port(self) -> int:
        assert self._gvsp is not None
        return int(self._gvsp.getsockname()[1])

    @property
    def triggers_lost(self) -> int:
        """Software triggers of pulses the fake never filled (expired, or dropped at a new acquisition); the priming
        trigger (``PRIMING_EXPOSURE_US``, fired only to absorb the fake's loss of the first trigger of an
        acquisition) is not counted."""
        with self._lock:
            return self._lost

    def _lose(self, fwd: _Forwarded) -> None:  # lock held
        if fwd.trigger.exposure_us != PRIMING_EXPOSURE_US:
            self._lost += 1

    # ------------------------------------------------------------------------------------------------ the fill side
    def take_trigger(self, software_triggered: bool = False) -> Trigger | None:
        """Called by the fake's fill (its thread) as it starts: the trigger this frame is for (None: a frame not
        triggered through the relay; counted lost when ``software_triggered``, the fake acquiring in software-trigger
        mode). Forwards the next held trigger, if any; it waits for :meth:`fill_done` before it can expire."""
        with self._lock:
            fwd, self._outstanding = self._outstanding, None
            self._filling = True
            if fwd is None and software_triggered:
                self.fills_untriggered += 1
                log.warning("fake camera %s: a frame filled for no trigger of the relay's (a lost trigger)",
                            self.serial)
            self._release_held()
        return fwd.trigger if fwd is not None else None

    def fill_done(self) -> None:
        """Called by the fake's fill as it ends: a trigger forwarded during the fill waited for it, its expiry counts
        from now."""
        with self._lock:
            self._filling = False
            if self._outstanding is not None:
                self._outstanding = _Forwarded(self._outstanding.trigger, self._clock_s())
        with contextlib.suppress(OSError):
            self._wake_w.send(b"f")  # the loop's expiry timeout starts over

    def _release_held(self) -> None:  # lock held
        if self._held and self._outstanding is None:
            upstream, packet, trigger = self._held.popleft()
            self._outstanding = _Forwarded(trigger, self._clock_s())
            with contextlib.suppress(OSError):
                upstream.send(packet)

    # ------------------------------------------------------------------------------------------------ the loop
    def _run(self) -> None:
        while not self._stopping:
            timeout = None
            with self._lock:
                if self._outstanding is not None and not self._filling:
                    timeout = max(0.0, self._outstanding.at_s + self.trigger_expiry_s - self._clock_s())
            for key, _ in self._sel.select(timeout):
                if key.data is None:
                    with contextlib.suppress(OSError):
                        self._wake_r.recv(64)
                    continue
                try:
                    key.data(key.fileobj)
                except OSError as exc:  # e.g. ECONNREFUSED from the fake's port while it stops
                    log.debug("fake relay %s: %s", self.serial, exc)
            self.expire(self._clock_s())

    def expire(self, now_s: float) -> bool:
        """Drop the forwarded trigger if the fake, not filling, left it unfilled for ``trigger_expiry_s`` up to
        ``now_s`` (the relay's clock): it is lost (counted), the next held one is forwarded. True when dropped."""
        with self._lock:
            fwd = self._outstanding
            if fwd is None or self._filling or now_s - fwd.at_s <= self.trigger_expiry_s:
                return False
            self.triggers_expired += 1
            self._lose(fwd)
            log.warning("fake camera %s: trigger of %d ns not filled within %.1f s: lost", self.serial,
                        fwd.trigger.t_ns, self.trigger_expiry_s)
            self._outstanding = None
            self._release_held()
            return True

    def _upstream_for(self, client: tuple[str, int]) -> socket.socket:
        up = self._upstream.pop(client, None)
        if up is None:
            if len(self._upstream) >= _MAX_CLIENTS:
                old_client, old = next(iter(self._upstream.items()))
                del self._upstream[old_client]
                self._client_of.pop(old.fileno(), None)
                self._sel.unregister(old)
                old.close()
            up = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
            up.bind((self.address, 0))
            up.connect(self.fake_gvcp)
            up.setblocking(False)
            self._client_of[up.fileno()] = client
            self._sel.register(up, selectors.EVENT_READ, self._on_fake)
        self._upstream[client] = up  # most recently used last
        return up

    def _on_client(self, sock: socket.socket) -> None:
        while True:
            try:
                packet, anc, _flags, client = sock.recvmsg(4096, socket.CMSG_SPACE(16))
            except BlockingIOError:
                return
            t_ns = time.time_ns()
            for level, kind, data in anc:
                if level == socket.SOL_SOCKET and kind == _SO_TIMESTAMPNS and len(data) >= 16:
                    sec, nsec = struct.unpack_from("qq", data)
                    t_ns = sec * 1_000_000_000 + nsec
            self._from_client(client, packet, t_ns)

    def _from_client(self, client: tuple[str, int], packet: bytes, t_ns: int) -> None:
        up = self._upstream_for(client)
        if len(packet) < 8 or packet[0] != 0x42:
            up.send(packet)
            return
        command, req_id = struct.unpack_from(">H2xH", packet, 2)
        if command == CMD_READREG:
            n = (len(packet) - 8) // 4
            self._reads[(client, req_id)] = [struct.unpack_from(">I", packet, 8 + 4 * i)[0] for i in range(n)]
            if len(self._reads) > 256:
                self._reads.pop(next(iter(self._reads)))
        elif command == CMD_WRITEREG:
            regs = _registers(packet)
            if any(a in (REG_SCP, REG_SCDA) for a, _ in regs):
                if self.lost_ratio > 0.0:
                    packet = self._rewrite_stream_destination(packet, regs)
                else:  # no loss asked for: the fake streams straight to the client, no Python on the frames' path
                    self._client_scda = self._client_scp = None
                    self._stream_dest = None
            if (REG_TRIGGER_SOFTWARE, 1) in regs and self._trigger(client, req_id, up, packet, t_ns):
                return
            if (REG_ACQUISITION, 1) in regs:
                up.send(packet)
                self._acquisition_started()
                return
        up.send(packet)

    def _acquisition_started(self) -> None:
        """AcquisitionStart was forwarded: a trigger forwarded before it and never filled is not this acquisition's;
        drop it and forward the next held one (module docstring)."""
        with self._lock:
            if self._outstanding is not None:
                self.triggers_dropped_at_start += 1
                self._lose(self._outstanding)
                self._outstanding = None
                self._release_held()

    def _rewrite_stream_destination(self, packet: bytes, regs: list[tuple[int, int]]) -> bytes:
        out = bytearray(packet)
        relay_ip = struct.unpack(">I", socket.inet_aton(self.address))[0]
        for i, (addr, value) in enumerate(regs):
            if addr == REG_SCDA:
                self._client_scda = struct.pack(">I", value)
                struct.pack_into(">I", out, 12 + 8 * i, relay_ip)
            elif addr == REG_SCP:
                self._client_scp = value
                struct.pack_into(">I", out, 12 + 8 * i, (value & 0xFFFF0000) | self.stream_port)
        if self._client_scda is not None and self._client_scp is not None:
            self._stream_dest = (socket.inet_ntoa(self._client_scda), self._client_scp & 0xFFFF)
        return bytes(out)

    def _trigger(self, client: tuple[str, int], req_id: int, up: socket.socket, packet: bytes, t_ns: int) -> bool:
        """Record a trigger; True when it is held (or a duplicate), so not forwarded now."""
        if (client, req_id) in self._recent_triggers:
            return True  # a retransmission: the fake has (or will have) the original, whose ack answers it
        if not (self.read_register(REG_ACQUISITION) and self.read_register(REG_TRIGGER_MODE) == 1
                and self.read_register(REG_TRIGGER_SOURCE) == 1):
            return False  # not acquiring in software-trigger mode: the fake's own behaviour
        self._recent_triggers.append((client, req_id))
        trigger = Trigger(t_ns, int(self.read_register(REG_EXPOSURE_US)))
        with self._lock:
            if self._outstanding is None:
                self._outstanding = _Forwarded(trigger, self._clock_s())
                return False
            self._held.append((up, packet, trigger))
            self.triggers_held += 1
            return True

    def _on_fake(self, up: socket.socket) -> None:
        client = self._client_of.get(up.fileno())
        while True:
            try:
                packet = up.recv(65536)
            except BlockingIOError:
                return
            if client is None or self._public is None:
                continue
            if len(packet) >= 8 and struct.unpack_from(">H", packet, 2)[0] == ACK_READREG:
                addresses = self._reads.pop((client, struct.unpack_from(">H", packet, 6)[0]), None)
                if addresses:
                    packet = self._rewrite_read_ack(packet, addresses)
            self._public.sendto(packet, client)

    def _rewrite_read_ack(self, packet: bytes, addresses: list[int]) -> bytes:
        out = bytearray(packet)
        for i, addr in enumerate(addresses):
            if 8 + 4 * i + 4 > len(out):
                break
            if addr == REG_TRIGGERS_LOST:
                struct.pack_into(">I", out, 8 + 4 * i, self.triggers_lost & 0xFFFF_FFFF)
            elif addr == REG_SCDA and self._client_scda is not None:
                out[8 + 4 * i:12 + 4 * i] = self._client_scda
            elif addr == REG_SCP and self._client_scp is not None:
                value = struct.unpack_from(">I", out, 8 + 4 * i)[0]
                struct.pack_into(">I", out, 8 + 4 * i, (value & 0xFFFF0000) | (self._client_scp & 0xFFFF))
        return bytes(out)

    def _on_gvsp(self, sock: socket.socket) -> None:
        while True:
            try:
                packet = sock.recv(65536)
            except BlockingIOError:
                return
            dest = self._stream_dest
            if dest is None or len(packet) < 8:
                continue
            ratio = self.lost_ratio
            if ratio > 0.0:
                block_id = struct.unpack_from(">H", packet, 2)[0]
                packet_id = struct.unpack_from(">I", packet, 4)[0] & 0xFFFFFF
                if packet_lost(self.seed, self.serial, block_id, packet_id, ratio):
                    self.dropped.append((block_id, packet_id))
                    continue
            with contextlib.suppress(OSError):
                sock.sendto(packet, dest)
