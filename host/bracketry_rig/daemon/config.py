"""Rig configuration (TOML), validated with errors that name the key and what is wrong.

The dataclasses below are the one field table: each key is declared once with its type, default, choices or range
and help (``config_schema.setting``); the checker and the documented example ``host/deploy/rig.example.toml``
(``python -m bracketry_rig.daemon.config > host/deploy/rig.example.toml``) are derived from them. ``parse_config`` adds
only the rules that span keys. Unknown keys are errors (a typo must not silently fall back to a default in the
field). ``host/deploy/rig.simulated.toml`` configures the simulated rig.
"""

from __future__ import annotations

import tomllib
from pathlib import Path
from typing import Any

from bracketry_base.errors import BracketryError
from bracketry_base.ipv4 import unicast_ipv4
from bracketry_rig.cameras.profiles import PROFILES, profile_kind
from bracketry_rig.daemon.config_schema import Checker, config_table, example_toml, setting, table, tables
from bracketry_rig.wire import bproto

CAMERA_PROFILES = PROFILES
SIDES = ("left", "right")
TRIGGER_KINDS = ("serial", "simulator", "qemu")
PIXEL_FORMATS = ("BayerRG12p", "BayerRG12", "Mono16", "BayerRG8", "Mono8")
TRIGGER_ACTIVATIONS = ("FallingEdge", "RisingEdge", "LevelLow", "LevelHigh")
BAUDRATES = (9600, 19200, 38400, 57600, 115200, 230400, 460800, 921600, 1000000, 2000000)
#: lowest frame rate the trigger accepts: one pulse per bproto.MAX_PERIOD_US (the wire codec's SET_BRACKETS rule)
MIN_FPS = 1e6 / bproto.MAX_PERIOD_US


class ConfigError(BracketryError):
    """A configuration file is invalid; the message names the file, the key and the problem."""


def _bracket_items(brackets: list[Any]) -> tuple[str, str] | None:
    if not 1 <= len(brackets) <= bproto.MAX_BRACKETS:
        return "", f"must list 1..{bproto.MAX_BRACKETS} exposures, got {len(brackets)}"
    for i, ms in enumerate(brackets):
        if isinstance(ms, bool) or not isinstance(ms, int | float):
            return f"[{i}]", f"must be a number of milliseconds, got {ms!r}"
        if ms * 1000 < bproto.MIN_EXPOSURE_US:
            return f"[{i}]", f"{ms} ms is below the {bproto.MIN_EXPOSURE_US / 1000:.3f} ms minimum exposure"
    return None


def check_brackets_ms(brackets: list[Any], fps: float) -> tuple[str, str] | None:
    """The bracket table rule (the wire codec's, ``bproto``): None when ``brackets`` (ms) is a table the trigger
    accepts at ``fps``; else ``(where, problem)`` for the first problem (``where``: "" or "[i]")."""
    problem = _bracket_items(brackets)
    if problem:
        return problem
    period_us = round(1e6 / fps)
    for i, ms in enumerate(brackets):
        if ms * 1000 + bproto.EXPOSURE_MARGIN_US > period_us:
            return (f"[{i}]", f"{ms} ms does not fit the {period_us} us period at {fps:g} fps "
                              f"(needs exposure + {bproto.EXPOSURE_MARGIN_US / 1000:g} ms <= period)")
    if bproto.check_set_brackets(period_us, [round(ms * 1000) for ms in brackets]):  # the codec owns the rule
        return "", (f"the trigger refuses {brackets} ms at a {period_us} us period "
                    "(SET_BRACKETS rule, firmware/protocol/PROTOCOL.md section 3)")
    return None


def _address_problem(text: str) -> str | None:
    try:
        unicast_ipv4(text)
    except BracketryError as exc:
        return f"{'not a unicast IPv4 address' if 'unicast' in str(exc) else 'not an IPv4 address'}: {text!r}"
    return None


def _listen_problem(text: str) -> str | None:
    from bracketry_rig.monitor.address import parse_listen

    try:
        parse_listen(text)
    except ValueError as exc:
        return str(exc)
    return None


_BAUD_REFUSED = "unsupported baud rate {value}"


@config_table
class CameraConfig:
    """One GigE camera, opened by its IPv4 ``address`` (cameras are never discovered by broadcast)."""

    side: str = setting(help="Which camera of the stereo pair", choices=SIDES)
    profile: str = setting(help="Camera model (what the daemon configures on it)", choices=CAMERA_PROFILES)
    address: str | None = setting(default=None, check=_address_problem, example="192.168.10.11",
                                  help="IPv4 address the camera is opened at (needed: cameras are never discovered "
                                       "by broadcast)")
    device_id: str | None = setting(default=None, example="40123456",
                                    help="The id or serial number the camera at that address must report, so swapped "
                                         "cables or a replaced camera are caught at start-up")
    trigger_line: str = setting(default="Line3", help="Input line wired to the trigger")
    trigger_activation: str = setting(default="FallingEdge", choices=TRIGGER_ACTIVATIONS,
                                      help="Trigger edge or level (FallingEdge: exposure while the line is low)")
    pixel_format: str = setting(default="BayerRG12p", choices=PIXEL_FORMATS, help="Pixel format recorded")
    packet_size_bytes: int = setting(default=9000, min=576, max=9216, unit="bytes",
                                     help="GigE Vision packet size (9000: jumbo frames on the 10 GbE card)")
    packet_delay_ticks: int = setting(default=0, min=0, help="Inter-packet delay, camera ticks")


