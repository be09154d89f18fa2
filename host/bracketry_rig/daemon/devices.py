"""The rig's USB serial devices: list them (pyusb), map them to serial ports, and write stable-name udev rules.

The trigger is an STM32 reached through an ST-LINK virtual COM port, the STM32's own USB CDC port or a USB-UART
adapter (FTDI); the panel is an ESP32 board's USB bridge (CP210x, CH340/CH9102) or the ESP32-S3's native USB. udev
rules match vendor id, product id and serial number, so each board keeps its name (``/dev/bracketry-trigger``,
``/dev/bracketry-panel``) whatever order the kernel enumerates them in.
"""

from __future__ import annotations

import json
from collections.abc import Iterable
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Any

from bracketry_base.errors import BracketryError

#: (vendor id, product id) -> (bridge name, default role)
KNOWN_BRIDGES: dict[tuple[int, int], tuple[str, str]] = {
    (0x0483, 0x374B): ("ST-LINK/V2-1 virtual COM port", "trigger"),
    (0x0483, 0x3752): ("ST-LINK/V2-1 virtual COM port", "trigger"),
    (0x0483, 0x374E): ("STLINK-V3 virtual COM port", "trigger"),
    (0x0483, 0x374F): ("STLINK-V3 virtual COM port", "trigger"),
    (0x0483, 0x5740): ("STM32 USB CDC (VCP)", "trigger"),
    (0x0403, 0x6001): ("FTDI FT232R USB-UART", "trigger"),
    (0x0403, 0x6014): ("FTDI FT232H USB-UART", "trigger"),
    (0x0403, 0x6015): ("FTDI FT231X USB-UART", "trigger"),
    (0x10C4, 0xEA60): ("Silicon Labs CP210x USB-UART", "panel"),
    (0x1A86, 0x7523): ("WCH CH340 USB-UART", "panel"),
    (0x1A86, 0x55D4): ("WCH CH9102 USB-UART", "panel"),
    (0x303A, 0x1001): ("Espressif USB JTAG/serial (ESP32-S3/C3)", "panel"),
}
ROLE_SYMLINKS = {"trigger": "bracketry-trigger", "panel": "bracketry-panel"}


@dataclass(frozen=True)
class UsbSerialDevice:
    """One USB device that is (or could be) a rig serial port.

    ``vendor_id``/``product_id`` are 16-bit USB ids; ``serial`` is the iSerial string (None if unreadable);
    ``port`` the tty it appears as (None if not mapped); ``bridge`` and ``role`` come from :data:`KNOWN_BRIDGES`.
    """

    vendor_id: int
    product_id: int
    serial: str | None
    manufacturer: str | None
    product: str | None
    bus: int | None
    address: int | None
    bridge: str
    role: str | None
    port: str | None = None

    @property
    def usb_id(self) -> str:
        """``vvvv:pppp`` in lowercase hex, as lsusb prints it."""
        return f"{self.vendor_id:04x}:{self.product_id:04x}"


def classify(vendor_id: int, product_id: int) -> tuple[str, str | None]:
    """Bridge name and default role of a USB id; ("unknown", None) for devices that are not rig bridges."""
    name, role = KNOWN_BRIDGES.get((vendor_id, product_id), ("unknown", ""))
    return name, (role or None)


def from_descriptors(records: Iterable[dict[str, Any]], ports: Iterable[dict[str, Any]] = ()) -> list[UsbSerialDevice]:
    """Build the device list from recorded descriptors (dicts with idVendor, idProduct, iSerialNumber, iManufacturer,
    iProduct, bus, address; ints or hex strings) and serial-port records (dicts with device, vid, pid, serial_number,
    as pyserial's ``list_ports`` gives them). Only known bridges are returned, sorted by role then serial."""
    port_list = list(ports)
    out = []
    for rec in records:
        vid, pid = _as_int(rec.get("idVendor")), _as_int(rec.get("idProduct"))
        if vid is None or pid is None:
            raise BracketryError(f"USB descriptor record without idVendor/idProduct: {rec}")
        bridge, role = classify(vid, pid)
        if role is None:
            continue
        serial = rec.get("iSerialNumber")
        port = None
        for p in port_list:
            if _as_int(p.get("vid")) == vid and _as_int(p.get("pid")) == pid and \
                    (serial is None or p.get("serial_number") == serial):
                port = p.get("device")
                break
        out.append(UsbSerialDevice(vid, pid, serial, rec.get("iManufacturer"), rec.get("iProduct"),
                                   _as_int(rec.get("bus")), _as_int(rec.get("address")), bridge, role, port))
    return sorted(out, key=lambda d: (d.role or "", d.serial or "", d.usb_id))


