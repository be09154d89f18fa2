"""ORB features with ORB-SLAM2's extractor settings, built on OpenCV.

ORB-SLAM2's ``ORBextractor`` (the paper's front end) does, per pyramid level ``l`` (scale ``s^l``):
FAST in 30x30 px cells at ``iniThFAST``, falling back to ``minThFAST`` in cells where nothing is found; an octree
that keeps ``n_l`` well-spread keypoints (``n_l`` geometric in the level, summing to ``nFeatures``); orientation by
intensity centroid (radius 15); rBRIEF descriptors (OpenCV's pattern) on a 7x7, sigma 2 Gaussian-blurred level.

This module reproduces that pipeline with these documented differences:

* FAST runs once per level at ``minThFAST`` with non-maximum suppression; a cell keeps its corners whose FAST score
  reaches ``iniThFAST`` when it has any, otherwise all of them (the same cell fallback, vectorised; ORB-SLAM runs
  FAST twice per cell, without suppression across cell edges).
* The octree distribution is replaced by a rank-in-cell selection on a grid of about ``n_l`` cells: the best corner
  of every cell first, then the second best of every cell, and so on until ``n_l``. Both keep the strongest corner of
  each region and spread the rest uniformly.
* Keypoints closer than 19 px (ORB-SLAM's EDGE_THRESHOLD) to a level's border are dropped (ORB-SLAM detects from
  16 px).
* Descriptors come from ``cv2.ORB.compute`` on each level with our keypoints and angles (same bit pattern, same blur).
"""

from __future__ import annotations

from collections.abc import Iterator
from dataclasses import dataclass, field

import cv2
import numpy as np

_POPCOUNT = np.array([bin(i).count("1") for i in range(256)], dtype=np.uint8)
_HALF_PATCH = 15


