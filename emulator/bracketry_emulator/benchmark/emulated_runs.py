"""The benchmark's emulated runs of AE methods on one trajectory (one closed loop per method), made once and reused.

Both entry points call :func:`bracketry_emulator.ae.run_methods` and write into a temporary sibling folder that is
renamed when complete, so an interrupted benchmark never leaves a half-written run that looks finished:

- :func:`emulate_runs`: every missing method of a trajectory in one pass (each bracket sequence decoded once and
  emulated for all methods) — what a local benchmark does before VO;
- :func:`emulate_run`: one method, inside a benchmark task (the Dask path, where tasks run on other machines).
"""

from __future__ import annotations

import json
import shutil
from dataclasses import replace
from pathlib import Path
from typing import TYPE_CHECKING, Any

from bracketry.errors import BracketryError

if TYPE_CHECKING:
    from bracketry_emulator.ae.runner import LoopConfig

_OPTIONS_FILE = "closedloop_options.json"
#: option names of earlier versions -> (current name, factor to its unit), read from existing options files
_RENAMED = {"init_exposure_ms": ("init_exposure_us", 1000.0)}


def check_options(runs_dir: Path, loop: LoopConfig) -> None:
    """Runs already in ``runs_dir`` must have been made with the same settings (:meth:`LoopConfig.to_json`; else:
    one clear line); the first writes them to ``closedloop_options.json``."""
    options = loop.to_json()
    path = runs_dir / _OPTIONS_FILE
    if path.is_file():
        before = json.loads(path.read_text())
        for old, (new, factor) in _RENAMED.items():
            if old in before and new not in before:
                before[new] = before.pop(old) * factor
        if before.get("parity") == "upstream" and before.get("selection") == "highernosat":
            before["selection"] = "upstream"  # what upstream parity always ran (written as given before)
        if before != options:
            changed = ", ".join(f"{k} {before.get(k)!r} -> {options.get(k)!r}" for k in sorted(options)
                                if before.get(k) != options.get(k))
            raise BracketryError(f"{runs_dir} holds closed loops made with other settings ({changed}); "
                                 "choose a new --out")
    else:
        runs_dir.mkdir(parents=True, exist_ok=True)
        path.write_text(json.dumps(options, indent=1, sort_keys=True) + "\n")


def all_methods() -> tuple[str, ...]:
    """The ids that ``--methods all`` expands to (the paper's eight; ``zhang`` by name)."""
    from bracketry_emulator.ae.registry import PAPER_METHODS

    return tuple(PAPER_METHODS)


def _closed_loops(dataset_path: Path, methods: list[str], tmp_root: Path, cfg: LoopConfig, workers: int,
                  progress: bool, stages: Any = None) -> None:
    from bracketry_emulator.ae import run_methods

    shutil.rmtree(tmp_root, ignore_errors=True)
    tmp_root.mkdir(parents=True)
    summary = run_methods(dataset_path, methods, tmp_root, workers=workers, progress=progress, config=cfg)
    if stages is not None:
        stages.merge(summary.stages)
    for method in methods:
        if not (tmp_root / method / "images_left").is_dir():
            raise BracketryError(f"the closed loop of {method!r} on {dataset_path} produced no images_left/")


def emulate_runs(dataset_path: Path, methods: list[str], runs_dir: Path, loop: LoopConfig, *, workers: int = 0,
                 progress: bool = False, stages: Any = None) -> list[Path]:
    """Emulated run folders ``runs_dir/<method>`` of ``methods`` on the dataset, the missing ones produced in one
    shared-decode pass (``workers`` processes, 0 = automatic) with the closed-loop settings ``loop`` (images
    written). Returns the folders in ``methods`` order. A folder without images (a run whose images went to SLAM in
    memory) is made again, with them. ``stages``: receives the pass's stage times
    (:class:`~bracketry_emulator.stages.StageTimes`)."""
    check_options(runs_dir, loop)
    finals = [runs_dir / m for m in methods]
    missing = [m for m, f in zip(methods, finals, strict=True) if not (f / "images_left").is_dir()]
    if missing:
        tmp_root = runs_dir / ".partial"
        _closed_loops(dataset_path, missing, tmp_root, replace(loop, write_images=True), workers, progress, stages)
        for method in missing:
            if (runs_dir / method).exists():
                shutil.rmtree(runs_dir / method)
            (tmp_root / method).rename(runs_dir / method)
        for extra in tmp_root.iterdir():  # summary.json, exposures.csv, exposure_times.png of the pass
            if extra.is_file():
                extra.replace(runs_dir / f"closedloop_{extra.name}")
        shutil.rmtree(tmp_root, ignore_errors=True)
    return finals


def emulate_run(dataset_path: Path, method: str, runs_dir: Path, loop: LoopConfig) -> Path:
    """Emulated run folder ``runs_dir/<method>`` of ``method`` on the dataset (produced if absent) with the
    closed-loop settings ``loop`` (images written)."""
    check_options(runs_dir, loop)
    final = runs_dir / method
    if (final / "images_left").is_dir():
        return final
    tmp_root = runs_dir / f".partial-{method}"
    _closed_loops(dataset_path, [method], tmp_root, replace(loop, write_images=True), 1, False)
    final.parent.mkdir(parents=True, exist_ok=True)
    (tmp_root / method).rename(final)
    for extra in tmp_root.iterdir():  # e.g. a summary written next to the method folder
        if extra.is_file():
            extra.replace(runs_dir / f"{method}.{extra.name}")
    shutil.rmtree(tmp_root, ignore_errors=True)
    return final
