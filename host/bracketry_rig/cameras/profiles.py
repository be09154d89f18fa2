"""Camera profiles: which GenICam features to write for each camera kind, written then read back.

Two profiles:
    ``basler_ace2``  Basler ace 2 GigE (a2A1920-51gcPRO): hardware trigger on a GPIO line, exposure = pulse width
                     (``ExposureMode TriggerWidth``), 12-bit Bayer, chunks. Feature table: :func:`basler_ace2_writes`
                     (GenICam SFNC names as the ace 2 exposes them).
    ``aravis_fake``  the Aravis fake GigE camera: ``ExposureTimeAbs``/``GainRaw``, TriggerSource ``Software``,
                     Mono16 carries the 12-bit codes (the fake has no BayerRG12 pixels), no chunks, no ExposureMode.

Every written feature is read back; ``ConfigReport.raise_if_mismatch()`` refuses recording with one clear line when a
required feature is absent or reads back a different value. Optional features that a camera lacks are listed as
``absent`` in the report, never skipped silently.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any

from bracketry_rig.cameras.aravis_gi import CameraError, glib_error_message

PROFILES = ("basler_ace2", "aravis_fake")


@dataclass(frozen=True)
class CameraSettings:
    """What to configure on one camera.

    Attributes:
        profile: ``basler_ace2`` or ``aravis_fake``.
        pixel_format: on the wire; ``BayerRG12p``/``BayerRG12`` (Basler), ``Mono16``/``Mono8``/``BayerRG8`` (fake).
        width, height, offset_x, offset_y: region of interest in pixels (None keeps the camera's value).
        trigger_source: ``Line3`` (Basler GPIO) or ``Software`` (fake; set by its profile).
        trigger_activation: ``FallingEdge`` upstream (exposure while the line is low).
        packet_size_bytes: GevSCPSPacketSize (None keeps it); 1500 without jumbo frames.
        packet_delay_ticks: GevSCPD inter-packet delay in camera ticks (None keeps it).
        exposure_us: initial exposure for cameras that time the exposure themselves (fake), microseconds.
        chunks: chunk names to enable when the camera has chunks.
        fake_max_frame_rate_hz: fake camera only: its AcquisitionFrameRate, which paces triggered frames too.
    """

    profile: str = "basler_ace2"
    pixel_format: str = "BayerRG12p"
    width: int | None = None
    height: int | None = None
    offset_x: int | None = None
    offset_y: int | None = None
    trigger_source: str = "Line3"
    trigger_activation: str = "FallingEdge"
    packet_size_bytes: int | None = None
    packet_delay_ticks: int | None = None
    exposure_us: float = 1000.0
    chunks: tuple[str, ...] = ("Timestamp", "FrameID", "ExposureTime", "CounterValue")
    fake_max_frame_rate_hz: float = 500.0


@dataclass(frozen=True)
class ProfileKind:
    """How a camera of one profile works with the rig, beyond its feature writes.

    ``trigger``: ``line`` (the trigger device's pulse reaches a GPIO line) or ``software`` (no trigger line: the host
    fires TriggerSoftware at each TRIGGER event, see ``bracketry_rig.cameras.triggering``); ``transport``: whether the
    rig config's packet size and delay apply (the fake camera serves on loopback at its own packet size);
    ``lost_triggers_register``: the register holding how many software triggers the camera lost (None: it keeps no
    such count; the fake camera's relay does, ``bracketry_rig.cameras.fake_relay.REG_TRIGGERS_LOST``).
    """

    trigger: str
    transport: bool
    lost_triggers_register: int | None = None


#: ``bracketry_rig.cameras.fake_relay.REG_TRIGGERS_LOST`` (the fake camera's relay answers it)
FAKE_LOST_TRIGGERS_REGISTER = 0xFF00

PROFILE_KINDS: dict[str, ProfileKind] = {
    "basler_ace2": ProfileKind(trigger="line", transport=True),
    "aravis_fake": ProfileKind(trigger="software", transport=False,
                               lost_triggers_register=FAKE_LOST_TRIGGERS_REGISTER),
}


def profile_kind(profile: str) -> ProfileKind:
    """The :class:`ProfileKind` of ``profile``; CameraError for an unknown one."""
    try:
        return PROFILE_KINDS[profile]
    except KeyError:
        raise CameraError(f"unknown camera profile {profile!r} (known: {', '.join(PROFILES)})") from None


def settings_from_config(camera: Any, *, width: int | None = None, height: int | None = None,
                         exposure_us: float = 1000.0) -> CameraSettings:
    """CameraSettings from a rig config camera entry (``bracketry_rig.daemon.config.CameraConfig`` or alike: profile,
    pixel_format, trigger_line, trigger_activation, packet_size_bytes, packet_delay_ticks); ``exposure_us`` is the
    initial exposure of cameras that time it themselves. The profile decides what applies: a software-triggered
    camera gets TriggerSource ``Software``, a camera without ``transport`` keeps its packet settings."""
    profile = getattr(camera, "profile", "basler_ace2")
    kind = profile_kind(profile)
    pixel_format = getattr(camera, "pixel_format", "BayerRG12p")
    if profile == "aravis_fake" and pixel_format in ("BayerRG12p", "BayerRG12"):
        pixel_format = "Mono16"  # the fake has no 12-bit Bayer pixels: Mono16 carries the 12-bit codes
    return CameraSettings(profile=profile, pixel_format=pixel_format, width=width, height=height,
                          trigger_source="Software" if kind.trigger == "software" else
                          getattr(camera, "trigger_line", "Line3"),
                          trigger_activation=getattr(camera, "trigger_activation", "FallingEdge"),
                          packet_size_bytes=getattr(camera, "packet_size_bytes", None) if kind.transport else None,
                          packet_delay_ticks=getattr(camera, "packet_delay_ticks", None) if kind.transport else None,
                          exposure_us=float(exposure_us))


@dataclass(frozen=True)
class FeatureWrite:
    """One feature to write: ``kind`` enum|int|float|bool|command; ``required`` ones must exist and read back."""

    name: str
    value: Any
    kind: str
    required: bool = True
    tolerance: float = 1e-3


@dataclass
class FeatureResult:
    name: str
    wanted: Any
    read: Any
    status: str  # ok | mismatch | absent | error | unsupported
    required: bool
    detail: str = ""


@dataclass
class ConfigReport:
    """Outcome of configuring one camera: one row per feature, in write order."""

    camera: str
    profile: str
    results: list[FeatureResult] = field(default_factory=list)

    @property
    def problems(self) -> list[FeatureResult]:
        return [r for r in self.results if r.required and r.status != "ok"]

    @property
    def ok(self) -> bool:
        return not self.problems

    def raise_if_mismatch(self) -> None:
        """Raise ``CameraError`` naming every required feature that is absent or reads back differently."""
        if self.ok:
            return
        parts = []
        for r in self.problems:
            if r.status == "mismatch":
                parts.append(f"{r.name} reads {r.read!r}, wanted {r.wanted!r}")
            else:
                parts.append(f"{r.name} {r.status}{': ' + r.detail if r.detail else ''}")
        raise CameraError(f"camera {self.camera} ({self.profile}): refusing to record: " + "; ".join(parts))

    def as_rows(self) -> list[dict[str, Any]]:
        return [{"feature": r.name, "wanted": r.wanted, "read": r.read, "status": r.status,
                 "required": r.required, "detail": r.detail} for r in self.results]


def basler_ace2_writes(s: CameraSettings) -> list[FeatureWrite]:
    """Feature writes of the ``basler_ace2`` profile, in the order Basler needs (ExposureMode after the trigger)."""
    writes = [
        FeatureWrite("UserSetSelector", "Default", "enum", required=False),
        FeatureWrite("UserSetLoad", None, "command", required=False),
        FeatureWrite("AcquisitionMode", "Continuous", "enum"),
        FeatureWrite("TriggerSelector", "FrameStart", "enum"),
        FeatureWrite("TriggerMode", "On", "enum"),
        FeatureWrite("TriggerSource", s.trigger_source, "enum"),
        FeatureWrite("TriggerActivation", s.trigger_activation, "enum"),
        FeatureWrite("LineSelector", s.trigger_source, "enum", required=False),
        FeatureWrite("LineMode", "Input", "enum", required=False),
        FeatureWrite("ExposureAuto", "Off", "enum"),
        FeatureWrite("ExposureMode", "TriggerWidth", "enum"),
        FeatureWrite("GainAuto", "Off", "enum"),
        FeatureWrite("Gain", 0.0, "float"),
        FeatureWrite("Gamma", 1.0, "float", required=False),
        FeatureWrite("LUTEnable", False, "bool", required=False),
        FeatureWrite("BalanceWhiteAuto", "Off", "enum", required=False),
        FeatureWrite("ImageCompressionMode", "Off", "enum", required=False),
        FeatureWrite("PixelFormat", s.pixel_format, "enum"),
        FeatureWrite("AcquisitionFrameRateEnable", False, "bool"),
    ]
    writes += _roi_writes(s)
    if s.chunks:
        writes.append(FeatureWrite("ChunkModeActive", True, "bool", required=False))
        for chunk in s.chunks:
            writes.append(FeatureWrite("ChunkSelector", chunk, "enum", required=False))
            writes.append(FeatureWrite("ChunkEnable", True, "bool", required=False))
    writes += _transport_writes(s)
    return writes


def aravis_fake_writes(s: CameraSettings) -> list[FeatureWrite]:
    """Feature writes of the ``aravis_fake`` profile.

    Explicit differences from ``basler_ace2``: ExposureTimeAbs instead of ExposureTime (the host sets it before each
    software trigger, standing for the pulse width), GainRaw instead of Gain, TriggerSource Software (Line0 never
    fires), no ExposureMode, no chunks (frame timestamps and ids come from the GVSP leader only).
    """
    writes = [
        FeatureWrite("AcquisitionMode", "Continuous", "enum"),
        # the fake paces frames at AcquisitionFrameRate even when triggered: keep it far above the trigger rate
        FeatureWrite("AcquisitionFrameRate", float(s.fake_max_frame_rate_hz), "float"),
        FeatureWrite("TriggerSelector", "FrameStart", "enum"),
        FeatureWrite("TriggerMode", "On", "enum"),
        FeatureWrite("TriggerSource", "Software", "enum"),
        FeatureWrite("GainRaw", 0, "int"),
        FeatureWrite("ExposureTimeAbs", float(s.exposure_us), "float"),
        FeatureWrite("PixelFormat", s.pixel_format, "enum"),
    ]
    writes += _roi_writes(s)
    writes += _transport_writes(s)
    return writes


def _roi_writes(s: CameraSettings) -> list[FeatureWrite]:
    out = []
    # Offsets first to zero so that a larger width/height fits, then size, then the wanted offsets.
    zero_x = 0 if s.offset_x is not None else None
    zero_y = 0 if s.offset_y is not None else None
    for name, value in (("OffsetX", zero_x), ("OffsetY", zero_y), ("Width", s.width), ("Height", s.height),
                        ("OffsetX", s.offset_x), ("OffsetY", s.offset_y)):
        if value is not None:
            out.append(FeatureWrite(name, int(value), "int"))
    return out


def _transport_writes(s: CameraSettings) -> list[FeatureWrite]:
    out = []
    if s.packet_size_bytes is not None:
        out.append(FeatureWrite("GevSCPSPacketSize", int(s.packet_size_bytes), "int"))
    if s.packet_delay_ticks is not None:
        out.append(FeatureWrite("GevSCPD", int(s.packet_delay_ticks), "int"))
    return out


def profile_writes(s: CameraSettings) -> list[FeatureWrite]:
    if s.profile == "basler_ace2":
        return basler_ace2_writes(s)
    if s.profile == "aravis_fake":
        return aravis_fake_writes(s)
    raise CameraError(f"unknown camera profile {s.profile!r} (known: {', '.join(PROFILES)})")


def feature_available(device: Any, name: str) -> bool:
    """True when the device's GenICam tree has ``name`` and it is implemented/available."""
    try:
        if device.get_feature(name) is None:
            return False
        checker = getattr(device, "is_feature_available", None)
        return bool(checker(name)) if checker is not None else True
    except Exception:
        return False


def read_feature(device: Any, name: str, kind: str) -> Any:
    if kind == "enum":
        return device.get_string_feature_value(name)
    if kind == "int":
        return int(device.get_integer_feature_value(name))
    if kind == "float":
        return float(device.get_float_feature_value(name))
    if kind == "bool":
        return bool(device.get_boolean_feature_value(name))
    return None


def write_feature(device: Any, name: str, kind: str, value: Any) -> None:
    if kind == "enum":
        device.set_string_feature_value(name, str(value))
    elif kind == "int":
        device.set_integer_feature_value(name, int(value))
    elif kind == "float":
        device.set_float_feature_value(name, float(value))
    elif kind == "bool":
        device.set_boolean_feature_value(name, bool(value))
    elif kind == "command":
        device.execute_command(name)
    else:
        raise ValueError(f"unknown feature kind {kind}")


def _same(w: FeatureWrite, read: Any) -> bool:
    if w.kind == "float":
        return read is not None and math.isclose(float(read), float(w.value), rel_tol=w.tolerance, abs_tol=w.tolerance)
    return bool(read == w.value)


def apply_writes(device: Any, camera: str, profile: str, writes: list[FeatureWrite]) -> ConfigReport:
    """Write each feature, read it back at once (selectors are still set), and collect a report."""
    report = ConfigReport(camera=camera, profile=profile)
    for w in writes:
        if not feature_available(device, w.name):
            report.results.append(FeatureResult(w.name, w.value, None, "absent", w.required))
            continue
        try:
            write_feature(device, w.name, w.kind, w.value)
        except Exception as exc:
            read = _try_read(device, w)
            report.results.append(FeatureResult(w.name, w.value, read, "error", w.required, glib_error_message(exc)))
            continue
        if w.kind == "command":
            report.results.append(FeatureResult(w.name, None, None, "ok", w.required))
            continue
        read = _try_read(device, w)
        status = "ok" if _same(w, read) else "mismatch"
        report.results.append(FeatureResult(w.name, w.value, read, status, w.required))
    return report


def _try_read(device: Any, w: FeatureWrite) -> Any:
    try:
        return read_feature(device, w.name, w.kind)
    except Exception:
        return None


#: features reported by ``probe`` (name -> kind)
PROBE_FEATURES: dict[str, str] = {
    "PixelFormat": "enum", "TriggerSelector": "enum", "TriggerMode": "enum", "TriggerSource": "enum",
    "TriggerActivation": "enum", "ExposureMode": "enum", "ExposureAuto": "enum", "ExposureTime": "float",
    "ExposureTimeAbs": "float", "Gain": "float", "GainRaw": "int", "GainAuto": "enum", "Gamma": "float",
    "LUTEnable": "bool", "ChunkModeActive": "bool", "ImageCompressionMode": "enum",
    "AcquisitionFrameRateEnable": "bool", "AcquisitionFrameRate": "float", "Width": "int", "Height": "int",
    "OffsetX": "int", "OffsetY": "int", "GevSCPSPacketSize": "int", "GevSCPD": "int", "DeviceTemperature": "float",
}


def probe_features(device: Any) -> dict[str, dict[str, Any]]:
    """Which of ``PROBE_FEATURES`` exist, their current value and (enumerations) the allowed values."""
    out: dict[str, dict[str, Any]] = {}
    for name, kind in PROBE_FEATURES.items():
        if not feature_available(device, name):
            out[name] = {"available": False}
            continue
        entry: dict[str, Any] = {"available": True, "value": _try_read(device, FeatureWrite(name, None, kind))}
        if kind == "enum":
            try:
                entry["values"] = list(device.dup_available_enumeration_feature_values_as_strings(name))
            except Exception:
                entry["values"] = []
        out[name] = entry
    return out
