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
from collections.abc import Sequence
from dataclasses import replace
from pathlib import Path
from typing import TYPE_CHECKING, Any

from bracketry_base.errors import BracketryError

if TYPE_CHECKING:
    from bracketry_emulator.ae.registry import MethodSpec
    from bracketry_emulator.ae.runner import LoopConfig

#: in a plugin's run folder: its source and options (a run made otherwise is made again)
_PLUGIN_FILE = "plugin.json"

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


def method_name(method: str | MethodSpec) -> str:
    """A method's name (its folder under ``runs/<trajectory>/``)."""
    return method if isinstance(method, str) else method.name


def _plugin_doc(method: str | MethodSpec) -> dict[str, Any] | None:
    return None if isinstance(method, str) or method.plain else method.to_json()


def made_by(folder: Path, method: str | MethodSpec) -> bool:
    """Whether the run in ``folder`` was made by this method (a plugin: same source and options, in
    ``plugin.json``; a built-in: no such file)."""
    path = folder / _PLUGIN_FILE
    try:
        before = json.loads(path.read_text()) if path.is_file() else None
    except (OSError, ValueError):
        return False
    return before == _plugin_doc(method)


def mark_made_by(folder: Path, method: str | MethodSpec) -> None:
    """Write ``plugin.json`` (source and options) into a plugin's run folder; nothing for a built-in."""
    doc = _plugin_doc(method)
    if doc is not None:
        (folder / _PLUGIN_FILE).write_text(json.dumps(doc, indent=1, sort_keys=True) + "\n")


def _closed_loops(dataset_path: Path, methods: Sequence[str | MethodSpec], tmp_root: Path, cfg: LoopConfig,
                  workers: int, progress: bool, stages: Any = None) -> None:
    from bracketry_emulator.ae import run_methods

    shutil.rmtree(tmp_root, ignore_errors=True)
    tmp_root.mkdir(parents=True)
    summary = run_methods(dataset_path, methods, tmp_root, workers=workers, progress=progress, config=cfg)
    if stages is not None:
        stages.merge(summary.stages)
    for method in map(method_name, methods):
        if not (tmp_root / method / "images_left").is_dir():
            raise BracketryError(f"the closed loop of {method!r} on {dataset_path} produced no images_left/")


def emulate_runs(dataset_path: Path, methods: Sequence[str | MethodSpec], runs_dir: Path, loop: LoopConfig, *,
                 workers: int = 0, progress: bool = False, stages: Any = None) -> list[Path]:
    """Emulated run folders ``runs_dir/<method>`` of ``methods`` on the dataset, the missing ones produced in one
    shared-decode pass (``workers`` processes, 0 = automatic) with the closed-loop settings ``loop`` (images
    written). Returns the folders in ``methods`` order. A folder without images (a run whose images went to SLAM in
    memory) is made again, with them; so is a plugin's run made with another source or options. ``stages``:
    receives the pass's stage times (:class:`~bracketry_emulator.stages.StageTimes`)."""
    check_options(runs_dir, loop)
    finals = [runs_dir / method_name(m) for m in methods]
    missing = [m for m, f in zip(methods, finals, strict=True)
               if not (f / "images_left").is_dir() or not made_by(f, m)]
    if missing:
        tmp_root = runs_dir / ".partial"
        _closed_loops(dataset_path, missing, tmp_root, replace(loop, write_images=True), workers, progress, stages)
        for m in missing:
            method = method_name(m)
            if (runs_dir / method).exists():
                shutil.rmtree(runs_dir / method)
            (tmp_root / method).rename(runs_dir / method)
            mark_made_by(runs_dir / method, m)
        for extra in tmp_root.iterdir():  # summary.json, exposures.csv, exposure_times.png of the pass
            if extra.is_file():
                extra.replace(runs_dir / f"closedloop_{extra.name}")
        shutil.rmtree(tmp_root, ignore_errors=True)
    return finals


def emulate_run(dataset_path: Path, spec: str | MethodSpec, runs_dir: Path, loop: LoopConfig) -> Path:
    """Emulated run folder ``runs_dir/<name>`` of the method ``spec`` on the dataset (produced if absent or made by
    another plugin source or options) with the closed-loop settings ``loop`` (images written)."""
    check_options(runs_dir, loop)
    method = method_name(spec)
    final = runs_dir / method
    if (final / "images_left").is_dir() and made_by(final, spec):
        return final
    tmp_root = runs_dir / f".partial-{method}"
    _closed_loops(dataset_path, [spec], tmp_root, replace(loop, write_images=True), 1, False)
    final.parent.mkdir(parents=True, exist_ok=True)
    if final.exists():
        shutil.rmtree(final)
    (tmp_root / method).rename(final)
    mark_made_by(final, spec)
    for extra in tmp_root.iterdir():  # e.g. a summary written next to the method folder
        if extra.is_file():
            extra.replace(runs_dir / f"{method}.{extra.name}")
    shutil.rmtree(tmp_root, ignore_errors=True)
    return final
