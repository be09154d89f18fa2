"""The oracle's step search (method id ``oracle``): per step, the exposure of a fine grid that tracks best on its own
among those that keep the link to the recent frames (a stand-in for SLAM's local map). NON-CAUSAL: it reads the next
step's brackets, which no camera can. The oracle is a control row that frames the benchmark's results (the best
exposure sequence found), not an AE method: this search proposes its own candidate sequence, and the benchmark's
oracle row is the best whole run of each trajectory and repeat among this search's closed-loop run and every other
row's (:mod:`bracketry_emulator.benchmark.oracle_rows`: success, then time before failure, distance tracked, RTE), so
it keeps at least as many walks as any row benchmarked beside it, at no SLAM run beyond this search's. A one-step
score alone cannot promise that (ORB-SLAM3 is not deterministic run to run, and what keeps its map is more than the
next frame's tracks).

Two scores of a candidate exposure ``e`` for step k+1, at step k::

    tracked(F, G, a) = cross-checked ORB matches between frames F and G with Hamming distance <= 40 whose keypoint
                       moved at most a x 8 % of the image size, / ORB_FEATURES
    link(e)          = mean over the last MAP_WINDOW frames F_j as the method got them (j = k, k-1, ..., a = k+1-j
                       steps before k+1) of tracked(F_j, I_{k+1}(e), a)
    quality(e)       = tracked(I_k(e), I_{k+1}(e), 1)

where ``I_k(e)`` is the AE camera's image of step k emulated at ``e`` (the closed loop's own emulation, the same
source bracket a method asking for ``e`` gets), turned into 8-bit gray as the localisation sees it
(:func:`~bracketry_emulator.features.demosaic.to_gray8`) and area-downscaled to at most :data:`WORK_WIDTH` columns.
``link`` is what keeps SLAM tracking at the next frame: ORB-SLAM matches each frame to its local map, points made
from the last keyframes (the window), not to the last frame alone. ``quality`` is what keeps it tracking after
that: how well exposure ``e`` tracks on its own (noise, clipping and blur lose features; it does not depend on the
exposure the method happens to hold, so a dark stretch is not a trap: a score of the link alone rewards staying
near the current exposure, however poor: on a demo-size suite's forest canopy walk it held 1 to 8 ms with 55 to
85 % of the view dark, where AE50 went to 64 ms, and the built-in VO could not initialise on its first 3 frames).
The answer for step k+1: among the exposures whose link reaches :data:`LINK_SHARE` (tracking holds), the best
of max(quality, link) (at a change of light no exposure suits both steps, so ``quality`` underrates the one that
suits the new light, which its link shows); when none does, the best link (the smallest break); when no link
reaches :data:`MIN_SHARE` (the start, or a frame too dark or blank to track from), the best quality. Scores within
5 % of the best count as equal and then the one nearest the current target (in stops) wins, then the shorter (less
motion blur); the current target when nothing is tracked under any ``e``.

Why this score: the benchmark's localisation (ORB-SLAM3, and the built-in VO) tracks ORB features frame to frame,
so the share of features that survive into the next frame under one exposure is the quantity that decides whether
it keeps tracking; it penalises what a gradient or feature count alone does not: noise and clipping (features that
do not repeat), and motion blur at long exposures of a moving camera (the next frame is blurred over its own
interval), and it rewards what the tracker needs at a change of light: a next frame that looks like the current one.

Grid: exposures ``hi_ms * 2**(-k / steps_per_stop)`` for k = 0, 1, ... down to ``lo_ms`` (default 0.25..64 ms in
half stops: 17 exposures, 64 ms being the loop's longest), clipped to the loop's bounds. Searched coarse to fine:
every whole stop (9 exposures), then the two grid neighbours of the answer among them. Cost per evaluated exposure:
two emulations (steps k and k+1), two ORB extractions and ``window`` + 1 matchings (the window's features are
kept, not extracted again), against one emulation, one extraction and one matching for a one-step score: on the
shared 2-core machine under load (11 ms an extraction, 36 ms a 500 x 500 cross-checked matching) about 3.2 times its
cost per exposure, over 11 exposures a step (about 1 to 1.8 s a step at 320x200 there, on that load).

What the method sees (beside the image): ``meta["look_ahead"](target_us, offset)`` -> uint16 HxW Bayer image of
the AE camera at ``target_us`` for the current step (offset 0) or the next one (offset 1; None at the last step),
given by the closed loop (:mod:`.scheduler`) to methods that declare ``looks_ahead = True``.
"""

from __future__ import annotations

import math
from collections import deque
from collections.abc import Callable
from typing import Any

import cv2
import numpy as np

from ..features.demosaic import to_gray8

