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
from pathlib import Path
from typing import Any

from bracketry.errors import BracketryError

#: closed-loop settings a benchmark may change (JSON-able; see :func:`loop_config`), with their defaults
LOOP_DEFAULTS: dict[str, Any] = {"selection": "highernosat", "crf": "srgb", "init_exposure_us": 4000.0, "seed": 0,
                                 "ae_camera": "left", "parity": "default"}
_OPTIONS_FILE = "closedloop_options.json"
#: option names of earlier versions -> (current name, factor to its unit), read from existing options files
_RENAMED = {"init_exposure_ms": ("init_exposure_us", 1000.0)}


def loop_options(**given: Any) -> dict[str, Any]:
    """The complete closed-loop settings: ``LOOP_DEFAULTS`` updated with the ``given`` ones that are not None."""
    unknown = set(given) - set(LOOP_DEFAULTS)
    if unknown:
        raise ValueError(f"unknown closed-loop option(s): {', '.join(sorted(unknown))}")
    return {**LOOP_DEFAULTS, **{k: v for k, v in given.items() if v is not None}}


def loop_config(options: dict[str, Any] | None, drl_weights: str | None) -> Any:
    """The :class:`~bracketry_emulator.ae.LoopConfig` of benchmark closed-loop ``options`` (validated)."""
    from bracketry_emulator.ae import LoopConfig
    from bracketry_emulator.emulation.settings import emulator_config

    o = loop_options(**(options or {}))
    cfg = LoopConfig(emulator=emulator_config(o["selection"], str(o["crf"]), str(o["parity"])),
                     ae_camera=o["ae_camera"], init_exposure_us=float(o["init_exposure_us"]), seed=int(o["seed"]),
                     drl_weights=drl_weights)
    cfg.validate()
    return cfg


def _check_options(runs_dir: Path, options: dict[str, Any]) -> None:
    """Runs already in ``runs_dir`` must have been made with the same settings (else: one clear line)."""
    path = runs_dir / _OPTIONS_FILE
    if path.is_file():
        before = json.loads(path.read_text())
        for old, (new, factor) in _RENAMED.items():
            if old in before and new not in before:
                before[new] = before.pop(old) * factor
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


def _closed_loops(dataset_path: Path, methods: list[str], tmp_root: Path, drl_weights: str | None, workers: int,
                  progress: bool, options: dict[str, Any] | None, stages: Any = None) -> None:
    from bracketry_emulator.ae import run_methods

    cfg = loop_config(options, drl_weights)
    shutil.rmtree(tmp_root, ignore_errors=True)
    tmp_root.mkdir(parents=True)
    summary = run_methods(dataset_path, methods, tmp_root, workers=workers, progress=progress, config=cfg)
    if stages is not None:
        stages.merge(summary.stages)
    for method in methods:
        if not (tmp_root / method / "images_left").is_dir():
            raise BracketryError(f"the closed loop of {method!r} on {dataset_path} produced no images_left/")


def emulate_runs(dataset_path: Path, methods: list[str], runs_dir: Path, *, drl_weights: str | None = None,
                 workers: int = 0, progress: bool = False, options: dict[str, Any] | None = None,
                 stages: Any = None) -> list[Path]:
    """Emulated run folders ``runs_dir/<method>`` of ``methods`` on the dataset, the missing ones produced in one
    shared-decode pass (``workers`` processes, 0 = automatic) with the closed-loop ``options`` (see
    :data:`LOOP_DEFAULTS`). Returns the folders in ``methods`` order. A folder without images (a run whose images
    went to SLAM in memory) is made again, with them. ``stages``: receives the pass's stage times
    (:class:`~bracketry_emulator.stages.StageTimes`)."""
    _check_options(runs_dir, loop_options(**(options or {})))
    finals = [runs_dir / m for m in methods]
    missing = [m for m, f in zip(methods, finals, strict=True) if not (f / "images_left").is_dir()]
    if missing:
        tmp_root = runs_dir / ".partial"
        _closed_loops(dataset_path, missing, tmp_root, drl_weights, workers, progress, options, stages)
        for method in missing:
            if (runs_dir / method).exists():
                shutil.rmtree(runs_dir / method)
            (tmp_root / method).rename(runs_dir / method)
        for extra in tmp_root.iterdir():  # summary.json, exposures.csv, exposure_times.png of the pass
            if extra.is_file():
                extra.replace(runs_dir / f"closedloop_{extra.name}")
        shutil.rmtree(tmp_root, ignore_errors=True)
    return finals


def emulate_run(dataset_path: Path, method: str, runs_dir: Path, drl_weights: str | None = None,
                options: dict[str, Any] | None = None) -> Path:
    """Emulated run folder ``runs_dir/<method>`` of ``method`` on the dataset (produced if absent)."""
    _check_options(runs_dir, loop_options(**(options or {})))
    final = runs_dir / method
    if (final / "images_left").is_dir():
        return final
    tmp_root = runs_dir / f".partial-{method}"
    _closed_loops(dataset_path, [method], tmp_root, drl_weights, 1, False, options)
    final.parent.mkdir(parents=True, exist_ok=True)
    (tmp_root / method).rename(final)
    for extra in tmp_root.iterdir():  # e.g. a summary written next to the method folder
        if extra.is_file():
            extra.replace(runs_dir / f"{method}.{extra.name}")
    shutil.rmtree(tmp_root, ignore_errors=True)
    return final
