"""Rig configuration (TOML), validated with errors that name the key and what is wrong.

Example files: ``host/deploy/rig.example.toml`` (the real rig) and ``host/deploy/rig.simulated.toml`` (simulation).
Every key, its type, unit and bounds are declared once below; unknown keys are errors (a typo must not silently fall
back to a default in the field).
"""

from __future__ import annotations

import tomllib
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from bracketry.cameras.profiles import PROFILES, profile_kind
from bracketry.errors import BracketryError
from bracketry.ipv4 import unicast_ipv4
from bracketry.wire import bproto

CAMERA_PROFILES = PROFILES
SIDES = ("left", "right")
TRIGGER_KINDS = ("serial", "simulator", "qemu")
PIXEL_FORMATS = ("BayerRG12p", "BayerRG12", "Mono16", "BayerRG8", "Mono8")
TRIGGER_ACTIVATIONS = ("FallingEdge", "RisingEdge", "LevelLow", "LevelHigh")
#: lowest frame rate the trigger accepts: one pulse per bproto.MAX_PERIOD_US (the wire codec's SET_BRACKETS rule)
MIN_FPS = 1e6 / bproto.MAX_PERIOD_US


class ConfigError(BracketryError):
    """A configuration file is invalid; the message names the file, the key and the problem."""


@dataclass(frozen=True)
class CameraConfig:
    """One GigE camera, opened by its IPv4 ``address`` (cameras are never discovered by broadcast). ``device_id``
    (optional): the id or serial number the camera at that address must report, so swapped cables or a replaced
    camera are caught at start-up instead of recording under the wrong side."""

    side: str
    profile: str
    address: str | None = None
    device_id: str | None = None
    trigger_line: str = "Line3"
    trigger_activation: str = "FallingEdge"
    pixel_format: str = "BayerRG12p"
    packet_size_bytes: int = 9000
    packet_delay_ticks: int = 0


@dataclass(frozen=True)
class TriggerConfig:
    """The STM32 trigger's serial link (``kind`` serial), or a simulated one for ``bracketry simulate``."""

    kind: str = "serial"
    port: str = "/dev/bracketry-trigger"
    baudrate: int = 921600


@dataclass(frozen=True)
class PanelConfig:
    """The ESP32 panel's serial link; ``enabled = false`` runs the rig without a panel."""

    enabled: bool = True
    port: str = "/dev/bracketry-panel"
    baudrate: int = 115200
    refresh_hz: float = 4.0


@dataclass(frozen=True)
class MonitorConfig:
    """The browser monitor (table ``[monitor]``; no table: off). ``listen`` ``HOST:PORT`` (IPv4; anything but
    loopback needs the token); ``preview_hz`` previews per second per camera and bracket; ``bayer`` frames are RGGB
    mosaics (default: the cameras' pixel format says so); ``white_dn`` the sensors' white level (default 4095, 255
    for 8-bit formats)."""

    listen: str = "127.0.0.1:8470"
    preview_hz: float = 1.0
    bayer: bool = True
    white_dn: int = 4095


@dataclass(frozen=True)
class RigConfig:
    """The whole rig. Times in the names' units; ``brackets_us`` is derived from ``brackets_ms``."""

    output_dir: Path
    brackets_ms: tuple[float, ...]
    fps: float
    cameras: tuple[CameraConfig, ...]
    trigger: TriggerConfig = field(default_factory=TriggerConfig)
    panel: PanelConfig = field(default_factory=PanelConfig)
    min_free_mb: int = 2048
    stop_free_mb: int = 512
    split_size_mb: int = 4096
    split_minutes: float = 10.0
    status_socket: Path = Path("/run/bracketry/status.sock")
    source: Path | None = None
    monitor: MonitorConfig | None = None

    @property
    def period_us(self) -> int:
        """Trigger period, microseconds (1e6 / fps, rounded)."""
        return round(1e6 / self.fps)

    @property
    def brackets_us(self) -> tuple[int, ...]:
        """Exposure of each bracket, microseconds."""
        return tuple(round(ms * 1000) for ms in self.brackets_ms)

    def camera(self, side: str) -> CameraConfig:
        """The camera of ``side`` ("left" or "right")."""
        for cam in self.cameras:
            if cam.side == side:
                return cam
        raise KeyError(side)