#: ORB features extracted per image at most (4 pyramid levels at <= 320 px: a cheap stand-in for ORB-SLAM3's)
ORB_FEATURES = 500
#: FAST threshold of the extraction (8-bit levels): weak corners (noise, quantisation) are not features
FAST_THRESHOLD = 20
#: a match counts as tracked when its keypoint moved at most this share of the image's larger side between frames
MAX_MOTION = 0.08
#: largest Hamming distance (of 256 bits) of a match that counts as tracked
MAX_HAMMING = 40
#: the score's images are area-downscaled to at most this many columns (for speed; ORB's pyramid starts there)
WORK_WIDTH = 320
#: scores within this share of the best are as good: the oracle then keeps nearest its current exposure (a steady
#: exposure is easier to track than one that jumps between equal scores)
KEEP_WITHIN = 0.05
#: below this best link the current frame is too poor to judge from (dark, blank): each exposure is then judged
#: by its quality alone
MIN_SHARE = 0.05
#: an exposure keeps the link to the map when at least this share of the map's features (50 of 500) is tracked into
#: the next frame under it: ORB-SLAM keeps tracking with 30 inlier map matches (``Tracking::TrackLocalMap``)
LINK_SHARE = 0.1

#: frames the score matches the next one against: the current frame and the ones before it, as the method got them
#: (ORB-SLAM tracks against its local map, built from the last keyframes, not against the last frame alone)
MAP_WINDOW = 3

#: a frame's ORB features: keypoint positions (float32 Nx2, px), descriptors (uint8 Nx32), image size (px)
Features = tuple[np.ndarray, np.ndarray, int]
LookAhead = Callable[[float, int], "np.ndarray | None"]


def exposure_grid_us(lo_ms: float, hi_ms: float, steps_per_stop: int, bounds_us: tuple[float, float]) -> list[float]:
    """The oracle's grid (us, ascending): ``hi_ms * 2**(-k/steps_per_stop)`` down to ``lo_ms``, clipped to
    ``bounds_us`` (duplicates after clipping removed)."""
    n = math.floor(math.log2(hi_ms / lo_ms) * steps_per_stop + 1e-9) + 1
    raw = [hi_ms * 1000.0 * 2.0 ** (-k / steps_per_stop) for k in range(n)]
    lo_b, hi_b = bounds_us
    return sorted({round(min(max(e, lo_b), hi_b), 3) for e in raw})


def work_gray8(image: np.ndarray, width: int = WORK_WIDTH) -> np.ndarray:
    """uint8 gray of a uint16 HxW Bayer mosaic as the localisation sees it, area-downscaled to ``width`` columns."""
    gray = to_gray8(image)
    h, w = gray.shape
    if w <= width:
        return gray
    return cv2.resize(gray, (width, max(1, round(h * width / w))), interpolation=cv2.INTER_AREA)


class ORBTracker:
    """ORB features of 8-bit images and the share of them tracked between two images."""

    def __init__(self, n_features: int = ORB_FEATURES, max_hamming: int = MAX_HAMMING) -> None:
        self.n_features, self.max_hamming = n_features, max_hamming
        self.orb = cv2.ORB_create(  # type: ignore[attr-defined]
            nfeatures=n_features, nlevels=4, fastThreshold=FAST_THRESHOLD, edgeThreshold=15, patchSize=15)
        self.matcher = cv2.BFMatcher(cv2.NORM_HAMMING, crossCheck=True)

    def describe(self, gray8: np.ndarray) -> Features | None:
        """ORB keypoint positions (float32 Nx2, px) and descriptors (uint8 Nx32) of ``gray8``; None without any."""
        kps, desc = self.orb.detectAndCompute(gray8, None)
        if desc is None or not len(desc):
            return None
        xy = np.array([k.pt for k in kps], np.float32).reshape(-1, 2)
        return xy, desc, max(gray8.shape)

    def tracked_share(self, a: Features | None, b: Features | None, steps: int = 1) -> float:
        """Cross-checked matches of ``a``'s descriptors into ``b``'s within :attr:`max_hamming` whose keypoint moved
        at most ``steps`` x :data:`MAX_MOTION` of the image size (``b`` is ``steps`` frames after ``a``),
        / ``n_features``."""
        if a is None or b is None:
            return 0.0
        (xy_a, da, size), (xy_b, db, _) = a, b
        matches = self.matcher.match(da, db)
        if not matches:
            return 0.0
        qi = np.fromiter((m.queryIdx for m in matches), np.intp, len(matches))
        ti = np.fromiter((m.trainIdx for m in matches), np.intp, len(matches))
        dist = np.fromiter((m.distance for m in matches), np.float32, len(matches))
        moved = np.linalg.norm(xy_a[qi] - xy_b[ti], axis=1)
        ok = (dist <= self.max_hamming) & (moved <= MAX_MOTION * steps * size)
        return int(np.count_nonzero(ok)) / float(self.n_features)


