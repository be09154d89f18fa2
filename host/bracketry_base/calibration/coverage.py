"""Which board views to keep while capturing, and how well the kept ones cover what a calibration needs.

The view parameters and the bars are ROS ``camera_calibration``'s (the tool BorealHDR calibrated with), so a field
user reads them the same way. From the board's four outer inner corners in the image (for a partial ChArUco view,
projected through the homography fitted to the corners found):

- ``x``, ``y``: the mean corner position, the image shrunk by half the board's apparent size on each side, in 0..1;
- ``size``: sqrt(board area / image area);
- ``skew``: ``min(1, 2 |pi/2 - angle|)`` of the board's top-left corner angle.

A view is kept when the board is found in both images (:data:`MIN_CORNERS_BOTH` corners both cameras see), sharp
enough (:data:`~bracketry_base.calibration.detect.MAX_BLUR_PX`, the blur measure of :mod:`.detect`, in both), and not a
near-duplicate: the sum of absolute differences of its (x, y, size, skew) to every kept view's exceeds
:data:`MIN_DISTANCE` (ROS: 0.2). The bars are each parameter's span over the kept views divided by the span ROS
asks for (x 0.7, y 0.7, size 0.4, skew 0.5; small sizes and skews are not rewarded: their lower end counts as 0),
capped at 1. The set is *enough* when every bar is full and at least :data:`MIN_VIEWS_ENOUGH` views are kept, or
when :data:`MAX_VIEWS_ENOUGH` views are kept (ROS: 40).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import cv2
import numpy as np

from bracketry_base.calibration.board import BoardSpec
from bracketry_base.calibration.detect import MAX_BLUR_PX, Detection, common

PARAMS = ("x", "y", "size", "skew")
#: the span of each parameter that fills its bar (ROS camera_calibration's param_ranges)
PARAM_RANGES = (0.7, 0.7, 0.4, 0.5)
MIN_DISTANCE = 0.2
MIN_VIEWS_ENOUGH = 15
MAX_VIEWS_ENOUGH = 40
MIN_CORNERS_BOTH = 8


def outer_corners(board: BoardSpec, det: Detection) -> np.ndarray:
    """The board's four outer inner corners in the image (top-left, top-right, bottom-right, bottom-left), float64
    (4, 2) px: from the detection when found, else through the homography fitted to the detected corners."""
    obj = board.object_points()[:, :2].astype(np.float64)
    want = board.outer_corner_ids()
    if np.all(np.isin(want, det.ids)):
        pos = np.searchsorted(det.ids, want)
        return det.corners_px[pos].astype(np.float64)
    H, _mask = cv2.findHomography(obj[det.ids], det.corners_px.astype(np.float64), 0)
    if H is None:
        return det.corners_px[[0, 0, -1, -1]].astype(np.float64)
    p = cv2.perspectiveTransform(obj[want].reshape(-1, 1, 2), H)
    return p.reshape(4, 2)


def _angle(a: np.ndarray, b: np.ndarray, c: np.ndarray) -> float:
    ab, cb = a - b, c - b
    cos = float(ab @ cb / max(np.linalg.norm(ab) * np.linalg.norm(cb), 1e-12))
    return math.acos(max(-1.0, min(1.0, cos)))


def view_params(board: BoardSpec, det: Detection, size: tuple[int, int]) -> tuple[float, float, float, float]:
    """(x, y, size, skew) of a view (module docstring), each in 0..1. ``size``: (width, height) px."""
    w, h = size
    quad = outer_corners(board, det)
    x, y = quad[:, 0], quad[:, 1]
    area = 0.5 * abs(float(np.dot(x, np.roll(y, 1)) - np.dot(y, np.roll(x, 1))))
    border = math.sqrt(area)
    mx, my = float(det.corners_px[:, 0].mean()), float(det.corners_px[:, 1].mean())
    px = min(1.0, max(0.0, (mx - border / 2) / max(w - border, 1e-9)))
    py = min(1.0, max(0.0, (my - border / 2) / max(h - border, 1e-9)))
    psize = math.sqrt(area / (w * h))
    skew = min(1.0, 2.0 * abs(math.pi / 2 - _angle(quad[3], quad[0], quad[1])))
    return px, py, psize, skew


@dataclass
class Coverage:
    """The views kept so far and their coverage (the capture's state; pure, fed one stereo pair at a time).

    Attributes:
        board: the board; size: (width, height) px; max_blur_px: the sharpness limit.
        kept: parameters of every kept view (of the left camera), in the order kept.
    """

    board: BoardSpec
    size: tuple[int, int]
    max_blur_px: float = MAX_BLUR_PX
    kept: list[tuple[float, float, float, float]] = field(default_factory=list)

    def judge(self, left: Detection | None, right: Detection | None) -> tuple[bool, str]:
        """Whether a stereo pair is worth keeping, and why (one short phrase). Does not keep it."""
        if left is None or right is None:
            missing = " and ".join(s for s, d in (("left", left), ("right", right)) if d is None)
            return False, f"board not found ({missing})"
        ids, _a, _b = common(left, right)
        if ids.size < MIN_CORNERS_BOTH:
            return False, f"only {ids.size} corners seen by both cameras"
        blur = max(left.blur_px, right.blur_px)
        if not blur <= self.max_blur_px:
            return False, f"blurred ({blur:.1f} px > {self.max_blur_px:g} px)"
        p = view_params(self.board, left, self.size)
        if self.kept:
            d = min(sum(abs(a - b) for a, b in zip(p, q, strict=True)) for q in self.kept)
            if d <= MIN_DISTANCE:
                return False, f"too close to a kept view ({d:.2f} <= {MIN_DISTANCE:g}): move or tilt the board"
        return True, "new view"

    def offer(self, left: Detection | None, right: Detection | None) -> tuple[bool, str]:
        """:meth:`judge`, and keep the pair when it is worth it."""
        ok, why = self.judge(left, right)
        if ok:
            assert left is not None
            self.kept.append(view_params(self.board, left, self.size))
        return ok, why

    def bars(self) -> dict[str, float]:
        """Coverage of each parameter, 0..1 (module docstring)."""
        if not self.kept:
            return dict.fromkeys(PARAMS, 0.0)
        arr = np.array(self.kept)
        lo, hi = arr.min(axis=0), arr.max(axis=0)
        lo[2:] = 0.0  # small sizes and skews are not rewarded
        return {k: float(min(1.0, (hi[i] - lo[i]) / PARAM_RANGES[i])) for i, k in enumerate(PARAMS)}

    @property
    def enough(self) -> bool:
        """Whether the kept set is enough to calibrate (module docstring)."""
        n = len(self.kept)
        return n >= MAX_VIEWS_ENOUGH or (n >= MIN_VIEWS_ENOUGH and all(v >= 1.0 for v in self.bars().values()))

    def status(self) -> dict[str, object]:
        """The monitor's view of the capture: kept count, bars, enough, and what is missing."""
        bars = self.bars()
        short = [k for k, v in bars.items() if v < 1.0]
        if self.enough:
            advice = "enough views: stop and solve"
        elif short:
            advice = "move the board to fill: " + ", ".join(short)
        else:
            advice = f"keep going: {len(self.kept)} of {MIN_VIEWS_ENOUGH} views"
        return {"kept": len(self.kept), "bars": bars, "enough": self.enough, "advice": advice}