# key -> (type(s), required) per table
_RIG_KEYS: dict[str, tuple[tuple[type, ...], bool]] = {
    "output_dir": ((str,), True),
    "brackets_ms": ((list,), True),
    "fps": ((int, float), True),
    "min_free_mb": ((int,), False),
    "stop_free_mb": ((int,), False),
    "split_size_mb": ((int,), False),
    "split_minutes": ((int, float), False),
    "status_socket": ((str,), False),
}
_CAMERA_KEYS: dict[str, tuple[tuple[type, ...], bool]] = {
    "side": ((str,), True),
    "profile": ((str,), True),
    "address": ((str,), False),
    "device_id": ((str,), False),
    "trigger_line": ((str,), False),
    "trigger_activation": ((str,), False),
    "pixel_format": ((str,), False),
    "packet_size_bytes": ((int,), False),
    "packet_delay_ticks": ((int,), False),
}
_TRIGGER_KEYS: dict[str, tuple[tuple[type, ...], bool]] = {
    "kind": ((str,), False),
    "port": ((str,), False),
    "baudrate": ((int,), False),
}
_PANEL_KEYS: dict[str, tuple[tuple[type, ...], bool]] = {
    "enabled": ((bool,), False),
    "port": ((str,), False),
    "baudrate": ((int,), False),
    "refresh_hz": ((int, float), False),
}
_MONITOR_KEYS: dict[str, tuple[tuple[type, ...], bool]] = {
    "listen": ((str,), False),
    "preview_hz": ((int, float), False),
    "bayer": ((bool,), False),
    "white_dn": ((int,), False),
}
_TOP_KEYS = {"rig", "trigger", "panel", "cameras", "monitor"}
_BAUDRATES = (9600, 19200, 38400, 57600, 115200, 230400, 460800, 921600, 1000000, 2000000)


def check_brackets_ms(brackets: list[Any], fps: float) -> tuple[str, str] | None:
    """The bracket table rule (the wire codec's, ``bproto``): None when ``brackets`` (ms) is a table the trigger
    accepts at ``fps``; else ``(where, problem)`` for the first problem (``where``: "" or "[i]")."""
    period_us = round(1e6 / fps)
    if not 1 <= len(brackets) <= bproto.MAX_BRACKETS:
        return "", f"must list 1..{bproto.MAX_BRACKETS} exposures, got {len(brackets)}"
    for i, ms in enumerate(brackets):
        if isinstance(ms, bool) or not isinstance(ms, int | float):
            return f"[{i}]", f"must be a number of milliseconds, got {ms!r}"
        if ms * 1000 < bproto.MIN_EXPOSURE_US:
            return f"[{i}]", f"{ms} ms is below the {bproto.MIN_EXPOSURE_US / 1000:.3f} ms minimum exposure"
        if ms * 1000 + bproto.EXPOSURE_MARGIN_US > period_us:
            return (f"[{i}]", f"{ms} ms does not fit the {period_us} us period at {fps:g} fps "
                              f"(needs exposure + {bproto.EXPOSURE_MARGIN_US / 1000:g} ms <= period)")
    if bproto.check_set_brackets(period_us, [round(ms * 1000) for ms in brackets]):  # the codec owns the rule
        return "", (f"the trigger refuses {brackets} ms at a {period_us} us period "
                    "(SET_BRACKETS rule, firmware/protocol/PROTOCOL.md section 3)")
    return None


class _Checker:
    def __init__(self, source: str) -> None:
        self.source = source

    def fail(self, key: str, problem: str) -> None:
        raise ConfigError(f"{self.source}: {key}: {problem}")

    def table(self, data: Any, where: str, spec: dict[str, tuple[tuple[type, ...], bool]]) -> dict[str, Any]:
        if not isinstance(data, dict):
            self.fail(where, f"must be a table, got {type(data).__name__}")
        for key in data:
            if key not in spec:
                known = ", ".join(sorted(spec))
                self.fail(f"{where}.{key}", f"unknown key (known: {known})")
        for key, (types, required) in spec.items():
            if key not in data:
                if required:
                    self.fail(f"{where}.{key}", "missing (required)")
                continue
            value = data[key]
            ok = isinstance(value, types) and not (isinstance(value, bool) and bool not in types)
            if not ok:
                names = " or ".join("number" if t is float else t.__name__ for t in types)
                self.fail(f"{where}.{key}", f"must be {names}, got {type(value).__name__} {value!r}")
        return data