def hamming_distance(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Hamming distances between 256-bit ORB descriptors, broadcasting over leading axes.

    Args:
        a, b: uint8 arrays ``(..., 32)`` that broadcast against each other.
    Returns:
        int32 array of the broadcast leading shape, bits in 0..256.
    """
    return _POPCOUNT[np.bitwise_xor(a, b)].sum(axis=-1, dtype=np.int32)


@dataclass(frozen=True)
class OrbSettings:
    """ORB extractor parameters; the defaults are the paper's ORB-SLAM2 settings."""

    n_features: int = 3000
    scale_factor: float = 1.2
    n_levels: int = 13
    ini_th_fast: int = 15
    min_th_fast: int = 5
    cell_px: int = 30
    edge_px: int = 19

    def features_per_level(self) -> list[int]:
        """Desired keypoints per level, geometric in ``1/scale_factor`` and summing to ``n_features``."""
        factor = 1.0 / self.scale_factor
        first = self.n_features * (1 - factor) / (1 - factor**self.n_levels)
        counts = [round(first * factor**level) for level in range(self.n_levels - 1)]
        counts.append(max(self.n_features - sum(counts), 0))
        return counts


@dataclass
class Features:
    """Keypoints and descriptors of one image, positions in level-0 pixels.

    Attributes:
        xy_px: float32 Nx2 (x, y) in pixels of the input image.
        octave: int16 N pyramid level of each keypoint.
        angle_deg: float32 N orientation in degrees [0, 360).
        response: float32 N FAST score.
        descriptors: uint8 Nx32 rBRIEF descriptors.
        width_px, height_px: input image size.
    """

    xy_px: np.ndarray
    octave: np.ndarray
    angle_deg: np.ndarray
    response: np.ndarray
    descriptors: np.ndarray
    width_px: int
    height_px: int
    scale_factors: np.ndarray = field(default_factory=lambda: np.ones(1))

    def __len__(self) -> int:
        return len(self.xy_px)

    def subset(self, index: np.ndarray) -> Features:
        """The features selected by an index or boolean mask."""
        return Features(self.xy_px[index], self.octave[index], self.angle_deg[index], self.response[index],
                        self.descriptors[index], self.width_px, self.height_px, self.scale_factors)


def _circle_offsets() -> tuple[np.ndarray, np.ndarray]:
    ys, xs = np.mgrid[-_HALF_PATCH:_HALF_PATCH + 1, -_HALF_PATCH:_HALF_PATCH + 1]
    inside = xs**2 + ys**2 <= _HALF_PATCH**2 + _HALF_PATCH  # ORB-SLAM's u_max circle, rounded outwards
    return xs[inside].astype(np.int32), ys[inside].astype(np.int32)


_CIRCLE_X, _CIRCLE_Y = _circle_offsets()


def _ic_angle_deg(image: np.ndarray, x: np.ndarray, y: np.ndarray) -> np.ndarray:
    """Intensity-centroid orientation (degrees) of integer positions ``x, y`` (at least 15 px from the border)."""
    px = image[y[:, None] + _CIRCLE_Y[None, :], x[:, None] + _CIRCLE_X[None, :]].astype(np.float64)
    m10 = (px * _CIRCLE_X[None, :]).sum(axis=1)
    m01 = (px * _CIRCLE_Y[None, :]).sum(axis=1)
    return (np.degrees(np.arctan2(m01, m10)) % 360.0).astype(np.float32)


def _spread(xy: np.ndarray, response: np.ndarray, width: int, height: int, wanted: int) -> np.ndarray:
    """Indices of up to ``wanted`` keypoints spread over a grid of about ``wanted`` cells, best per cell first."""
    if len(xy) <= wanted:
        return np.arange(len(xy))
    side = max(np.sqrt(width * height / max(wanted, 1)), 1.0)
    ncols = max(int(np.ceil(width / side)), 1)
    cell = (xy[:, 1] // side).astype(np.int64) * ncols + (xy[:, 0] // side).astype(np.int64)
    order = np.lexsort((-response, cell))
    sorted_cell = cell[order]
    starts = np.r_[0, np.flatnonzero(np.diff(sorted_cell)) + 1]
    run_lengths = np.diff(np.r_[starts, len(order)])
    rank = np.arange(len(order)) - np.repeat(starts, run_lengths)
    pick = np.lexsort((-response[order], rank))[:wanted]
    return order[pick]


class OrbExtractor:
    """ORB-SLAM2-like ORB extractor (see the module docstring). Stateless apart from its OpenCV objects."""

    def __init__(self, settings: OrbSettings | None = None) -> None:
        self.settings = settings or OrbSettings()
        s = self.settings
        self._fast = cv2.FastFeatureDetector_create(  # type: ignore[attr-defined]
            threshold=s.min_th_fast, nonmaxSuppression=True, type=cv2.FastFeatureDetector_TYPE_9_16)
        self._orb = cv2.ORB_create(  # type: ignore[attr-defined]
            nfeatures=max(s.n_features, 1), scaleFactor=s.scale_factor, nlevels=1,
            edgeThreshold=_HALF_PATCH + 1, patchSize=2 * _HALF_PATCH + 1)
        self.scale_factors = np.array([s.scale_factor**level for level in range(s.n_levels)])

    def pyramid(self, gray8: np.ndarray) -> list[np.ndarray]:
        """Image pyramid, level ``l`` resized (bilinear) by ``1/scale_factor**l`` from the previous level."""
        h, w = gray8.shape
        levels = [gray8]
        for level in range(1, self.settings.n_levels):
            size = (round(w / self.scale_factors[level]), round(h / self.scale_factors[level]))
            if min(size) <= 2 * self.settings.edge_px:
                break
            levels.append(cv2.resize(levels[-1], size, interpolation=cv2.INTER_LINEAR))
        return levels

    def _detect_level(self, image: np.ndarray, wanted: int) -> tuple[np.ndarray, np.ndarray]:
        s = self.settings
        h, w = image.shape
        kps = self._fast.detect(image, None)
        if not kps or wanted <= 0:
            return np.zeros((0, 2), np.float32), np.zeros(0, np.float32)
        xy = cv2.KeyPoint_convert(kps).reshape(-1, 2)  # type: ignore[attr-defined]  # float32 pt, one C++ call
        resp = np.fromiter((k.response for k in kps), np.float32, len(kps))
        e = s.edge_px
        inside = (xy[:, 0] >= e) & (xy[:, 0] < w - e) & (xy[:, 1] >= e) & (xy[:, 1] < h - e)
        xy, resp = xy[inside], resp[inside]
        if len(xy) == 0:
            return xy, resp
        ncols = int(np.ceil(w / s.cell_px))
        cell = (xy[:, 1] // s.cell_px).astype(np.int64) * ncols + (xy[:, 0] // s.cell_px).astype(np.int64)
        # cells with a corner at iniThFAST or more (a cell's maximum reaches it exactly then)
        strong = resp >= s.ini_th_fast
        has_strong = np.zeros(int(cell.max()) + 1, bool)
        has_strong[cell[strong]] = True
        keep = strong | ~has_strong[cell]
        xy, resp = xy[keep], resp[keep]
        pick = _spread(xy, resp, w, h, wanted)
        return xy[pick], resp[pick]

    def _level_points(self, gray8: np.ndarray, mask: np.ndarray | None
                      ) -> Iterator[tuple[int, np.ndarray, np.ndarray, np.ndarray]]:
        """(level, level image, keypoints xy in level pixels, responses) of every level with keypoints in ``mask``."""
        if gray8.dtype != np.uint8 or gray8.ndim != 2:
            raise ValueError("ORB detection needs a uint8 HxW gray image")
        h0, w0 = gray8.shape
        wanted = self.settings.features_per_level()
        for level, image in enumerate(self.pyramid(gray8)):
            xy, resp = self._detect_level(image, wanted[level])
            if len(xy) == 0:
                continue
            if mask is not None:
                scale = self.scale_factors[level]
                x0 = np.clip((xy[:, 0] * scale).astype(int), 0, w0 - 1)
                y0 = np.clip((xy[:, 1] * scale).astype(int), 0, h0 - 1)
                ok = np.asarray(mask)[y0, x0] > 0
                xy, resp = xy[ok], resp[ok]
                if len(xy) == 0:
                    continue
            yield level, image, xy, resp

    def detect_xy(self, gray8: np.ndarray, mask: np.ndarray | None = None) -> np.ndarray:
        """The keypoint positions of :meth:`detect_and_compute` (float32 (N, 2), ``gray8`` pixels, same order)
        without orientations and descriptors (a third of the cost): the descriptor step drops no keypoint, since
        the detector keeps ``edge_px`` (19) from every border and ORB's descriptor border is 16 px."""
        if self.settings.edge_px < _HALF_PATCH + 1:  # then the descriptor step may drop keypoints: do it
            return self.detect_and_compute(gray8, mask).xy_px
        out = [xy * self.scale_factors[level] for level, _image, xy, _resp in self._level_points(gray8, mask)]
        return np.concatenate(out).astype(np.float32) if out else np.zeros((0, 2), np.float32)

    def detect_and_compute(self, gray8: np.ndarray, mask: np.ndarray | None = None) -> Features:
        """Detect and describe keypoints.

        Args:
            gray8: uint8 HxW gray image.
            mask: optional uint8/bool HxW, keypoints only where non-zero (level-0 pixels).
        Returns:
            :class:`Features` (at most ``n_features`` keypoints, positions in ``gray8`` pixels).
        """
        h0, w0 = gray8.shape
        out_xy, out_oct, out_ang, out_resp, out_desc = [], [], [], [], []
        for level, image, xy, resp in self._level_points(gray8, mask):
            scale = self.scale_factors[level]
            ix = np.rint(xy[:, 0]).astype(np.int32)
            iy = np.rint(xy[:, 1]).astype(np.int32)
            angle = _ic_angle_deg(image, ix, iy)
            kps = [cv2.KeyPoint(float(x), float(y), 31.0, float(a), float(r), 0, i)
                   for i, (x, y, a, r) in enumerate(zip(xy[:, 0], xy[:, 1], angle, resp))]
            kps_out, desc = self._orb.compute(image, kps)
            if desc is None or not kps_out:
                continue
            idx = np.array([k.class_id for k in kps_out], dtype=np.int64)
            out_xy.append(xy[idx] * scale)
            out_oct.append(np.full(len(idx), level, np.int16))
            out_ang.append(angle[idx])
            out_resp.append(resp[idx])
            out_desc.append(desc)
        if not out_xy:
            return Features(np.zeros((0, 2), np.float32), np.zeros(0, np.int16), np.zeros(0, np.float32),
                            np.zeros(0, np.float32), np.zeros((0, 32), np.uint8), w0, h0, self.scale_factors)
        return Features(np.concatenate(out_xy).astype(np.float32), np.concatenate(out_oct),
                        np.concatenate(out_ang), np.concatenate(out_resp), np.concatenate(out_desc), w0, h0,
                        self.scale_factors)
