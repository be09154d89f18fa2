"""The live state of a board capture for the monitor page: the latest pair's corners and previews, the decision on
it, and the coverage bars of the views kept so far (:class:`bracketry_base.calibration.coverage.Coverage`).

The capture (``bracketry calibrate capture``) calls :meth:`CaptureFeed.offer` for every stereo pair; the monitor's
HTTP thread reads :meth:`CaptureFeed.snapshot` and :meth:`CaptureFeed.preview_png` (``GET /api/calibration``,
``GET /api/calibration/{side}.png``). One lock guards the state; the previews are encoded by the capture's thread.
"""

from __future__ import annotations

import threading
from typing import Any

import cv2
import numpy as np

from bracketry_base.calibration.board import BoardSpec
from bracketry_base.calibration.coverage import MIN_VIEWS_ENOUGH, Coverage
from bracketry_base.calibration.detect import Detection

#: width of the previews the page shows, px
PREVIEW_WIDTH = 320


class CaptureFeed:
    """What the page shows of a running capture (thread-safe)."""

    def __init__(self, board: BoardSpec, size: tuple[int, int], max_blur_px: float | None = None) -> None:
        self.coverage = Coverage(board, size) if max_blur_px is None else Coverage(board, size, max_blur_px)
        self._lock = threading.Lock()
        self._version = 0
        self._offered = 0
        self._last: dict[str, Any] | None = None
        self._png: dict[str, bytes] = {}
        self._done = False

    def offer(self, gray8: tuple[np.ndarray, np.ndarray], dets: tuple[Detection | None, Detection | None]
              ) -> tuple[bool, str]:
        """Judge one stereo pair (uint8 grey images (H, W) and their detections), keep it when worth it, and
        publish it. Returns (kept, why)."""
        kept, why = self.coverage.offer(*dets)
        w, h = self.coverage.size
        corners = {side: [] if d is None else np.round(d.corners_px / [w, h], 5).tolist()
                   for side, d in zip(("left", "right"), dets, strict=True)}
        pngs = {}
        for side, img in zip(("left", "right"), gray8, strict=True):
            scale = PREVIEW_WIDTH / img.shape[1]
            small = cv2.resize(img, (PREVIEW_WIDTH, max(1, round(img.shape[0] * scale))), interpolation=cv2.INTER_AREA)
            ok, buf = cv2.imencode(".png", small)
            if ok:
                pngs[side] = buf.tobytes()
        with self._lock:
            self._offered += 1
            self._version += 1
            self._last = {"kept": kept, "why": why, "corners": corners}
            self._png = pngs
        return kept, why

    def finish(self) -> None:
        """The capture has ended (the page says so)."""
        with self._lock:
            self._done = True
            self._version += 1

    def snapshot(self) -> dict[str, Any]:
        """``GET /api/calibration``: see MONITOR.md."""
        with self._lock:
            st = self.coverage.status()
            return {"active": True, "done": self._done, "version": self._version, "offered": self._offered,
                    "size": list(self.coverage.size), "board": self.coverage.board.to_dict(),
                    "min_views": MIN_VIEWS_ENOUGH, **st, "last": self._last}

    def preview_png(self, side: str) -> bytes | None:
        """The latest pair's preview of ``side`` (PNG, :data:`PREVIEW_WIDTH` px wide), or None."""
        with self._lock:
            return self._png.get(side)
