"""Dataset model: frames, complete bracket sequences, the Dataset container.

A *frame* is one raw image of one camera side at one exposure time. A *bracket sequence* is one complete,
time-ordered bracket cycle (every exposure of the bracket set exactly once, shortest first), matched across the
camera sides by timestamp. Images are raw RGGB Bayer mosaics of 12-bit codes (uint16, HxW).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from bracketry_base.errors import BracketryError

#: Loads one frame's image: () -> uint16 HxW Bayer codes.
FrameLoader = Callable[[], np.ndarray]


class DatasetError(BracketryError):
    """A dataset cannot be read: missing folder, corrupt file, no complete sequence, mismatched sides."""


@dataclass(frozen=True)
class Frame:
    """One raw frame: ``side`` ("left"/"right"), ``exposure_us``, ``t_ns`` (capture timestamp), ``source``
    (a human-readable location used in error messages) and ``loader`` (returns the uint16 HxW mosaic)."""

    side: str
    exposure_us: int
    t_ns: int
    source: str
    loader: FrameLoader = field(compare=False, repr=False)

    def load(self) -> np.ndarray:
        """The frame's image: np.ndarray uint16 HxW, raw RGGB Bayer 12-bit codes."""
        return self.loader()

    def load_into(self, out: np.ndarray) -> np.ndarray:
        """The frame's image in ``out`` (uint16 HxW, C-contiguous; e.g. a slot of a frame buffer): decoded straight
        into it when the loader can (``loader.into(out)``, the PNG files' loader), else loaded and copied. Returns
        ``out``; an image of another shape is returned as it is, ``out`` left untouched."""
        into = getattr(self.loader, "into", None)
        if into is not None:
            return into(out)
        img = self.loader()
        if img.shape != out.shape:
            return img
        out[...] = img
        return out


@dataclass(frozen=True)
class BracketSequence:
    """One complete bracket cycle, present on every side of the dataset.

    Attributes:
        index: position of the sequence in the dataset (0-based, time order).
        exposures_us: the bracket exposure times in microseconds, sorted ascending.
        timestamps_ns: ``{side: {exposure_us: t_ns}}`` capture timestamps of every frame.
        frames: ``{side: {exposure_us: Frame}}``.
    """

    index: int
    exposures_us: tuple[int, ...]
    timestamps_ns: dict[str, dict[int, int]]
    frames: dict[str, dict[int, Frame]] = field(repr=False)

    @property
    def sides(self) -> tuple[str, ...]:
        """The camera sides of this sequence."""
        return tuple(self.frames)

    @property
    def start_ns(self) -> int:
        """Timestamp of the earliest frame of the sequence (any side)."""
        return min(min(d.values()) for d in self.timestamps_ns.values())

    def load(self, side: str) -> dict[int, np.ndarray]:
        """All brackets of one side: ``{exposure_us: uint16 HxW Bayer codes}`` (ascending exposure order)."""
        if side not in self.frames:
            raise DatasetError(f"sequence {self.index} has no side {side!r} (sides: {', '.join(self.sides)})")
        images = {exp: self.frames[side][exp].load() for exp in self.exposures_us}
        shapes = {img.shape for img in images.values()}
        if len(shapes) != 1:
            raise DatasetError(f"sequence {self.index} side {side}: brackets have different shapes {sorted(shapes)}")
        return images


@dataclass
class Dataset:
    """A bracketed dataset: complete sequences matched over ``sides``, plus what could not be used.

    Attributes:
        path: the folder (or MCAP file) that was opened.
        kind: "borealhdr", "synthetic" or "mcap".
        sides: camera sides present in every returned sequence, e.g. ("left", "right").
        calibration_dir: folder with camera_info YAMLs / pcalib.txt, or None.
        groundtruth_path: TUM trajectory file (synthetic worlds), or None.
        problems: one line per incomplete sequence, unmatched frame group or skipped file.
    """

    path: Path
    kind: str
    sides: tuple[str, ...]
    calibration_dir: Path | None
    groundtruth_path: Path | None
    _sequences: list[BracketSequence]
    problems: list[str] = field(default_factory=list)

    def sequences(self) -> list[BracketSequence]:
        """Complete, time-ordered bracket sequences (every side, every exposure)."""
        return list(self._sequences)

    @property
    def exposures_us(self) -> tuple[int, ...]:
        """The bracket set (ascending microseconds)."""
        return self._sequences[0].exposures_us

    def pcalib_path(self) -> Path | None:
        """``calibration_dir/pcalib*.txt`` if there is exactly one obvious candidate (pcalib.txt preferred)."""
        if self.calibration_dir is None:
            return None
        exact = self.calibration_dir / "pcalib.txt"
        if exact.is_file():
            return exact
        found = sorted(self.calibration_dir.glob("pcalib*.txt"))
        return found[0] if found else None
