"""The calibration target: a ChArUco board (default) or a plain checkerboard, and its definition as a dict.

A board is defined by its squares (``squares_x`` columns, ``squares_y`` rows, side ``square_m`` metres); a ChArUco
board adds its markers (side ``marker_m``, an OpenCV ArUco dictionary name). The corners the solver uses are the
inner chessboard corners, ``(squares_x - 1) * (squares_y - 1)`` of them, with ids in row-major order (OpenCV's
ChArUco ids) and board coordinates ``((i % nx + 1) * square_m, (i // nx + 1) * square_m, 0)``, ``nx = squares_x - 1``.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import cv2
import numpy as np

from bracketry_base.errors import BracketryError

KINDS = ("charuco", "checkerboard")
#: a board of many corners is not a board a person carries; refuse obviously wrong definitions early
MAX_SQUARES = 40


@dataclass(frozen=True)
class BoardSpec:
    """A calibration board.

    Attributes:
        kind: "charuco" or "checkerboard".
        squares_x, squares_y: squares along the board's x (columns) and y (rows), each >= 3.
        square_m: side of one square in metres.
        marker_m: side of an ArUco marker in metres (ChArUco only; < square_m).
        dictionary: OpenCV ArUco dictionary name, e.g. "DICT_4X4_50" (ChArUco only).
    """

    kind: str = "charuco"
    squares_x: int = 8
    squares_y: int = 6
    square_m: float = 0.09
    marker_m: float = 0.065
    dictionary: str = "DICT_4X4_50"

    def __post_init__(self) -> None:
        if self.kind not in KINDS:
            raise BracketryError(f"board: kind must be one of {', '.join(KINDS)} (got {self.kind!r})")
        if not (3 <= self.squares_x <= MAX_SQUARES and 3 <= self.squares_y <= MAX_SQUARES):
            raise BracketryError(f"board: squares_x and squares_y must be in 3..{MAX_SQUARES} "
                                 f"(got {self.squares_x} x {self.squares_y})")
        if not (np.isfinite(self.square_m) and 0 < self.square_m < 1):
            raise BracketryError(f"board: square_m must be in (0, 1) metres (got {self.square_m})")
        if self.kind == "charuco":
            if not (np.isfinite(self.marker_m) and 0 < self.marker_m < self.square_m):
                raise BracketryError(f"board: marker_m must be in (0, square_m) (got {self.marker_m})")
            if not hasattr(cv2.aruco, self.dictionary) or not self.dictionary.startswith("DICT_"):
                raise BracketryError(f"board: unknown ArUco dictionary {self.dictionary!r} (e.g. DICT_4X4_50)")
            n_markers = (self.squares_x * self.squares_y) // 2
            size = int(self.dictionary.rsplit("_", 1)[-1]) if self.dictionary.rsplit("_", 1)[-1].isdigit() else 0
            if size and n_markers > size:
                raise BracketryError(f"board: {n_markers} markers do not fit the dictionary {self.dictionary}")

    @property
    def corners_x(self) -> int:
        """Inner corners along x."""
        return self.squares_x - 1

    @property
    def corners_y(self) -> int:
        """Inner corners along y."""
        return self.squares_y - 1

    @property
    def n_corners(self) -> int:
        """Number of inner corners (ids 0 .. n_corners - 1)."""
        return self.corners_x * self.corners_y

    @property
    def size_m(self) -> tuple[float, float]:
        """Width and height of the squared area in metres."""
        return self.squares_x * self.square_m, self.squares_y * self.square_m

    def object_points(self) -> np.ndarray:
        """Board coordinates of every inner corner, float32 (n_corners, 3) metres, row-major ids."""
        i = np.arange(self.n_corners)
        x = (i % self.corners_x + 1) * self.square_m
        y = (i // self.corners_x + 1) * self.square_m
        return np.stack([x, y, np.zeros_like(x)], axis=1).astype(np.float32)

    def outer_corner_ids(self) -> np.ndarray:
        """Ids of the four extreme inner corners (top-left, top-right, bottom-right, bottom-left), int (4,)."""
        nx, n = self.corners_x, self.n_corners
        return np.array([0, nx - 1, n - 1, n - nx])

    def opencv_board(self) -> Any:
        """The ``cv2.aruco.CharucoBoard`` (ChArUco only)."""
        if self.kind != "charuco":
            raise BracketryError("board: only a ChArUco board has an ArUco board object")
        dictionary = cv2.aruco.getPredefinedDictionary(getattr(cv2.aruco, self.dictionary))
        return cv2.aruco.CharucoBoard((self.squares_x, self.squares_y), self.square_m, self.marker_m, dictionary)

    def image(self, px_per_square: int, margin_squares: float = 0.5) -> np.ndarray:
        """The printable board, uint8 (H, W), white margin of ``margin_squares`` squares around the squared area.

        Pixel (col, row) covers board coordinates ``((col + 0.5) / px_per_square - margin_m, ...)``: the squared
        area starts ``margin_squares * px_per_square`` pixels in.
        """
        w = self.squares_x * px_per_square
        h = self.squares_y * px_per_square
        if self.kind == "charuco":
            inner = self.opencv_board().generateImage((w, h), marginSize=0, borderBits=1)
        else:
            yy, xx = np.mgrid[0:h, 0:w] // px_per_square
            inner = np.where((xx + yy) % 2 == 0, 0, 255).astype(np.uint8)
        m = round(margin_squares * px_per_square)
        return cv2.copyMakeBorder(inner, m, m, m, m, cv2.BORDER_CONSTANT, value=255)

    def to_dict(self) -> dict[str, Any]:
        """The definition as written to ``board.yaml``."""
        d: dict[str, Any] = {"kind": self.kind, "squares_x": self.squares_x, "squares_y": self.squares_y,
                             "square_m": float(self.square_m)}
        if self.kind == "charuco":
            d.update(marker_m=float(self.marker_m), dictionary=self.dictionary)
        return d

    @classmethod
    def from_dict(cls, d: Any) -> BoardSpec:
        """A board from its ``board.yaml`` dict; a missing or ill-typed key is a :class:`BracketryError`."""
        if not isinstance(d, dict):
            raise BracketryError("board definition must be a mapping (kind, squares_x, squares_y, square_m, ...)")
        unknown = set(d) - {"kind", "squares_x", "squares_y", "square_m", "marker_m", "dictionary"}
        if unknown:
            raise BracketryError(f"board definition: unknown keys {sorted(unknown)}")
        try:
            kind = str(d.get("kind", "charuco"))
            kw: dict[str, Any] = {"kind": kind, "squares_x": int(d["squares_x"]), "squares_y": int(d["squares_y"]),
                                  "square_m": float(d["square_m"])}
            if kind == "charuco":
                kw.update(marker_m=float(d["marker_m"]), dictionary=str(d.get("dictionary", "DICT_4X4_50")))
        except KeyError as exc:
            raise BracketryError(f"board definition: missing key {exc.args[0]}") from None
        except (TypeError, ValueError) as exc:
            raise BracketryError(f"board definition: {exc}") from None
        return cls(**kw)