@config_table
class TriggerConfig:
    """The STM32 trigger's serial link (``kind`` serial), or a simulated one for ``bracketry simulate``."""

    kind: str = setting(default="serial", choices=TRIGGER_KINDS, help="The STM32 board, or a simulated one")
    port: str = setting(default="/dev/bracketry-trigger",
                        help="Serial port (udev name from host/deploy/99-bracketry.rules)")
    baudrate: int = setting(default=921600, choices=BAUDRATES, refused=_BAUD_REFUSED, help="Serial baud rate")


@config_table
class PanelConfig:
    """The ESP32 panel's serial link; ``enabled = false`` runs the rig without a panel."""

    enabled: bool = setting(default=True, help="false: run the rig without a panel")
    port: str = setting(default="/dev/bracketry-panel", help="Serial port (not the trigger's)")
    baudrate: int = setting(default=115200, choices=BAUDRATES, refused=_BAUD_REFUSED, help="Serial baud rate")
    refresh_hz: float = setting(default=4.0, min=2, max=5, unit="Hz", why="the panel's host heartbeat",
                                help="PANEL_STATE updates per second")


@config_table
class MonitorConfig:
    """The browser monitor (table ``[monitor]``; no table: off); see host/bracketry_rig/monitor/MONITOR.md."""

    listen: str = setting(default="127.0.0.1:8470", check=_listen_problem,
                          help="HOST:PORT, an IPv4 address of the rig, e.g. 10.42.0.1:8470 for its Wi-Fi access "
                               "point (anything but loopback needs the token)")
    preview_hz: float = setting(default=1.0, min=0.1, max=5, unit="per second",
                                help="Previews per camera and bracket")
    bayer: bool = setting(default=True, auto="true when every camera's pixel format is Bayer",
                          help="Frames are RGGB mosaics (demosaiced in the preview)")
    white_dn: int = setting(default=4095, min=1, max=65535, auto="255 when every pixel format is 8-bit, else 4095",
                            help="The sensors' white level, DN")


@config_table
class RigConfig:
    """The whole rig. Times in the names' units; ``brackets_us`` is derived from ``brackets_ms``."""

    output_dir: Path = setting(help="Folder of the recordings")
    brackets_ms: tuple[float, ...] = setting(
        check=_bracket_items, help=f"Exposure of each bracket, milliseconds (pulse width): 1..{bproto.MAX_BRACKETS} "
                                   f"values, each at least {bproto.MIN_EXPOSURE_US / 1000:g} ms")
    fps: float = setting(min=MIN_FPS, max=200, unit="frames per second",
                         help=f"Trigger rate; every exposure + {bproto.EXPOSURE_MARGIN_US / 1000:g} ms must fit 1/fps")
    cameras: tuple[CameraConfig, ...] = table(
        many=True, missing='missing: declare two [[cameras]] tables (side = "left" and "right")',
        help="The two cameras, one [[cameras]] table each: side left and right, profiles of one trigger kind.")
    trigger: TriggerConfig = table(default_factory=TriggerConfig, help="The trigger's serial link.")
    panel: PanelConfig = table(default_factory=PanelConfig, help="The status panel's serial link.")
    min_free_mb: int = setting(default=2048, min=0, help="Refuse to start recording below this free space, MB")
    stop_free_mb: int = setting(default=512, min=0, help="Stop cleanly when free space falls below this, MB; "
                                                         "at most min_free_mb")
    split_size_mb: int = setting(default=4096, min=16, unit="MB",
                                 help="A new MCAP file starts at this size or after split_minutes, whichever first")
    split_minutes: float = setting(default=10.0, min=0, min_open=True,
                                   help="A new MCAP file starts after this many minutes or at split_size_mb, "
                                        "whichever first")
    status_socket: Path = setting(default=Path("/run/bracketry/status.sock"), help="The daemon's status socket")
    calibration: Path | None = setting(
        default=None, example="/data/bracketry/calibration/2026-06-01",
        help="Stereo calibration folder (what `bracketry calibrate solve --out` writes: left.yaml, right.yaml, ...), "
             "a path relative to this file's folder or absolute; read when a recording starts and carried by each "
             "of its files, so `bracketry export --format borealhdr` writes it as the tree's calibration/ (none: "
             "recordings carry no calibration)")
    source: Path | None = None
    monitor: MonitorConfig | None = table(
        default=None, help="The browser monitor (remove the table to turn it off). Anything but a loopback address "
                           "needs the token the daemon generates at start (shown on the panel's message line as "
                           "\"WEB KEY ...\" and logged with the page's URL).")

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


