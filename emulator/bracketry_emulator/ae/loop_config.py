"""The settings of a closed-loop run (:class:`LoopConfig`): the rows of the settings table
(:data:`~bracketry_emulator.option_table.SETTINGS`, record ``loop``) and how files are written; what every worker
receives (:class:`~.scheduler.LoopSettings` ``loop``)."""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field, fields
from pathlib import Path
from typing import Any

from bracketry_base.errors import BracketryError

from ..defaults import CAMERAS, MAX_WARMUP_STEPS, PNG_COMPRESSIONS
from ..emulation import EmulatorConfig
from ..option_table import Setting, default, rows


@dataclass(frozen=True)
class LoopConfig:
    """Settings of a closed-loop run (see the module docstring). Exposures in us; ``camera``: the cameras written
    (left, right or both); ``ae_camera``: the camera whose image the methods see. Every setting a command takes is a
    row of :data:`~bracketry_emulator.option_table.SETTINGS` (record ``loop``): its default, choices, unit, help and
    cache-key rule are declared there once; a row without a field here travels in ``extra`` (:meth:`value`). JSON
    form: :meth:`to_json`."""

    emulator: EmulatorConfig = field(default_factory=EmulatorConfig)
    camera: str = "both"
    ae_camera: str = default("loop", "ae_camera")
    init_exposure_us: float = default("loop", "init_exposure_us")
    min_exposure_us: float = default("loop", "min_exposure_us")
    max_exposure_us: float = default("loop", "max_exposure_us")
    seed: int = default("loop", "seed")
    write_images: bool = True
    png_compression: str = PNG_COMPRESSIONS[0]
    overwrite: bool = False
    max_sequences: int | None = None
    memory_budget_bytes: int = 1 << 30
    images: str = default("loop", "images")
    #: steps each method takes on the first sequence's view before the run, not recorded (:func:`.loop.iter_loop`)
    warmup_steps: int = 0
    #: the values of the table's loop rows that have no field of their own: sorted (name, value) pairs
    extra: tuple[tuple[str, Any], ...] = ()

    def value(self, target: str) -> Any:
        """The value of a loop row's field ``target`` (``emulator.<f>`` for the emulator's; a row without a field
        of its own: from ``extra``, else its default)."""
        if target.startswith("emulator."):
            return getattr(self.emulator, target.removeprefix("emulator."))
        if target in _FIELDS:
            return getattr(self, target)
        found = dict(self.extra)
        if target in found:
            return found[target]
        return next(s.default_value for s in rows("loop", _table()) if s.target == target)

    def validate(self) -> None:
        """Raise BracketryError (one line, naming the ``bracketry emulate`` option) on a bad setting: the one
        place these settings are checked (each row's choices; the rules that span settings)."""
        if self.camera not in CAMERAS:
            raise BracketryError(f"--camera must be left, right or both, got {self.camera}")
        for s in rows("loop", _table()):
            v = self.value(s.target)
            if s.choices and v not in s.choices:
                raise BracketryError(f"{s.option} must be one of {', '.join(s.choices)}, got {v}")
        lo_ms, hi_ms, init_ms = self.min_exposure_us / 1000, self.max_exposure_us / 1000, self.init_exposure_us / 1000
        if not 0 < lo_ms < hi_ms:
            raise BracketryError(f"--min-exposure-ms {lo_ms:g} must be > 0 and below --max-exposure-ms {hi_ms:g}")
        if not lo_ms <= init_ms <= hi_ms:
            raise BracketryError(f"--init-exposure-ms {init_ms:g} is outside the bounds [--min-exposure-ms "
                                 f"{lo_ms:g}, --max-exposure-ms {hi_ms:g}]")
        if not 0 <= self.warmup_steps <= MAX_WARMUP_STEPS:
            raise BracketryError(f"--warmup-steps must be between 0 and {MAX_WARMUP_STEPS}, got {self.warmup_steps}")
        if self.png_compression not in PNG_COMPRESSIONS:
            raise BracketryError(f"--png-compression must be one of {', '.join(PNG_COMPRESSIONS)}, got "
                                 f"{self.png_compression}")
        self.emulator.validate()

    def to_json(self) -> dict[str, Any]:
        """The settings that decide the closed loops' results, as a JSON object (the benchmark's cache keys and
        ``closedloop_options.json``): every loop row whose ``key`` is ``always``, and those whose ``key`` is
        ``changed`` while they differ from their defaults (so the keys of runs made without them stay as they
        were): selection, crf, parity, ``init_exposure_us``, seed, ``ae_camera``; the exposure bounds, ``blur``,
        ``images`` and ``warmup_steps`` only when not their defaults. Which files are written and how (cameras,
        images, PNG encoding, overwrite, memory) are not in it; nor the emulator's settings no row declares
        (:meth:`from_json` gives their defaults, see :meth:`round_trips`)."""
        doc: dict[str, Any] = {}
        for s in rows("loop", _table()):
            v = self.value(s.target)
            if s.key == "always" or (s.key == "changed" and v != s.default_value):
                doc[s.json_name] = str(v) if isinstance(v, Path) else v
        if self.warmup_steps:  # set per trajectory (a manifest's warmup_steps), not by a row
            doc["warmup_steps"] = self.warmup_steps
        return doc

    @classmethod
    def from_values(cls, values: Mapping[str, Any], **given: Any) -> LoopConfig:
        """The validated settings of the loop rows' ``values`` ({field: value}, as
        :func:`~bracketry_emulator.option_table.record_values` gives them; missing: their defaults), with ``given``
        fields (e.g. ``write_images``, ``emulator`` fields a row does not declare: ``emulator=EmulatorConfig``
        whose declared fields the values replace). One line (BracketryError) on a bad setting."""
        from ..emulation.settings import emulator_config

        known = {s.target for s in rows("loop", _table())} | {"warmup_steps"}
        unknown = set(values) - known
        if unknown:
            raise ValueError(f"unknown closed-loop option(s): {', '.join(sorted(unknown))}")
        base: EmulatorConfig = given.pop("emulator", None) or EmulatorConfig()
        emu = {f: getattr(base, f) for f in _EMULATOR_FIELDS}
        own: dict[str, Any] = {}
        extra: dict[str, Any] = {}
        for s in rows("loop", _table()):
            v = _like(s.default_value, values[s.target]) if s.target in values else s.default_value
            if s.target.startswith("emulator."):
                emu[s.target.removeprefix("emulator.")] = v
            elif s.target in _FIELDS:
                own[s.target] = v
            else:
                extra[s.target] = v
        if "warmup_steps" in values:
            own["warmup_steps"] = int(values["warmup_steps"])
        emulator = emulator_config(**emu)
        cfg = cls(emulator=emulator, **own, extra=tuple(sorted(extra.items())), **given)
        cfg.validate()
        return cfg

    @classmethod
    def from_json(cls, doc: dict[str, Any], **given: Any) -> LoopConfig:
        """The validated settings of :meth:`to_json`'s form (missing keys: their defaults), with ``given`` fields
        (e.g. ``write_images``). One line (BracketryError) on a bad setting."""
        by_json = {s.json_name: s.target for s in rows("loop", _table())}
        by_json["warmup_steps"] = "warmup_steps"
        unknown = set(doc) - set(by_json)
        if unknown:
            raise ValueError(f"unknown closed-loop option(s): {', '.join(sorted(unknown))}")
        return cls.from_values({by_json[k]: v for k, v in doc.items() if v is not None}, **given)

    def round_trips(self) -> bool:
        """Whether :meth:`to_json` holds every setting that decides the results (the rest are how files are
        written): else two different configs would share one JSON form (and one cache key)."""
        out_only = ("write_images", "png_compression", "overwrite", "memory_budget_bytes")
        same = {k: getattr(self, k) for k in out_only}
        return LoopConfig.from_json(self.to_json(), **same) == self


def _table() -> tuple[Setting, ...]:
    """The settings table (read at each use, so a row declared later, e.g. by a test, is seen)."""
    from .. import option_table

    return option_table.SETTINGS


def _like(default_value: Any, value: Any) -> Any:
    """``value`` in the type of its default (a JSON 4000 for a float setting is 4000.0: one JSON form, one key)."""
    if isinstance(default_value, float) and isinstance(value, int) and not isinstance(value, bool):
        return float(value)
    if isinstance(default_value, str) and isinstance(value, Path):
        return str(value)
    return value


_FIELDS = {f.name for f in fields(LoopConfig)} - {"emulator", "extra"}
_EMULATOR_FIELDS = tuple(f.name for f in fields(EmulatorConfig))
