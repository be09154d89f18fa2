"""Power budget (sum of the BOM's nominal powers) and battery runtime per pack."""

from __future__ import annotations

from dataclasses import dataclass

from bracketry_rig.hwcalc.bom import Part


@dataclass(frozen=True)
class PowerBudget:
    """Loads in W: ``items`` (part id, quantity, W per unit, W total), sorted by total power, and their sum."""

    items: list[tuple[str, int, float, float]]
    total_w: float


def power_budget(parts: list[Part]) -> PowerBudget:
    """Sum the nominal power of every powered part (batteries and passive parts contribute 0 W)."""
    items = [(p.id, p.quantity, p.nominal_power_w, p.total_power_w) for p in parts
             if p.total_power_w > 0 and not p.is_battery]
    items.sort(key=lambda it: -it[3])
    return PowerBudget(items, sum(it[3] for it in items))


def battery_energy_wh(capacity_ah: float, voltage_v: float) -> float:
    """Nominal pack energy (Wh)."""
    return capacity_ah * voltage_v


def runtime_h(capacity_ah: float, voltage_v: float, load_w: float, efficiency: float = 1.0,
              usable_fraction: float = 1.0) -> float:
    """Hours a pack lasts at a constant ``load_w`` (W).

    ``efficiency`` is the DC-DC conversion efficiency (load power / battery power) and ``usable_fraction`` the part
    of the nominal energy that can be drawn. Defaults of 1.0 reproduce the paper's estimates (its ~79 W is counted at
    the battery); real converters (~0.88) and cold weather shorten the runtime accordingly.
    """
    if load_w <= 0:
        raise ValueError("load must be positive")
    if not 0 < efficiency <= 1 or not 0 < usable_fraction <= 1:
        raise ValueError("efficiency and usable_fraction must be in (0, 1]")
    return battery_energy_wh(capacity_ah, voltage_v) * usable_fraction * efficiency / load_w


def battery_runtimes(parts: list[Part], load_w: float, efficiency: float = 1.0,
                     usable_fraction: float = 1.0) -> list[tuple[Part, float]]:
    """(battery part, runtime in hours) for every battery of the BOM."""
    out = []
    for p in parts:
        if p.is_battery and p.voltage_v is not None and p.capacity_ah is not None:
            out.append((p, runtime_h(p.capacity_ah, p.voltage_v, load_w, efficiency, usable_fraction)))
    return out
