"""Closed-loop runs of AE methods on a bracketed dataset: load, run every method's loop, save.

Python API::

    from bracketry_emulator.ae import run_methods
    summary = run_methods("path/to/dataset", ["ae50", "shim", "kim"], "out/", workers=2)

At step k (the k-th complete bracket sequence) every method's current target exposure is emulated for every camera
side, the images are written, and the method sees the image of ``ae_camera`` (default left, as the authors) to
choose the next target, which is clamped to the run's bounds (the loop itself: :mod:`.loop`; processes, decoding and
step order: :mod:`.scheduler`; files: :mod:`.writers`).

Bounds (explicit, documented; the authors clamp nothing in the loop): ``min_exposure_us`` = 20 us (the authors'
only floor, Zhang's 0.02 ms) and ``max_exposure_us`` = 64 ms (2x the sample's longest bracket: beyond it the
emulation extrapolates more than one stop above any recorded frame). The first target is ``init_exposure_us``
(4 ms, as the authors) unless a method carries its own ``init_exposure_us`` attribute (constant-<ms>).

With ``write_images=False`` only the exposure trajectories (ae.csv, steps.csv, summaries, plot) are written.
Images are lossless PNGs (``png_compression``: ``stored`` by default, the fastest; ``fast``, ``small``, ``opencv``: see
:mod:`..emulation.writer` and emulator/DATASET.md for what each costs) written on background threads. Output
layout: :mod:`.writers`.
"""

from __future__ import annotations

import time
from collections.abc import Mapping, Sequence
from dataclasses import asdict, dataclass, field, fields, replace
from pathlib import Path
from typing import Any

from bracketry.errors import BracketryError

from ..dataset import open_dataset
from ..defaults import CAMERAS, MAX_WARMUP_STEPS, PNG_COMPRESSIONS
from ..emulation import EmulatorConfig
from ..option_table import Setting, default, rows
from ..stages import StageTimes, ae_stage
from .loop import MethodRun
from .registry import MethodSpec, resolve_methods
from .scheduler import LoopSettings, run_scheduled
from .writers import write_run_files


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


@dataclass
class RunSummary:
    """All methods of one run."""

    out_dir: Path
    runs: dict[str, MethodRun]
    n_sequences: int
    sides: tuple[str, ...]
    wall_s: float
    plot_path: Path | None = None
    #: the dataset's problems (incomplete sequences, skipped files; one line each), also in summary.json
    problems: list[str] = field(default_factory=list)
    #: where the time went: decode, emulation, png_write and ae:<method> seconds
    #: (:class:`~bracketry_emulator.stages.StageTimes` ``as_dict``)
    stages: dict[str, dict[str, float]] = field(default_factory=dict)