def parse_config(data: dict[str, Any], source: str = "<config>") -> RigConfig:
    """Validate a parsed TOML document and build a :class:`RigConfig`; raises :class:`ConfigError`. The keys'
    own rules come from the field table; the rules spanning keys are here."""
    c = Checker(source, ConfigError)
    known = ["rig", *(key.name for key in tables(RigConfig))]
    for name in data:
        if name not in known:
            c.fail(name, f"unknown table (known: {', '.join(sorted(known))})")
    if "rig" not in data:
        c.fail("rig", "missing table [rig]")
    rig = c.settings(data["rig"], "rig", RigConfig)
    problem = check_brackets_ms(data["rig"]["brackets_ms"], rig["fps"])
    if problem:
        c.fail(f"rig.brackets_ms{problem[0]}", problem[1])

    by_name = {key.name: key for key in tables(RigConfig)}
    cameras: tuple[CameraConfig, ...] = c.table(data, by_name["cameras"])
    for i, cam in enumerate(cameras):
        if cam.address is None:
            c.fail(f"cameras[{i}]", "needs address (IPv4; cameras are never discovered by broadcast, device_id alone "
                                    "cannot open one)")
    sides = sorted(cam.side for cam in cameras)
    if sides != ["left", "right"]:
        c.fail("cameras", f"need exactly one left and one right camera, got sides {sides}")
    for key in ("address", "device_id"):
        ids = [getattr(cam, key) for cam in cameras if getattr(cam, key)]
        if len(set(ids)) != len(ids):
            c.fail("cameras", f"left and right use the same {key} {ids[0]!r}")
    if len({profile_kind(cam.profile).trigger for cam in cameras}) > 1:
        c.fail("cameras", "one camera is triggered on a line and the other in software: use profiles of one kind")

    trigger, panel = c.table(data, by_name["trigger"]), c.table(data, by_name["panel"])
    if panel.enabled and trigger.port == panel.port:
        c.fail("panel.port", f"same serial port as trigger.port ({trigger.port})")
    monitor = None
    if "monitor" in data:  # two keys' defaults follow the cameras' pixel formats
        formats = [cam.pixel_format for cam in cameras]
        auto = {"bayer": all(f.startswith("Bayer") for f in formats),
                **({"white_dn": 255} if all(f.endswith("8") for f in formats) else {})}
        monitor = MonitorConfig(**{**auto, **c.settings(data["monitor"], "monitor", MonitorConfig)})
    if rig.get("calibration") is not None:
        rig["calibration"] = _calibration_folder(c, rig["calibration"], source)
    config = RigConfig(**rig, cameras=tuple(sorted(cameras, key=lambda cam: SIDES.index(cam.side))),
                       trigger=trigger, panel=panel, monitor=monitor,
                       source=Path(source) if source != "<config>" else None)
    if config.stop_free_mb > config.min_free_mb:
        c.fail("rig.stop_free_mb", f"({config.stop_free_mb}) must not exceed rig.min_free_mb ({config.min_free_mb})")
    return config


def _calibration_folder(c: Checker, folder: Path, source: str) -> Path:
    """``rig.calibration`` resolved against the config file's folder, checked to hold a calibration."""
    from bracketry_base.recording.calibration import read_calibration

    if not folder.is_absolute() and source != "<config>":
        folder = Path(source).parent / folder
    try:
        read_calibration(folder)
    except BracketryError as exc:
        c.fail("rig.calibration", str(exc))
    return folder


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


#: the real backpack, the documented example's values (``host/deploy/rig.example.toml``)
EXAMPLE = RigConfig(
    output_dir=Path("/data/bracketry"), brackets_ms=(1, 2, 4, 8, 16, 32), fps=22, min_free_mb=20480,
    stop_free_mb=4096, monitor=MonitorConfig(),
    cameras=(CameraConfig(side="left", profile="basler_ace2", address="192.168.10.11"),
             CameraConfig(side="right", profile="basler_ace2", address="192.168.10.12")))
EXAMPLE_HEADER = (
    "bracketry rig configuration: the real backpack (two Basler a2A1920-51gcPRO, STM32 trigger, ESP32 panel).",
    "Validate with: bracketry daemon --config rig.toml --check",
    "Generated from the field table in host/bracketry_rig/daemon/config.py by `python -m bracketry_rig.daemon.config > "
    "host/deploy/rig.example.toml`: edit the table, not this file.",
)


def example_config() -> str:
    """The documented example config (TOML), every key under its help, default, choices and range."""
    return example_toml(EXAMPLE, EXAMPLE_HEADER, "rig", "The recording: what to trigger and where to write.")


if __name__ == "__main__":
    print(example_config(), end="")