def _as_int(value: Any) -> int | None:
    if value is None:
        return None
    if isinstance(value, int):
        return value
    return int(str(value), 16)  # recorded ids are hex strings such as "0483" or "0x0483"


def scan() -> list[UsbSerialDevice]:
    """List the rig bridges on this machine's USB buses with pyusb and map them to pyserial's ports."""
    try:
        import usb.core  # type: ignore[import-untyped]
        import usb.util  # type: ignore[import-untyped]
    except ImportError:
        raise BracketryError("pyusb is not installed: pip install -e '.[host]'") from None
    from serial.tools import list_ports

    records = []
    try:
        found = list(usb.core.find(find_all=True) or [])
    except usb.core.NoBackendError:
        raise BracketryError("no libusb backend: apt-get install libusb-1.0-0") from None
    for dev in found:
        rec: dict[str, Any] = {"idVendor": dev.idVendor, "idProduct": dev.idProduct, "bus": dev.bus,
                               "address": dev.address}
        for key, index in (("iSerialNumber", dev.iSerialNumber), ("iManufacturer", dev.iManufacturer),
                           ("iProduct", dev.iProduct)):
            try:
                rec[key] = usb.util.get_string(dev, index) if index else None
            except (ValueError, usb.core.USBError, NotImplementedError):
                rec[key] = None  # no permission to read strings: still listed, matched without serial
        records.append(rec)
    ports = [{"device": p.device, "vid": p.vid, "pid": p.pid, "serial_number": p.serial_number}
             for p in list_ports.comports() if p.vid is not None]
    return from_descriptors(records, ports)


def udev_rules(devices: Iterable[UsbSerialDevice], roles: dict[str, str] | None = None) -> str:
    """udev rules giving each trigger/panel device a stable ``/dev/bracketry-*`` name.

    ``roles`` maps a serial number to "trigger" or "panel" (overrides the default role of the bridge). Raises
    BracketryError when two devices claim the same role without serial numbers to tell them apart.
    """
    roles = roles or {}
    lines = ["# bracketry: stable names for the rig's serial devices (generated by `bracketry devices`).",
             "# Install: cp FILE /etc/udev/rules.d/99-bracketry.rules && udevadm control --reload && udevadm trigger",
             ""]
    seen: dict[str, UsbSerialDevice] = {}
    for dev in devices:
        role = roles.get(dev.serial or "", dev.role)
        if role not in ROLE_SYMLINKS:
            continue
        if role in seen:
            raise BracketryError(f"two devices for the {role} role ({seen[role].usb_id} serial {seen[role].serial}, "
                                 f"{dev.usb_id} serial {dev.serial}): name one with --role SERIAL={role}")
        seen[role] = dev
        match = (f'SUBSYSTEM=="tty", ATTRS{{idVendor}}=="{dev.vendor_id:04x}", '
                 f'ATTRS{{idProduct}}=="{dev.product_id:04x}"')
        if dev.serial:
            match += f', ATTRS{{serial}}=="{dev.serial}"'
        lines.append(f"# {role}: {dev.bridge}" + (f", serial {dev.serial}" if dev.serial else ", no serial number"))
        lines.append(f'{match}, SYMLINK+="{ROLE_SYMLINKS[role]}", MODE="0660", GROUP="dialout"')
    if not seen:
        raise BracketryError("no trigger or panel device found: nothing to write")
    return "\n".join(lines) + "\n"


def load_recorded(path: Path) -> list[UsbSerialDevice]:
    """Load a recorded descriptor list (JSON ``{"usb": [...], "ports": [...]}``) for offline use and tests."""
    try:
        data = json.loads(path.read_text())
        return from_descriptors(data["usb"], data.get("ports", []))
    except (OSError, ValueError, KeyError, TypeError) as exc:
        raise BracketryError(f"{path}: not a recorded descriptor list: {exc}") from None


def as_dicts(devices: Iterable[UsbSerialDevice]) -> list[dict[str, Any]]:
    """JSON-friendly dicts (ids as hex strings)."""
    out = []
    for d in devices:
        row = asdict(d)
        row["vendor_id"], row["product_id"] = f"{d.vendor_id:04x}", f"{d.product_id:04x}"
        out.append(row)
    return out