class OracleAE:
    """Non-causal control: the grid exposure that maximises the share of ORB features tracked into the next frame
    (see the module docstring)."""

    name = "oracle"
    #: the closed loop gives this method ``meta["look_ahead"]`` (the next step's images): not a causal method
    looks_ahead = True
    #: shown in reports
    non_causal = True
    #: relative cost of one step (~15 emulations and ORB extractions), for balancing worker processes
    step_cost = 150

    def __init__(self, lo_ms: float = 0.25, hi_ms: float = 64.0, steps_per_stop: int = 2,
                 window: int = MAP_WINDOW) -> None:
        if not (0 < lo_ms < hi_ms) or steps_per_stop < 1 or window < 1:
            raise ValueError(f"oracle grid needs 0 < lo_ms < hi_ms, steps_per_stop >= 1 and window >= 1, got {lo_ms}, "
                             f"{hi_ms}, {steps_per_stop}, {window}")
        self.lo_ms, self.hi_ms, self.steps_per_stop = float(lo_ms), float(hi_ms), int(steps_per_stop)
        self.window = int(window)
        self.tracker = ORBTracker()
        #: per step: {exposure_us: quality} and {exposure_us: link to the map} of the last decision (for inspection
        #: and tests)
        self.last_scores: dict[float, float] = {}
        self.last_links: dict[float, float] = {}
        #: the features of the last ``window`` frames as the method got them, newest first (its stand-in map)
        self._map: deque[Features | None] = deque(maxlen=self.window)

    def reset(self, init_exposure_us: float) -> None:
        self.last_scores = {}
        self.last_links = {}
        self._map = deque(maxlen=self.window)

    def next_exposure_us(self, image: np.ndarray, exposure_us: float, meta: dict[str, Any]) -> float:
        look: LookAhead | None = meta.get("look_ahead")
        if look is None:
            raise ValueError("the oracle needs the closed loop's look-ahead (meta['look_ahead']); it runs only in "
                             "bracketry's closed loop")
        grid = exposure_grid_us(self.lo_ms, self.hi_ms, self.steps_per_stop,
                                tuple(meta.get("bounds_us", (1.0, 1e9))))  # type: ignore[arg-type]
        if look(grid[0], 1) is None:  # the last step: its answer is never used
            return float(exposure_us)
        self._map.appendleft(self._describe(image))
        links: dict[float, float] = {}
        owns: dict[float, float] = {}

        def evaluate(e: float) -> None:
            if e not in links:
                nxt = self._describe(look(e, 1))
                links[e] = self.map_share(nxt)
                owns[e] = self.tracker.tracked_share(self._describe(look(e, 0)), nxt)

        for i in range(len(grid) - 1, -1, -self.steps_per_stop):  # every whole stop, then the best one's neighbours
            evaluate(grid[i])
        i = grid.index(self._decide(links, owns, exposure_us))
        for j in (i - 1, i + 1):
            if 0 <= j < len(grid):
                evaluate(grid[j])
        self.last_scores = dict(sorted(owns.items()))
        self.last_links = dict(sorted(links.items()))
        if max(max(links.values()), max(owns.values())) <= 0.0:
            return float(exposure_us)
        return self._decide(links, owns, exposure_us)

    def map_share(self, b: Features | None) -> float:
        """The mean over the stand-in map's frames (the current one and up to ``window - 1`` before it) of the share
        of their features tracked into ``b`` (the next frame; a frame ``a`` steps older gets ``a + 1`` times the
        motion allowance)."""
        shares = [self.tracker.tracked_share(f, b, age + 1) for age, f in enumerate(self._map)]
        return float(np.mean(shares)) if shares else 0.0

    @staticmethod
    def _decide(links: dict[float, float], owns: dict[float, float], current_us: float) -> float:
        """The answer among the evaluated exposures (module docstring): the best of quality and link among those that
        keep the link to the map; without any, the best link; without a link worth the name, the best quality."""
        linked = {e: max(owns[e], v) for e, v in links.items() if v >= LINK_SHARE}
        if linked:
            return OracleAE._pick(linked, current_us)
        if max(links.values()) >= MIN_SHARE:
            return OracleAE._pick(links, current_us)
        return OracleAE._pick(owns, current_us)

    @staticmethod
    def _pick(scores: dict[float, float], current_us: float) -> float:
        """The exposure of the best score; among those within :data:`KEEP_WITHIN` of it, the nearest (in stops)
        to ``current_us``, then the shortest."""
        best = max(scores.values())
        near = [e for e, v in scores.items() if v >= best * (1.0 - KEEP_WITHIN)]
        return min(near, key=lambda e: (abs(math.log2(e / current_us)), e))

    def _describe(self, image: np.ndarray | None) -> Features | None:
        return None if image is None else self.tracker.describe(work_gray8(image))
