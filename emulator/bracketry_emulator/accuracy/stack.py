"""Reader of static exposure stacks (the paper's emulator-validation protocol), as written by ``bracketry synth
static`` (layout in ``emulator/DATASET.md``)::

    DIR/static.json                                  index
    DIR/sweep/exposures.csv                          index,exposure_us,file,truth_file
    DIR/sweep/<i>.png, DIR/truth/sweep/<i>.png       noisy ground truth at N exposures, its noise-free version
    DIR/repeats/<exposure_us>/<k>.png                25 repeated frames at some exposures (noise estimation)
    DIR/camera_left/<exposure_ms>/<timestamp_ns>.png the bracket set (one complete sequence)

A plain BorealHDR tree of a static scene (several frames per exposure folder) is also accepted: every frame of
every exposure is then a ground-truth frame and the frames of each folder are its repeats.
"""

from __future__ import annotations

import csv
import json
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from bracketry_base.errors import BracketryError

from ..dataset import open_dataset, read_png12
from ..dataset.borealhdr import SIDE_FOLDERS, exposure_us_from_folder, find_calibration_dir


@dataclass(frozen=True)
class SweepFrame:
    """One ground-truth exposure: ``exposure_us``, the noisy frame ``path`` and the noise-free ``truth_path``."""

    exposure_us: float
    path: Path
    truth_path: Path | None


@dataclass
class StaticStack:
    """A static stack: brackets (one sequence), ground-truth sweep, repeats; paths only (load on demand)."""

    root: Path
    brackets: dict[int, Path]
    sweep: list[SweepFrame]
    repeats: dict[float, list[Path]] = field(default_factory=dict)
    calibration_dir: Path | None = None
    camera_model: dict | None = None

    def load_brackets(self) -> dict[int, np.ndarray]:
        """{exposure_us: uint16 HxW} of the bracket set."""
        return {e: read_png12(p) for e, p in sorted(self.brackets.items())}

    def load_repeats(self) -> dict[float, list[np.ndarray]]:
        """{exposure_us: [uint16 HxW frames]} of the repeat sets."""
        return {e: [read_png12(p) for p in ps] for e, ps in sorted(self.repeats.items())}


def open_static_stack(root: str | Path, side: str = "left") -> StaticStack:
    """Open a static stack folder (see the module docstring); raises BracketryError with a clear message."""
    r = Path(root)
    if not r.is_dir():
        raise BracketryError(f"static stack not found: {r}")
    index_path = r / "static.json"
    model_path = r / "camera_model.json"
    model = json.loads(model_path.read_text()) if model_path.is_file() else None
    if index_path.is_file():
        return _open_synth(r, json.loads(index_path.read_text()), model)
    return _open_tree(r, side, model)


def _open_synth(r: Path, index: dict, model: dict | None) -> StaticStack:
    brackets: dict[int, Path] = {}
    for key, rel in index.get("brackets", {}).get("files", {}).items():
        brackets[round(float(key))] = r / rel
    sweep: list[SweepFrame] = []
    csv_path = r / index.get("sweep", {}).get("csv", "sweep/exposures.csv")
    if csv_path.is_file():
        with csv_path.open() as fh:
            for row in csv.DictReader(fh):
                truth = row.get("truth_file")
                sweep.append(SweepFrame(float(row["exposure_us"]), r / row["file"], r / truth if truth else None))
    repeats = {float(k): [r / p for p in v] for k, v in index.get("repeats", {}).get("files", {}).items()}
    if len(brackets) < 2:
        raise BracketryError(f"static stack {r}: static.json lists fewer than 2 brackets")
    if not sweep:
        raise BracketryError(f"static stack {r}: no ground-truth sweep ({csv_path} missing or empty)")
    missing = [p for p in list(brackets.values()) + [s.path for s in sweep] if not p.is_file()]
    if missing:
        raise BracketryError(f"static stack {r}: {len(missing)} listed file(s) missing, first {missing[0]}")
    return StaticStack(r, brackets, sorted(sweep, key=lambda s: s.exposure_us), repeats, find_calibration_dir(r), model)


def _open_tree(r: Path, side: str, model: dict | None) -> StaticStack:
    side_dir = r / SIDE_FOLDERS.get(side, f"camera_{side}")
    if not side_dir.is_dir():
        raise BracketryError(f"not a static stack (no static.json, no {side_dir.name}/): {r}")
    frames: dict[int, list[Path]] = {}
    for d in sorted(p for p in side_dir.iterdir() if p.is_dir()):
        pngs = sorted(d.glob("*.png"))
        if pngs:
            frames[exposure_us_from_folder(d.name)] = pngs
    if len(frames) < 2:
        raise BracketryError(f"static stack {r}: need frames at 2 or more exposures under {side_dir}")
    try:  # the bracket set = the first complete sequence if there is one
        seq = open_dataset(r, (side,)).sequences()[0]
        brackets = {e: Path(seq.frames[side][e].source) for e in seq.exposures_us}
    except BracketryError:
        brackets = {e: ps[0] for e, ps in frames.items()}
    sweep = [SweepFrame(float(e), p, None) for e, ps in sorted(frames.items()) for p in ps]
    repeats = {float(e): ps for e, ps in frames.items() if len(ps) >= 2}
    return StaticStack(r, brackets, sweep, repeats, find_calibration_dir(r), model)
