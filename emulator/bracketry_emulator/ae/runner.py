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
from dataclasses import asdict, dataclass, field, replace
from pathlib import Path
from typing import Any

from bracketry_base.errors import BracketryError

from ..dataset import open_dataset
from ..stages import StageTimes, ae_stage
from .loop import MethodRun
from .loop_config import LoopConfig as LoopConfig
from .registry import MethodSpec, resolve_methods
from .scheduler import LoopSettings, run_scheduled
from .writers import write_run_files


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
    from bracketry_base.progress import Progress

    return Progress("emulate", total=total, unit="step")
