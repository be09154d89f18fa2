"""Produce the emulated run of one AE method on one trajectory (the closed loop of the AE-methods issue).

Uses ``bracketry_emulator.ae.run_methods`` (owned by the AE helper) when it is available. Otherwise a minimal closed
loop with the same contract runs here: for each bracket sequence in time order, both cameras are emulated at the
method's current exposure (:class:`~bracketry_emulator.emulation.Emulator`, default config), written with
:class:`~bracketry_emulator.emulation.RunWriter`, and the method sees the left image to choose the next exposure.

The run is written to a temporary sibling folder and renamed when complete, so an interrupted benchmark never leaves
a half-written run that looks finished.
"""

from __future__ import annotations

import inspect
import shutil
from pathlib import Path

from bracketry.errors import BracketryError

DEFAULT_INIT_EXPOSURE_US = 4000.0
DEFAULT_BOUNDS_US = (50.0, 40_000.0)


def all_methods() -> tuple[str, ...]:
    """The ids that ``--methods all`` expands to (the AE registry's built-ins)."""
    try:
        from bracketry_emulator.ae.registry import BUILTIN_METHODS

        return tuple(BUILTIN_METHODS)
    except ImportError:
        return ("fix", "ae30", "ae50", "ae70", "shim", "wang", "kim", "drl", "zhang")


def _fallback_closed_loop(dataset_path: Path, method: str, out_dir: Path) -> None:
    from bracketry_emulator.ae import get_method
    from bracketry_emulator.dataset import open_dataset
    from bracketry_emulator.emulation import Emulator, EmulatorConfig, RunWriter

    ds = open_dataset(dataset_path)
    ae = get_method(method)
    target_us = DEFAULT_INIT_EXPOSURE_US
    ae.reset(target_us)
    emulator = Emulator(EmulatorConfig())
    lo, hi = DEFAULT_BOUNDS_US
    with RunWriter(out_dir, method, tuple(ds.sides)) as writer:
        for step, seq in enumerate(ds.sequences()):
            images = {side: emulator.emulate(seq.load(side), target_us) for side in ds.sides}
            writer.write_step(step, seq, images, target_us)
            first = ds.sides[0]
            meta = {"step": step, "timestamp_ns": seq.timestamps_ns[first][images[first].source_exposure_us],
                    "side": first, "sequence_index": seq.index, "response": emulator.response,
                    "source_exposure_us": images[first].source_exposure_us, "bounds_us": (lo, hi)}
            target_us = float(min(max(ae.next_exposure_us(images[first].image, target_us, meta), lo), hi))


def emulate_run(dataset_path: Path, method: str, runs_dir: Path) -> Path:
    """Emulated run folder ``runs_dir/<method>`` of ``method`` on the dataset (produced if absent)."""
    final = runs_dir / method
    if (final / "images_left").is_dir():
        return final
    tmp_root = runs_dir / f".partial-{method}"
    shutil.rmtree(tmp_root, ignore_errors=True)
    tmp_root.mkdir(parents=True)
    try:
        import bracketry_emulator.ae as ae_pkg

        run_methods = getattr(ae_pkg, "run_methods", None)
        if run_methods is not None:
            params = inspect.signature(run_methods).parameters
            kwargs: dict = {k: v for k, v in (("progress", False), ("workers", 1)) if k in params}
            run_methods(dataset_path, [method], tmp_root, **kwargs)
        else:
            _fallback_closed_loop(dataset_path, method, tmp_root)
    except BracketryError:
        raise
    except ImportError as exc:
        raise BracketryError(f"cannot run AE method {method!r}: {exc}") from exc
    produced = tmp_root / method
    if not (produced / "images_left").is_dir():
        raise BracketryError(f"the closed loop of {method!r} on {dataset_path} produced no images_left/")
    final.parent.mkdir(parents=True, exist_ok=True)
    produced.rename(final)
    for extra in tmp_root.iterdir():  # e.g. a summary written next to the method folder
        target = runs_dir / f"{method}.{extra.name}" if extra.is_file() else None
        if target is not None:
            extra.rename(target)
    shutil.rmtree(tmp_root, ignore_errors=True)
    return final