def run_methods(dataset_path: str | Path, methods: Sequence[str | MethodSpec], out_dir: str | Path, *,
                workers: int = 0, config: LoopConfig | None = None, progress: bool = True,
                feeds: dict[str, list[Any]] | None = None,
                method_options: Mapping[str, Mapping[str, Any]] | None = None, drl_weights: str | Path | None = None,
                **overrides: Any) -> RunSummary:
    """Run ``methods`` (resolved :class:`~.registry.MethodSpec`, carried to the workers as they are; or ids and
    ``--methods`` groups, resolved here by :func:`~.registry.resolve_methods` with ``method_options``: {method:
    {keyword: value}} for plugin constructors and ``drl_weights``: the DRL actor) in closed loop on a dataset; see
    the module docstring. Each method's outputs (folder, columns, ``runs`` keys) carry its name.

    ``workers``: processes (0 = automatic, see :func:`~.scheduler.run_scheduled`; 1 = in-process).
    ``feeds``: {method name: [objects with ``write_step``/``close`` like a RunWriter]} that also get every step's images
    (e.g. a SLAM process fed in memory; see :class:`~.scheduler.Worker`).
    ``overrides``: LoopConfig fields. Raises BracketryError (one line) on bad input or a failing method; outputs
    already written stay on disk.
    """
    t_start = time.perf_counter()
    cfg = config or LoopConfig()
    for k in overrides:
        if not hasattr(cfg, k):
            raise TypeError(f"unknown closed-loop option {k}")
    cfg = replace(cfg, **overrides)
    cfg.validate()
    if not methods:
        raise BracketryError("no AE method given")
    method_specs = resolve_methods(list(dict.fromkeys(methods)), method_options, drl_weights=drl_weights,
                                   seed=cfg.seed, parity=cfg.emulator.parity)  # names checked, no work yet
    specs = [m.name for m in method_specs]
    # fail fast (unknown ids, missing weights) and learn what each method declares for scheduling
    traits = {m.name: m.traits(cfg.seed, cfg.emulator.parity) for m in method_specs}
    dataset = open_dataset(dataset_path)
    write_sides = dataset.sides if cfg.camera == "both" else (cfg.camera,)
    for s in (*write_sides, cfg.ae_camera):
        if s not in dataset.sides:
            raise BracketryError(f"the dataset has no {s} camera (sides: {', '.join(dataset.sides)})")
    truth_dir = None
    if cfg.images == "truth":
        from .truth import truth_recording

        truth_recording(dataset.path)  # refuses any other dataset, before any work
        truth_dir = str(dataset.path)
    sequences = dataset.sequences()
    if cfg.max_sequences is not None:
        sequences = sequences[: cfg.max_sequences]
    if not sequences:
        raise BracketryError(f"no complete bracket sequence in {dataset_path}")
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    settings = LoopSettings(cfg, write_sides, tuple(dict.fromkeys([*write_sides, cfg.ae_camera])), truth_dir)
    bar = _progress_bar(progress, len(specs) * len(sequences))
    stages = StageTimes()
    try:
        runs = run_scheduled({m.name: m for m in method_specs}, traits, settings, sequences, out, workers=workers,
                             memory_budget_bytes=cfg.memory_budget_bytes, progress=bar.update, feeds=feeds,
                             stages=stages)
    finally:
        bar.close()
    for spec, run in runs.items():
        stages.add(ae_stage(spec), sum(st.ae_s for st in run.steps), n=len(run.steps))
    summary = RunSummary(out, runs, len(sequences), write_sides, time.perf_counter() - t_start,
                         problems=list(dataset.problems), stages=stages.as_dict())
    emu = asdict(cfg.emulator)
    emu = {k: (str(v) if isinstance(v, Path) else v) for k, v in emu.items()}  # noise: {read_dn, dn_per_e}
    settings_doc = {"dataset": str(dataset.path), "sequences": summary.n_sequences, "sides": list(summary.sides),
                    "ae_camera": cfg.ae_camera, "mode": cfg.emulator.parity,
                    "init_exposure_ms": cfg.init_exposure_us / 1000.0,
                    "bounds_ms": [cfg.min_exposure_us / 1000.0, cfg.max_exposure_us / 1000.0], "seed": cfg.seed,
                    "emulator": emu, "images": cfg.images, "wall_s": round(summary.wall_s, 3),
                    "dataset_problems": summary.problems}
    plugins = {m.name: m.to_json() for m in method_specs if not m.plain}
    if plugins:  # where each plugin came from and its options (built-ins: their name says it all)
        settings_doc["plugins"] = plugins
    summary.plot_path = write_run_files(out, runs, settings_doc, cfg.emulator.parity)
    summary.wall_s = time.perf_counter() - t_start
    return summary


class _NoBar:
    def update(self, n: int = 1) -> None:
        pass

    def close(self) -> None:
        pass


def _progress_bar(enabled: bool, total: int) -> Any:
    if not enabled:
        return _NoBar()
    from bracketry.progress import Progress

    return Progress("emulate", total=total, unit="step")
