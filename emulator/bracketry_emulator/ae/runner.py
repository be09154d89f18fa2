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
from ..defaults import (
    AE_CAMERAS,
    CAMERAS,
    DEFAULT_CRF,
    IMAGES,
    MAX_WARMUP_STEPS,
    PARITIES,
    PNG_COMPRESSIONS,
    SELECTIONS,
)
from ..emulation import EmulatorConfig
from ..stages import StageTimes, ae_stage
from .loop import DEFAULT_INIT_EXPOSURE_US, DEFAULT_MAX_EXPOSURE_US, DEFAULT_MIN_EXPOSURE_US, MethodRun
from .registry import MethodSpec, method_traits, methods_in_use, resolve_methods
from .scheduler import LoopSettings, run_scheduled
from .writers import write_run_files


@dataclass(frozen=True)
class LoopConfig:
    """Settings of a closed-loop run (see the module docstring). Exposures in us; ``camera``: the cameras written
    (left, right or both); ``ae_camera``: the camera whose image the methods see. Defaults and choices:
    :mod:`bracketry_emulator.defaults`. JSON form: :meth:`to_json`."""

    emulator: EmulatorConfig = field(default_factory=EmulatorConfig)
    camera: str = "both"
    ae_camera: str = "left"
    init_exposure_us: float = DEFAULT_INIT_EXPOSURE_US
    min_exposure_us: float = DEFAULT_MIN_EXPOSURE_US
    max_exposure_us: float = DEFAULT_MAX_EXPOSURE_US
    seed: int = 0
    drl_weights: str | None = None
    write_images: bool = True
    png_compression: str = PNG_COMPRESSIONS[0]
    overwrite: bool = False
    max_sequences: int | None = None
    memory_budget_bytes: int = 1 << 30
    images: str = IMAGES[0]
    #: steps each method takes on the first sequence's view before the run, not recorded (:func:`.loop.iter_loop`)
    warmup_steps: int = 0

    def validate(self) -> None:
        """Raise BracketryError (one line, naming the ``bracketry emulate`` option) on a bad setting: the one
        place these settings are checked."""
        if self.camera not in CAMERAS:
            raise BracketryError(f"--camera must be left, right or both, got {self.camera}")
        if self.ae_camera not in AE_CAMERAS:
            raise BracketryError(f"--ae-camera must be left or right, got {self.ae_camera}")
        lo_ms, hi_ms, init_ms = self.min_exposure_us / 1000, self.max_exposure_us / 1000, self.init_exposure_us / 1000
        if not 0 < lo_ms < hi_ms:
            raise BracketryError(f"--min-exposure-ms {lo_ms:g} must be > 0 and below --max-exposure-ms {hi_ms:g}")
        if not lo_ms <= init_ms <= hi_ms:
            raise BracketryError(f"--init-exposure-ms {init_ms:g} is outside the bounds [--min-exposure-ms "
                                 f"{lo_ms:g}, --max-exposure-ms {hi_ms:g}]")
        if not 0 <= self.warmup_steps <= MAX_WARMUP_STEPS:
            raise BracketryError(f"--warmup-steps must be between 0 and {MAX_WARMUP_STEPS}, got {self.warmup_steps}")
        if self.images not in IMAGES:
            raise BracketryError(f"--images must be one of {', '.join(IMAGES)}, got {self.images}")
        if self.png_compression not in PNG_COMPRESSIONS:
            raise BracketryError(f"--png-compression must be one of {', '.join(PNG_COMPRESSIONS)}, got "
                                 f"{self.png_compression}")
        self.emulator.validate()

    def to_json(self) -> dict[str, Any]:
        """The settings that decide the closed loops' results, as a JSON object (the benchmark's cache keys and
        ``closedloop_options.json``): selection, crf, parity, ``init_exposure_us``, seed, ``ae_camera``; the
        exposure bounds only where they are not the defaults, ``blur`` (motion-blur emulation), ``images``
        (truth runs) and ``warmup_steps`` only when not their defaults.
        Which files are written and how (cameras, images, PNG encoding, overwrite, memory) and the DRL weights
        (a method's own input) are not in it; nor the emulator's other settings (:meth:`from_json` gives their
        defaults, see :meth:`round_trips`)."""
        doc: dict[str, Any] = {"selection": self.emulator.selection, "crf": str(self.emulator.crf),
                               "init_exposure_us": self.init_exposure_us, "seed": self.seed,
                               "ae_camera": self.ae_camera, "parity": self.emulator.parity}
        if self.emulator.blur:  # only when on: the keys of runs without it stay as they were
            doc["blur"] = True
        if self.images != IMAGES[0]:  # likewise
            doc["images"] = self.images
        if self.warmup_steps:  # likewise
            doc["warmup_steps"] = self.warmup_steps
        for name in ("min_exposure_us", "max_exposure_us"):
            if getattr(self, name) != _DEFAULTS[name]:
                doc[name] = getattr(self, name)
        return doc

    @classmethod
    def from_json(cls, doc: dict[str, Any], **given: Any) -> LoopConfig:
        """The validated settings of :meth:`to_json`'s form (missing keys: their defaults), with ``given`` fields
        (e.g. ``drl_weights``, ``write_images``). One line (BracketryError) on a bad setting."""
        from ..emulation.settings import emulator_config

        unknown = set(doc) - set(_JSON_DEFAULTS)
        if unknown:
            raise ValueError(f"unknown closed-loop option(s): {', '.join(sorted(unknown))}")
        o = {**_JSON_DEFAULTS, **{k: v for k, v in doc.items() if v is not None}}
        cfg = cls(emulator=emulator_config(o["selection"], str(o["crf"]), str(o["parity"]), blur=bool(o["blur"])),
                  ae_camera=o["ae_camera"], init_exposure_us=float(o["init_exposure_us"]), seed=int(o["seed"]),
                  min_exposure_us=float(o["min_exposure_us"]), max_exposure_us=float(o["max_exposure_us"]),
                  images=str(o["images"]), warmup_steps=int(o["warmup_steps"]), **given)
        cfg.validate()
        return cfg

    def round_trips(self) -> bool:
        """Whether :meth:`to_json` holds every setting that decides the results (the rest are how files are
        written): else two different configs would share one JSON form (and one cache key)."""
        out_only = ("drl_weights", "write_images", "png_compression", "overwrite", "memory_budget_bytes")
        same = {k: getattr(self, k) for k in out_only}
        return LoopConfig.from_json(self.to_json(), **same) == self


