"""The bill of materials, ``hw/bom.csv``: one row per part with quantity, role, interface and nominal power."""

from __future__ import annotations

import csv
from dataclasses import dataclass
from pathlib import Path

from bracketry_base import paths
from bracketry_base.errors import BracketryError

COLUMNS = ("id", "category", "part", "manufacturer", "part_number", "quantity", "role", "interface",
           "nominal_power_w", "power_rail", "voltage_v", "capacity_ah", "power_source", "notes")


@dataclass(frozen=True)
class Part:
    """One BOM row. ``nominal_power_w`` is per unit (W); ``voltage_v``/``capacity_ah`` are set for batteries."""

    id: str
    category: str
    part: str
    manufacturer: str
    part_number: str
    quantity: int
    role: str
    interface: str
    nominal_power_w: float
    power_rail: str
    voltage_v: float | None
    capacity_ah: float | None
    power_source: str
    notes: str

    @property
    def total_power_w(self) -> float:
        """Power of all units of this row (W)."""
        return self.nominal_power_w * self.quantity

    @property
    def is_battery(self) -> bool:
        return self.category == "power" and self.capacity_ah is not None


def default_bom_path() -> Path:
    """``hw/bom.csv`` of the checkout."""
    return paths.hw_dir() / "bom.csv"


def _float_or_none(text: str) -> float | None:
    text = text.strip()
    return float(text) if text else None


def load_bom(path: Path | None = None) -> list[Part]:
    """Parse the BOM CSV; raises BracketryError on a missing file, a missing column or a bad number."""
    path = path or default_bom_path()
    try:
        with open(path, newline="") as fh:
            reader = csv.DictReader(fh)
            missing = [c for c in COLUMNS if c not in (reader.fieldnames or [])]
            if missing:
                raise BracketryError(f"{path}: missing column(s) {', '.join(missing)}")
            parts = []
            for lineno, row in enumerate(reader, start=2):
                try:
                    parts.append(Part(
                        id=row["id"], category=row["category"], part=row["part"], manufacturer=row["manufacturer"],
                        part_number=row["part_number"], quantity=int(row["quantity"]), role=row["role"],
                        interface=row["interface"], nominal_power_w=float(row["nominal_power_w"] or 0),
                        power_rail=row["power_rail"], voltage_v=_float_or_none(row["voltage_v"]),
                        capacity_ah=_float_or_none(row["capacity_ah"]), power_source=row["power_source"],
                        notes=row["notes"]))
                except (TypeError, ValueError) as exc:
                    raise BracketryError(f"{path}:{lineno}: bad value ({exc})") from None
    except OSError as exc:
        raise BracketryError(f"cannot read the BOM {path}: {exc.strerror}") from None
    ids = [p.id for p in parts]
    dup = sorted({i for i in ids if ids.count(i) > 1})
    if dup:
        raise BracketryError(f"{path}: duplicate part id(s) {', '.join(dup)}")
    return parts
