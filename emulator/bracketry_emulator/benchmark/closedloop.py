"""Produce the emulated runs of AE methods on one trajectory (the closed loops of the AE-methods issue).

Both entry points call :func:`bracketry_emulator.ae.run_methods` and write into a temporary sibling folder that is
renamed when complete, so an interrupted benchmark never leaves a half-written run that looks finished:

- :func:`emulate_runs`: every missing method of a trajectory in one pass (each bracket sequence decoded once and
  emulated for all methods) — what a local benchmark does before VO;
- :func:`emulate_run`: one method, inside a benchmark task (the Dask path, where tasks run on other machines).
"""

from __future__ import annotations

import shutil
from pathlib import Path

from bracketry.errors import BracketryError


def all_methods() -> tuple[str, ...]:
    """The ids that ``--methods all`` expands to (the AE registry's built-ins)."""
    from bracketry_emulator.ae.registry import BUILTIN_METHODS

    return tuple(BUILTIN_METHODS)


def _closed_loops(dataset_path: Path, methods: list[str], tmp_root: Path, drl_weights: str | None, workers: int,
                  progress: bool) -> None:
    from bracketry_emulator.ae import run_methods

    shutil.rmtree(tmp_root, ignore_errors=True)
    tmp_root.mkdir(parents=True)
    run_methods(dataset_path, methods, tmp_root, workers=workers, progress=progress, drl_weights=drl_weights)
    for method in methods:
        if not (tmp_root / method / "images_left").is_dir():
            raise BracketryError(f"the closed loop of {method!r} on {dataset_path} produced no images_left/")


def emulate_runs(dataset_path: Path, methods: list[str], runs_dir: Path, *, drl_weights: str | None = None,
                 workers: int = 0, progress: bool = False) -> list[Path]:
    """Emulated run folders ``runs_dir/<method>`` of ``methods`` on the dataset, the missing ones produced in one
    shared-decode pass (``workers`` processes, 0 = automatic). Returns the folders in ``methods`` order."""
    finals = [runs_dir / m for m in methods]
    missing = [m for m, f in zip(methods, finals, strict=True) if not (f / "images_left").is_dir()]
    if missing:
        tmp_root = runs_dir / ".partial"
        _closed_loops(dataset_path, missing, tmp_root, drl_weights, workers, progress)
        for method in missing:
            (tmp_root / method).rename(runs_dir / method)
        for extra in tmp_root.iterdir():  # summary.json, exposures.csv, exposure_times.png of the pass
            if extra.is_file():
                extra.replace(runs_dir / f"closedloop_{extra.name}")
        shutil.rmtree(tmp_root, ignore_errors=True)
    return finals


def emulate_run(dataset_path: Path, method: str, runs_dir: Path, drl_weights: str | None = None) -> Path:
    """Emulated run folder ``runs_dir/<method>`` of ``method`` on the dataset (produced if absent)."""
    final = runs_dir / method
    if (final / "images_left").is_dir():
        return final
    tmp_root = runs_dir / f".partial-{method}"
    _closed_loops(dataset_path, [method], tmp_root, drl_weights, 1, False)
    final.parent.mkdir(parents=True, exist_ok=True)
    (tmp_root / method).rename(final)
    for extra in tmp_root.iterdir():  # e.g. a summary written next to the method folder
        if extra.is_file():
            extra.replace(runs_dir / f"{method}.{extra.name}")
    shutil.rmtree(tmp_root, ignore_errors=True)
    return final
