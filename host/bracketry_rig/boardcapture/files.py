"""Board sessions on disk: the board definition (``board.yaml``) and the stereo image pairs of a session folder or
of a recording exported as a BorealHDR tree (docs/CALIBRATION.md, "A board session")."""

from __future__ import annotations

import struct
from pathlib import Path
from typing import Any

from bracketry_base.errors import BracketryError

IMAGE_SUFFIXES = (".png", ".tif", ".tiff", ".pgm", ".jpg")


def load_board(path: Path) -> Any:
    """The board of a ``board.yaml`` (one-line error when it is not one)."""
    import yaml

    from bracketry_base.calibration.board import BoardSpec

    try:
        doc = yaml.safe_load(Path(path).read_text())
    except (OSError, yaml.YAMLError) as exc:
        raise BracketryError(f"cannot read the board definition {path}: {' '.join(str(exc).split())}") from None
    return BoardSpec.from_dict(doc)


def image_pairs(folder: Path) -> list[tuple[Path, Path]]:
    """(left, right) image files of a session: ``left/`` and ``right/`` holding images of the same names (a board
    session), or a BorealHDR tree (``bracketry export --format borealhdr`` of a recording):
    ``camera_left/<exposure>/`` and ``camera_right/<exposure>/``, the k-th image of a side with the k-th of the
    other (the pairing's order) in each exposure folder."""
    if (folder / "camera_left").is_dir() and (folder / "camera_right").is_dir():
        return _borealhdr_pairs(folder)
    sides = [folder / "left", folder / "right"]
    if not all(d.is_dir() for d in sides):
        raise BracketryError(f"{folder} has no left/ and right/ image folders (a board session: left/NNNNNN.png, "
                             "right/NNNNNN.png) nor camera_left/ and camera_right/ (a BorealHDR tree)")
    names = [{p.name for p in d.iterdir() if p.suffix.lower() in IMAGE_SUFFIXES} for d in sides]
    if names[0] != names[1]:
        odd = sorted(names[0] ^ names[1])
        raise BracketryError(f"left/ and right/ of {folder} do not hold the same image names ({len(odd)} unpaired, "
                             f"e.g. {odd[0]}): give image pairs")
    if not names[0]:
        raise BracketryError(f"no images in {folder}/left (png, tif, pgm, jpg)")
    return [(sides[0] / n, sides[1] / n) for n in sorted(names[0])]


def _borealhdr_pairs(folder: Path) -> list[tuple[Path, Path]]:
    pairs = []
    lefts = sorted(d for d in (folder / "camera_left").iterdir() if d.is_dir())
    for d in lefts:
        r = folder / "camera_right" / d.name
        files = [sorted(p for p in x.iterdir() if p.suffix.lower() in IMAGE_SUFFIXES) if x.is_dir() else []
                 for x in (d, r)]
        if len(files[0]) != len(files[1]):
            raise BracketryError(f"{d} holds {len(files[0])} images but {r} {len(files[1])}: give image pairs "
                                 "(bracketry verify the recording)")
        pairs += list(zip(files[0], files[1], strict=True))
    if not pairs:
        raise BracketryError(f"no images in {folder}/camera_left/*/ (png, tif, pgm, jpg)")
    return pairs


def read_image(path: Path) -> Any:
    """An image file as it is stored (16-bit PNGs stay 16-bit); one-line error when unreadable."""
    import cv2

    img = cv2.imread(str(path), cv2.IMREAD_UNCHANGED)
    if img is None:
        raise BracketryError(f"cannot read image {path}")
    return img


def check_png_sizes(pairs: list[tuple[Path, Path]], size: tuple[int, int]) -> None:
    """Every PNG of the pairs is ``size`` (width, height), read from its header (other formats are checked when
    read)."""
    for pair in pairs:
        for p in pair:
            if p.suffix.lower() != ".png":
                continue
            with open(p, "rb") as f:
                head = f.read(24)
            if len(head) < 24 or head[12:16] != b"IHDR":
                raise BracketryError(f"{p} is not a PNG image")
            wh = struct.unpack(">II", head[16:24])
            if wh != size:
                raise BracketryError(f"{p} is {wh[0]}x{wh[1]} but {pairs[0][0]} is {size[0]}x{size[1]}: a "
                                     "session's images must all have one size")
