"""The trajectories of an environment: dataset arguments resolved (folders, MCAP files, manifests and their split)
and one trajectory's brackets loaded at the working resolution.

Python API::

    specs = resolve_trajectories(["suite/manifest.yaml"], split="train")   # [TrajectorySpec]
    traj = load_trajectory(specs[0].path, width=256)                         # Trajectory
    traj.brackets.shape        # (N sequences, B brackets, h, w) uint16 codes
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from bracketry_base.errors import BracketryError

from ..dataset import open_dataset
from ..metrics.manifest import TrajectorySpec, load_manifest
from .core import working_image

SPLITS: tuple[str, ...] = ("train", "test", "all")


@dataclass(frozen=True)
class Trajectory:
    """One trajectory at the working resolution.

    Attributes:
        name: its name (manifest entry or folder name).
        exposures_us: the bracket set (ascending us), B values.
        brackets: uint16 (N, B, h, w) working images (:func:`~.core.working_image`) of side ``side``: sequence n,
            bracket b (in ``exposures_us`` order).
        timestamps_ns: int64 (N,) start of each sequence (ns).
        side: the camera side loaded ("left").
    """

    name: str
    exposures_us: tuple[int, ...]
    brackets: np.ndarray
    timestamps_ns: np.ndarray
    side: str

    def images(self, n: int) -> dict[int, np.ndarray]:
        """Sequence ``n``'s brackets as the emulator takes them: {exposure_us: uint16 (h, w)} (views)."""
        return {e: self.brackets[n, b] for b, e in enumerate(self.exposures_us)}

    @property
    def steps(self) -> int:
        """Number of sequences (environment steps of a whole episode + 1)."""
        return int(self.brackets.shape[0])


def resolve_trajectories(datasets: list[str | Path] | str | Path, split: str = "all") -> list[TrajectorySpec]:
    """Trajectories of dataset arguments: dataset folders / MCAP files (kept whatever ``split``) and manifests
    (``.yaml``/``.yml``: only their entries of ``split``, "all" for every entry).

    Raises BracketryError (one line) for a missing path, an unknown split, or no trajectory left.
    """
    if split not in SPLITS:
        raise BracketryError(f"unknown split {split!r} (use {', '.join(SPLITS)})")
    items = [datasets] if isinstance(datasets, str | Path) else list(datasets)
    specs: list[TrajectorySpec] = []
    for raw in items:
        p = Path(raw)
        if p.is_file() and p.suffix.lower() in (".yaml", ".yml"):
            specs += [s for s in load_manifest(p) if split == "all" or s.split == split]
        elif p.exists():
            specs.append(TrajectorySpec(p.resolve().stem if p.is_file() else p.resolve().name, p.resolve(), "all"))
        else:
            raise BracketryError(f"dataset not found (need a dataset folder, an .mcap or a manifest .yaml): {p}")
    if not specs:
        raise BracketryError(f"no trajectory of split {split!r} in {', '.join(str(i) for i in items)}")
    return specs


def load_trajectory(path: str | Path, width: int = 256, side: str = "left", name: str | None = None,
                    max_sequences: int | None = None) -> Trajectory:
    """Load every complete sequence of the dataset at ``path`` (BorealHDR tree, synthetic world or MCAP), side
    ``side``, as working images ``width`` px wide (at most ``max_sequences`` of them, from the first).

    Raises BracketryError (one line) when the dataset cannot be read, lacks the side or has fewer than 2 sequences.
    """
    ds = open_dataset(path)
    if side not in ds.sides:
        raise BracketryError(f"{path}: no camera side {side!r} (sides: {', '.join(ds.sides)})")
    seqs = ds.sequences()[:max_sequences] if max_sequences else ds.sequences()
    if len(seqs) < 2:
        raise BracketryError(f"{path}: an episode needs at least 2 bracket sequences, found {len(seqs)}")
    exps = tuple(seqs[0].exposures_us)
    first = working_image(seqs[0].frames[side][exps[0]].load(), width)
    out = np.empty((len(seqs), len(exps), *first.shape), dtype=np.uint16)
    for n, seq in enumerate(seqs):
        if tuple(seq.exposures_us) != exps:
            raise BracketryError(f"{path}: sequence {seq.index} has brackets {seq.exposures_us}, not {exps}")
        for b, e in enumerate(exps):
            img = working_image(seq.frames[side][e].load(), width)
            if img.shape != first.shape:
                raise BracketryError(f"{path}: sequence {seq.index} has images of another size")
            out[n, b] = img
    stamps = np.array([seq.start_ns for seq in seqs], dtype=np.int64)
    return Trajectory(name or Path(path).name, exps, out, stamps, side)
