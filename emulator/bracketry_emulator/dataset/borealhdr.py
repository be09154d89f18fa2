"""Reader of the BorealHDR tree (and of synthetic worlds, which use the same tree plus ``groundtruth.txt``).

Layout: ``<root>/camera_left|camera_right/<exposure_ms as float, e.g. 1.0>/<timestamp_ns>.png`` (16-bit PNG,
raw RGGB Bayer 12-bit codes). The calibration folder is ``<root>/calibration`` or, as in the BorealHDR sample,
``<root>/../calibration``.
"""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path

from .grouping import group_sequences
from .imageio import PngLoader
from .model import BracketSequence, Dataset, DatasetError, Frame

SIDE_FOLDERS = {"left": "camera_left", "right": "camera_right"}


def is_borealhdr_tree(path: Path) -> bool:
    """True when ``path`` holds camera_left/ or camera_right/."""
    return any((path / folder).is_dir() for folder in SIDE_FOLDERS.values())


def exposure_us_from_folder(name: str) -> int:
    """Bracket folder name in milliseconds ("1.0", "16.0", "0.25") -> exposure in microseconds (int)."""
    try:
        ms = float(name)
    except ValueError as exc:
        raise DatasetError(f"bracket folder name is not an exposure in ms: {name!r}") from exc
    if not ms > 0:
        raise DatasetError(f"bracket folder exposure must be > 0 ms: {name!r}")
    return round(ms * 1000)


def scan_side(side_dir: Path, side: str, problems: list[str]) -> list[Frame]:
    """All frames of one ``camera_<side>`` folder; non-PNG files and badly named PNGs go to ``problems``."""
    frames: list[Frame] = []
    for bracket_dir in sorted(p for p in side_dir.iterdir() if p.is_dir()):
        exposure_us = exposure_us_from_folder(bracket_dir.name)
        for png in sorted(bracket_dir.iterdir()):
            if png.suffix.lower() != ".png":
                continue
            try:
                t_ns = int(png.stem)
            except ValueError:
                problems.append(f"{side}: skipped {png} (name is not a timestamp in ns)")
                continue
            if png.stat().st_size == 0:
                problems.append(f"{side}: skipped empty file {png}")
                continue
            frames.append(Frame(side, exposure_us, t_ns, str(png), PngLoader(png)))
    return frames


def find_calibration_dir(root: Path) -> Path | None:
    """``root/calibration`` or ``root/../calibration`` when it exists."""
    for cand in (root / "calibration", root.parent / "calibration"):
        if cand.is_dir():
            return cand
    return None


def side_sequences(wanted: tuple[str, ...], present: tuple[str, ...], scan: Callable[[str], list[Frame]],
                   where: Callable[[str], str], source: str, problems: list[str], tolerance_ns: int
                   ) -> list[BracketSequence]:
    """The bracket sequences of the camera sides ``wanted`` (a folder tree's or a zip's: ``scan`` lists a side's
    frames, ``where`` names its folder in messages, ``source`` the tree or archive); grouping problems are appended
    to ``problems``. Raises DatasetError (one line) for an unknown or missing side, a side without frames and no
    complete sequence."""
    frames_by_side: dict[str, list[Frame]] = {}
    for side in wanted:
        if side not in SIDE_FOLDERS:
            raise DatasetError(f"unknown camera side {side!r} (use left or right)")
        if side not in present:
            raise DatasetError(f"missing folder {where(side)}")
        frames_by_side[side] = scan(side)
        if not frames_by_side[side]:
            raise DatasetError(f"no PNG frames under {where(side)}")
    sequences, group_problems = group_sequences(frames_by_side, tolerance_ns=tolerance_ns)
    problems.extend(group_problems)
    if not sequences:
        detail = f" ({problems[0]})" if problems else ""
        raise DatasetError(f"no complete bracket sequence in {source}{detail}")
    return sequences


def open_tree(root: Path, sides: tuple[str, ...] | None = None, *, tolerance_ns: int = 2_000_000) -> Dataset:
    """Open a BorealHDR tree or synthetic world folder (``root`` holds camera_left/ and/or camera_right/)."""
    present = tuple(s for s, folder in SIDE_FOLDERS.items() if (root / folder).is_dir())
    wanted = sides or present
    problems: list[str] = []
    sequences = side_sequences(wanted, present, lambda side: scan_side(root / SIDE_FOLDERS[side], side, problems),
                               lambda side: str(root / SIDE_FOLDERS[side]), str(root), problems, tolerance_ns)
    gt = root / "groundtruth.txt"
    return Dataset(path=root, kind="synthetic" if gt.is_file() else "borealhdr", sides=tuple(wanted),
                   calibration_dir=find_calibration_dir(root), groundtruth_path=gt if gt.is_file() else None,
                   _sequences=sequences, problems=problems)