def parse_config(data: dict[str, Any], source: str = "<config>") -> RigConfig:
    """Validate a parsed TOML document and build a :class:`RigConfig`; raises :class:`ConfigError`."""
    c = _Checker(source)
    for key in data:
        if key not in _TOP_KEYS:
            c.fail(key, f"unknown table (known: {', '.join(sorted(_TOP_KEYS))})")
    if "rig" not in data:
        c.fail("rig", "missing table [rig]")
    rig = c.table(data["rig"], "rig", _RIG_KEYS)

    fps = float(rig["fps"])
    if not MIN_FPS <= fps <= 200.0:
        c.fail("rig.fps", f"must be within {MIN_FPS:g}..200 frames per second, got {fps}")
    brackets = rig["brackets_ms"]
    problem = check_brackets_ms(brackets, fps)
    if problem:
        c.fail(f"rig.brackets_ms{problem[0]}", problem[1])
    for key in ("min_free_mb", "stop_free_mb", "split_size_mb"):
        if key in rig and rig[key] < 0:
            c.fail(f"rig.{key}", f"must be >= 0, got {rig[key]}")
    min_free = rig.get("min_free_mb", 2048)
    stop_free = rig.get("stop_free_mb", 512)
    if stop_free > min_free:
        c.fail("rig.stop_free_mb", f"({stop_free}) must not exceed rig.min_free_mb ({min_free})")
    if "split_size_mb" in rig and rig["split_size_mb"] < 16:
        c.fail("rig.split_size_mb", f"must be >= 16 MB, got {rig['split_size_mb']}")
    if "split_minutes" in rig and rig["split_minutes"] <= 0:
        c.fail("rig.split_minutes", f"must be > 0, got {rig['split_minutes']}")

    cams_raw = data.get("cameras")
    if cams_raw is None:
        c.fail("cameras", "missing: declare two [[cameras]] tables (side = \"left\" and \"right\")")
    if not isinstance(cams_raw, list):
        raise ConfigError(f"{source}: cameras: must be an array of tables [[cameras]]")
    cameras = []
    for i, raw in enumerate(cams_raw):
        where = f"cameras[{i}]"
        cam = c.table(raw, where, _CAMERA_KEYS)
        if cam["side"] not in SIDES:
            c.fail(f"{where}.side", f"must be one of {', '.join(SIDES)}, got {cam['side']!r}")
        if cam["profile"] not in CAMERA_PROFILES:
            c.fail(f"{where}.profile", f"must be one of {', '.join(CAMERA_PROFILES)}, got {cam['profile']!r}")
        if "address" not in cam:
            c.fail(where, "needs address (IPv4; cameras are never discovered by broadcast, device_id alone cannot "
                          "open one)")
        if "address" in cam:
            try:
                unicast_ipv4(cam["address"])
            except BracketryError as exc:
                kind = "not a unicast IPv4 address" if "unicast" in str(exc) else "not an IPv4 address"
                c.fail(f"{where}.address", f"{kind}: {cam['address']!r}")
        act = cam.get("trigger_activation", "FallingEdge")
        if act not in TRIGGER_ACTIVATIONS:
            c.fail(f"{where}.trigger_activation", f"must be one of {', '.join(TRIGGER_ACTIVATIONS)}, got {act!r}")
        pf = cam.get("pixel_format", "BayerRG12p")
        if pf not in PIXEL_FORMATS:
            c.fail(f"{where}.pixel_format", f"must be one of {', '.join(PIXEL_FORMATS)}, got {pf!r}")
        ps = cam.get("packet_size_bytes", 9000)
        if not 576 <= ps <= 9216:
            c.fail(f"{where}.packet_size_bytes", f"must be within 576..9216 bytes, got {ps}")
        pd = cam.get("packet_delay_ticks", 0)
        if pd < 0:
            c.fail(f"{where}.packet_delay_ticks", f"must be >= 0, got {pd}")
        cameras.append(CameraConfig(**cam))
    sides = sorted(cam.side for cam in cameras)
    if sides != ["left", "right"]:
        c.fail("cameras", f"need exactly one left and one right camera, got sides {sides}")
    for key in ("address", "device_id"):
        ids = [getattr(cam, key) for cam in cameras if getattr(cam, key)]
        if len(set(ids)) != len(ids):
            c.fail("cameras", f"left and right use the same {key} {ids[0]!r}")
    if len({profile_kind(cam.profile).trigger for cam in cameras if cam.profile in CAMERA_PROFILES}) > 1:
        c.fail("cameras", "one camera is triggered on a line and the other in software: use profiles of one kind")

    trig = c.table(data.get("trigger", {}), "trigger", _TRIGGER_KEYS)
    if trig.get("kind", "serial") not in TRIGGER_KINDS:
        c.fail("trigger.kind", f"must be one of {', '.join(TRIGGER_KINDS)}, got {trig['kind']!r}")
    if "baudrate" in trig and trig["baudrate"] not in _BAUDRATES:
        c.fail("trigger.baudrate", f"unsupported baud rate {trig['baudrate']}")
    panel = c.table(data.get("panel", {}), "panel", _PANEL_KEYS)
    if "baudrate" in panel and panel["baudrate"] not in _BAUDRATES:
        c.fail("panel.baudrate", f"unsupported baud rate {panel['baudrate']}")
    if "refresh_hz" in panel and not 2.0 <= panel["refresh_hz"] <= 5.0:
        c.fail("panel.refresh_hz", f"must be within 2..5 Hz (the panel's host heartbeat), got {panel['refresh_hz']}")
    if trig.get("port") and panel.get("enabled", True) and trig.get("port") == panel.get("port"):
        c.fail("panel.port", f"same serial port as trigger.port ({trig['port']})")

    monitor = None
    if "monitor" in data:
        mon = c.table(data["monitor"], "monitor", _MONITOR_KEYS)
        from bracketry.monitor.address import parse_listen

        try:
            parse_listen(mon.get("listen", "127.0.0.1:8470"))
        except ValueError as exc:
            c.fail("monitor.listen", str(exc))
        if "preview_hz" in mon and not 0.1 <= mon["preview_hz"] <= 5.0:
            c.fail("monitor.preview_hz", f"must be within 0.1..5 per second, got {mon['preview_hz']}")
        eight_bit = all(cam.pixel_format.endswith("8") for cam in cameras)
        if "white_dn" in mon and not 1 <= mon["white_dn"] <= 65535:
            c.fail("monitor.white_dn", f"must be within 1..65535, got {mon['white_dn']}")
        monitor = MonitorConfig(listen=mon.get("listen", "127.0.0.1:8470"),
                                preview_hz=float(mon.get("preview_hz", 1.0)),
                                bayer=mon.get("bayer", all(cam.pixel_format.startswith("Bayer") for cam in cameras)),
                                white_dn=mon.get("white_dn", 255 if eight_bit else 4095))

    return RigConfig(
        output_dir=Path(rig["output_dir"]).expanduser(),
        brackets_ms=tuple(float(x) for x in brackets),
        fps=fps,
        cameras=tuple(sorted(cameras, key=lambda cam: SIDES.index(cam.side))),
        trigger=TriggerConfig(**trig),
        panel=PanelConfig(**panel),
        min_free_mb=min_free,
        stop_free_mb=stop_free,
        split_size_mb=rig.get("split_size_mb", 4096),
        split_minutes=float(rig.get("split_minutes", 10.0)),
        status_socket=Path(rig.get("status_socket", "/run/bracketry/status.sock")),
        source=Path(source) if source != "<config>" else None,
        monitor=monitor,
    )


def load_config(path: str | Path) -> RigConfig:
    """Read and validate a rig TOML file; every problem is a one-line :class:`ConfigError`."""
    p = Path(path)
    try:
        text = p.read_text(encoding="utf-8")
    except FileNotFoundError:
        raise ConfigError(f"{p}: no such config file") from None
    except (OSError, UnicodeDecodeError) as exc:
        raise ConfigError(f"{p}: cannot read: {exc}") from None
    try:
        data = tomllib.loads(text)
    except tomllib.TOMLDecodeError as exc:
        raise ConfigError(f"{p}: not valid TOML: {exc}") from None
    return parse_config(data, str(p))
