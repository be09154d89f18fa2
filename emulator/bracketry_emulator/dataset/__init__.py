"""Bracketed datasets: the BorealHDR tree, synthetic worlds (same tree + groundtruth.txt) and MCAP recordings.

Python API::

    from bracketry_emulator.dataset import open_dataset
    ds = open_dataset("path/to/backpack_2023-09-25-15-05-03")   # or its parent, a synthetic world, a .zip, a .mcap
    for seq in ds.sequences():                                  # complete, time-ordered, left/right matched
        brackets = seq.load("left")                             # {exposure_us: uint16 HxW RGGB Bayer codes}

Every problem (missing folder, corrupt PNG, no complete sequence) raises :class:`DatasetError`, a
``BracketryError`` that the CLI prints as one line. Incomplete sequences are listed in ``Dataset.problems``.
"""

from __future__ import annotations

from pathlib import Path

from .borealhdr import is_borealhdr_tree, open_tree
from .grouping import group_sequences
from .imageio import read_png12, write_png16
from .model import BracketSequence, Dataset, DatasetError, Frame

__all__ = ["BracketSequence", "Dataset", "DatasetError", "Frame", "group_sequences", "open_dataset",
           "read_png12", "write_png16"]


def open_dataset(path: str | Path, sides: tuple[str, ...] | None = None, *, tolerance_ns: int = 2_000_000
                 ) -> Dataset:
    """Open a bracketed dataset and group it into complete sequences.

    Args:
        path: a BorealHDR recording folder (holding camera_left/, camera_right/), its parent when it holds exactly
            one recording (as the BorealHDR sample root), a synthetic world folder, a ``.zip`` holding one of these
            (read in place, :mod:`.ziptree`), or an MCAP file (or a folder of ``*.mcap`` split files).
        sides: camera sides to use, default every side present ("left", "right").
        tolerance_ns: largest timestamp difference for matching left and right frames of one shot.
    """
    p = Path(path)
    if not p.exists():
        raise DatasetError(f"dataset not found: {p}")
    if p.is_file() and p.suffix.lower() == ".zip":
        from .ziptree import open_zip

        return open_zip(p, sides, tolerance_ns=tolerance_ns)
    if p.is_file() or (p.is_dir() and any(p.glob("*.mcap")) and not is_borealhdr_tree(p)):
        from .mcap_reader import open_mcap

        return open_mcap(p, sides, tolerance_ns=tolerance_ns)
    if is_borealhdr_tree(p):
        return open_tree(p, sides, tolerance_ns=tolerance_ns)
    children = sorted(c for c in p.iterdir() if c.is_dir() and is_borealhdr_tree(c))
    if len(children) == 1:
        return open_tree(children[0], sides, tolerance_ns=tolerance_ns)
    if len(children) > 1:
        names = ", ".join(c.name for c in children)
        raise DatasetError(f"{p} holds several recordings ({names}); pass one of them")
    raise DatasetError(f"not a dataset (no camera_left/ or camera_right/, no .mcap): {p}")
