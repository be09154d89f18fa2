"""Previews of frames already received, computed off the acquisition path at a bounded rate.

The pairing thread calls :meth:`PreviewHub.offer` with each paired set after the recorder took it. ``offer`` only
checks a clock and appends frame references to a bounded, drop-oldest queue (never blocks, never copies pixels);
per camera and bracket at most ``rate_hz`` frames per second are taken. One worker thread renders what the queue
holds: preview (PNG), histogram, over/under-exposed shares and the luminance the advisor uses.
"""

from __future__ import annotations

import collections
import logging
import threading
import time
from dataclasses import dataclass
from typing import Any

import numpy as np

from bracketry_rig.monitor.core import WHITE_DN, exposure_shares, histogram, luminance, preview_rgb, preview_step

log = logging.getLogger(__name__)


@dataclass(frozen=True)
class Preview:
    """The latest rendered frame of one camera and bracket.

    ``png``: the preview image; ``histogram``: luminance counts (64 bins over 0..white_dn); ``over``/``under``:
    over- and under-exposed shares (0..1); ``lum``: the subsampled luminance (float32 DN, for the advisor);
    ``t_ns``: the frame's host time; ``version``: increases with every render of this camera and bracket.
    """

    side: str
    bracket_index: int
    exposure_us: int
    t_ns: int
    png: bytes
    width: int
    height: int
    histogram: tuple[int, ...]
    over: float
    under: float
    lum: np.ndarray
    version: int


def encode_png(rgb: np.ndarray) -> bytes:
    """``(h, w, 3)`` uint8 RGB -> PNG bytes (OpenCV's encoder)."""
    import cv2

    ok, buf = cv2.imencode(".png", np.ascontiguousarray(rgb[..., ::-1]), [cv2.IMWRITE_PNG_COMPRESSION, 1])
    if not ok:
        raise ValueError("PNG encoding failed")
    return buf.tobytes()


class PreviewHub:
    """Bounded, drop-oldest hand-off from the pairing thread to one preview worker.

    Args:
        bayer: frames are RGGB mosaics (demosaiced in the preview).
        white_dn: the sensors' white level, DN.
        rate_hz: previews per second per camera and bracket, at most.
        max_items: queue length; when full the oldest frame is dropped (counted in ``dropped``).
        max_width: preview width, pixels.
    """

    def __init__(self, *, bayer: bool = True, white_dn: int = WHITE_DN, rate_hz: float = 1.0, max_items: int = 8,
                 max_width: int = 240) -> None:
        self.bayer, self.white_dn, self.max_width = bayer, white_dn, max_width
        self.period_s = 1.0 / rate_hz
        self.dropped = 0
        self.rendered = 0
        self.render_s = 0.0
        self._queue: collections.deque[tuple[str, int, int, int, Any]] = collections.deque(maxlen=max_items)
        self._taken: dict[tuple[str, int], float] = {}
        self._latest: dict[tuple[str, int], Preview] = {}
        self._lock = threading.Lock()
        self._wake = threading.Event()
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None

    def start(self) -> PreviewHub:
        self._thread = threading.Thread(target=self._run, name="monitor-previews", daemon=True)
        self._thread.start()
        return self

    def close(self) -> None:
        self._stop.set()
        self._wake.set()
        if self._thread is not None:
            self._thread.join(timeout=5.0)

    def offer(self, pset: Any) -> None:
        """Called on the pairing thread with a ``PairedSet``: cheap, never blocks."""
        ev = pset.event
        if ev is None:
            return
        now = time.monotonic()
        for side, frame in pset.frames.items():
            if frame is None or frame.image is None:
                continue
            key = (side, int(ev.bracket_index))
            if now - self._taken.get(key, -1e9) < self.period_s:
                continue
            self._taken[key] = now
            if len(self._queue) == self._queue.maxlen:
                self.dropped += 1
            self._queue.append((side, int(ev.bracket_index), int(ev.exposure_us), int(pset.stamp_ns), frame.image))
        self._wake.set()

    def add_image(self, side: str, bracket_index: int, exposure_us: int, image: np.ndarray,
                  t_ns: int | None = None) -> None:
        """Queue one raw image (e.g. from a file or a test) as if a paired set had brought it."""
        self._queue.append((side, bracket_index, exposure_us, time.time_ns() if t_ns is None else t_ns, image))
        self._wake.set()

    def _run(self) -> None:
        while not self._stop.is_set():
            self._wake.wait(0.5)
            self._wake.clear()
            self.drain()

    def drain(self) -> int:
        """Render everything queued (the worker does this; tests may call it); returns how many were rendered."""
        n = 0
        while True:
            try:
                side, bracket, exposure_us, t_ns, image = self._queue.popleft()
            except IndexError:
                return n
            try:
                self._render(side, bracket, exposure_us, t_ns, image)
                n += 1
            except Exception:  # a bad frame must not end the previews
                log.exception("preview of %s bracket %d failed", side, bracket)

    def _render(self, side: str, bracket: int, exposure_us: int, t_ns: int, image: np.ndarray) -> None:
        t0 = time.perf_counter()
        rgb = preview_rgb(image, bayer=self.bayer, white_dn=self.white_dn, max_width=self.max_width)
        step = preview_step(image.shape, self.bayer, self.max_width)
        lum = luminance(image, self.bayer, step)
        over, under = exposure_shares(lum, white_dn=self.white_dn)
        hist = histogram(lum, white_dn=self.white_dn)
        png = encode_png(rgb)
        with self._lock:
            old = self._latest.get((side, bracket))
            self._latest[(side, bracket)] = Preview(side, bracket, exposure_us, t_ns, png, rgb.shape[1], rgb.shape[0],
                                                    tuple(int(v) for v in hist), over, under, lum,
                                                    (old.version + 1) if old else 1)
            self.rendered += 1
            self.render_s += time.perf_counter() - t0

    def latest(self) -> dict[tuple[str, int], Preview]:
        """The latest preview of each (side, bracket index)."""
        with self._lock:
            return dict(self._latest)

    def clear(self) -> None:
        """Forget every preview and every frame not yet rendered (the bracket table changed)."""
        self._queue.clear()
        with self._lock:
            self._latest.clear()
        self._taken.clear()