_DEFAULTS = {f.name: f.default for f in fields(LoopConfig)}
#: :meth:`LoopConfig.to_json`'s keys and their defaults
_JSON_DEFAULTS: dict[str, Any] = {"selection": SELECTIONS[0], "crf": DEFAULT_CRF, "parity": PARITIES[0],
                                  "init_exposure_us": _DEFAULTS["init_exposure_us"], "seed": _DEFAULTS["seed"],
                                  "ae_camera": _DEFAULTS["ae_camera"], "min_exposure_us": _DEFAULTS["min_exposure_us"],
                                  "max_exposure_us": _DEFAULTS["max_exposure_us"], "blur": False,
                                  "images": IMAGES[0], "warmup_steps": 0}


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
                method_options: Mapping[str, Mapping[str, Any]] | None = None, **overrides: Any) -> RunSummary:
    """Run ``methods`` (ids, see :func:`get_method`, or resolved :class:`~.registry.MethodSpec`) in closed loop on a
    dataset; see the module docstring. Each method's outputs (folder, columns, ``runs`` keys) carry its name
    (:func:`~.registry.resolve_methods`; ``method_options``: {method: {keyword: value}} for plugin constructors).

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
    loader = {"seed": cfg.seed, "drl_weights": cfg.drl_weights, "parity": cfg.emulator.parity}
    specs = resolve_methods(list(dict.fromkeys(methods)), method_options, **loader)  # names checked, no work yet
    with methods_in_use(specs):
        return _run_methods(dataset_path, specs, out_dir, workers, cfg, progress, feeds, loader, t_start)


def _run_methods(dataset_path: str | Path, method_specs: list[MethodSpec], out_dir: str | Path, workers: int,
                 cfg: LoopConfig, progress: bool, feeds: dict[str, list[Any]] | None, loader: dict[str, Any],
                 t_start: float) -> RunSummary:
    specs = [m.name for m in method_specs]
    # fail fast (unknown ids, missing weights) and learn what each method declares for scheduling
    traits = {spec: method_traits(spec, **loader) for spec in specs}
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
    settings = LoopSettings(cfg.emulator, cfg.ae_camera, write_sides, tuple(dict.fromkeys([*write_sides,
                            cfg.ae_camera])), cfg.init_exposure_us, cfg.min_exposure_us, cfg.max_exposure_us,
                            cfg.seed, cfg.drl_weights, cfg.write_images, cfg.png_compression, cfg.overwrite,
                            truth_dir, cfg.warmup_steps)
    bar = _progress_bar(progress, len(specs) * len(sequences))
    stages = StageTimes()
    try:
        runs = run_scheduled(traits, settings, sequences, out, workers=workers,
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
