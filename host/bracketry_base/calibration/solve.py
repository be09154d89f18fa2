"""Stereo calibration from board detections: intrinsics and distortion per camera, extrinsics, rectification.

The robust selection (RANSAC over views), per camera:

1. the usable views are those with the board detected (at least :data:`MIN_CORNERS` corners) and sharp enough
   (:data:`~bracketry_base.calibration.detect.MAX_BLUR_PX`);
2. ``trials`` times, a random subset of ``subset`` views (seeded: ``numpy.random.default_rng(seed)``, the same
   draws every run) is calibrated (``cv2.calibrateCamera``, plumb_bob with k3 fixed at 0 unless asked); with that
   camera every usable view's pose is solved (``cv2.solvePnP``) and its reprojection RMS measured; views under
   ``inlier_px`` are its inliers;
3. the subset with the most inliers (ties: the smaller median RMS of its inliers) wins; the camera is calibrated
   again on all its inliers, the per-view RMS measured again, and the views above
   ``max(inlier_px, 3 x median RMS)`` dropped as outliers; two rounds.

Then the stereo pair: the views both cameras kept, on the corners both saw, ``cv2.stereoCalibrateExtended`` with
the intrinsics fixed, views above the same limit (per-view stereo RMS) dropped and the pair solved again; then
(``joint``) both cameras and the pair refined together from there (intrinsics as the starting guess; kept unless its
RMS grows by half: the rigid pair constrains the principal points, whose error it about halved on rendered
sessions, e.g. 0.98 -> 0.58 px and 0.78 -> 0.37 px at 640x400); ``cv2.stereoRectify`` (alpha 0, zero disparity
at infinity) gives R1, R2, P1, P2 with ``P2[0, 3] = -fx' * baseline_m``.

Errors that say what to do (:class:`~bracketry_base.errors.BracketryError`): too few usable views in a camera, too few
views the cameras share, images of different sizes.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Any

import cv2
import numpy as np

from bracketry_base.calibration.board import BoardSpec
from bracketry_base.calibration.detect import MAX_BLUR_PX, MIN_CORNERS, Detection, common
from bracketry_base.errors import BracketryError

#: fewest usable views of one camera, and of the pair
MIN_VIEWS = 6
MIN_STEREO_VIEWS = 5
#: default inlier limit of the per-view reprojection RMS, px
INLIER_PX = 1.0
TRIALS = 24
SUBSET = 10


@dataclass(frozen=True)
class CameraSolution:
    """One camera: K float64 (3, 3), D float64 (5,) plumb_bob, RMS over its used views (px), and per view index
    the reprojection RMS (px) of every usable view (used or dropped)."""

    K: np.ndarray
    D: np.ndarray
    rms_px: float
    view_rms_px: dict[int, float]
    used: list[int]


@dataclass(frozen=True)
class DroppedView:
    """A view left out, the camera ("left", "right", "stereo") and why (one line)."""

    view: int
    camera: str
    reason: str


@dataclass
class StereoSolution:
    """The calibrated pair.

    Attributes:
        size: (width, height) px. left, right: :class:`CameraSolution`.
        R float64 (3, 3), T float64 (3,) m: a point X in the left camera frame is ``R @ X + T`` in the right one.
        rectification: R1, R2 (3, 3), P1, P2 (3, 4), Q (4, 4) of ``cv2.stereoRectify``.
        stereo_rms_px: RMS of the stereo solve; stereo_view_rms_px: per view (max of the two cameras).
        used: views of the stereo solve; dropped: every view left out, with its reason.
        scheme: the robust selection's parameters (for the report).
    """

    size: tuple[int, int]
    left: CameraSolution
    right: CameraSolution
    R: np.ndarray
    T: np.ndarray
    rectification: dict[str, np.ndarray]
    stereo_rms_px: float
    stereo_view_rms_px: dict[int, float]
    used: list[int]
    dropped: list[DroppedView] = field(default_factory=list)
    scheme: dict[str, Any] = field(default_factory=dict)

    @property
    def baseline_m(self) -> float:
        """Distance between the optical centres, m."""
        return float(np.linalg.norm(self.T))

    def side(self, side: str) -> CameraSolution:
        """The solution of "left" or "right"."""
        return self.left if side == "left" else self.right


def _points(board: BoardSpec, det: Detection) -> tuple[np.ndarray, np.ndarray]:
    obj = board.object_points()[det.ids]
    return obj.reshape(-1, 1, 3), det.corners_px.reshape(-1, 1, 2).astype(np.float32)


def _calibrate(board: BoardSpec, dets: Sequence[Detection], size: tuple[int, int], flags: int
               ) -> tuple[np.ndarray, np.ndarray]:
    obj, img = zip(*(_points(board, d) for d in dets), strict=True)
    crit = (cv2.TERM_CRITERIA_COUNT + cv2.TERM_CRITERIA_EPS, 100, 1e-10)
    _rms, K, D, _r, _t = cv2.calibrateCamera(list(obj), list(img), size, None, None, flags=flags, criteria=crit)
    return K, np.asarray(D, np.float64).ravel()[:5]


def view_rms_px(board: BoardSpec, det: Detection, K: np.ndarray, D: np.ndarray) -> float:
    """Reprojection RMS (px) of one view with the camera (K, D): the board pose solved, its corners reprojected."""
    obj, img = _points(board, det)
    ok, rvec, tvec = cv2.solvePnP(obj, img, K, D, flags=cv2.SOLVEPNP_ITERATIVE)
    if not ok:
        return float("inf")
    proj, _ = cv2.projectPoints(obj, rvec, tvec, K, D)
    return float(np.sqrt(np.mean(np.sum((proj - img) ** 2, axis=2))))


def _robust_camera(board: BoardSpec, dets: dict[int, Detection], size: tuple[int, int], rng: np.random.Generator,
                   trials: int, subset: int, inlier_px: float, flags: int) -> CameraSolution:
    keys = sorted(dets)
    m = min(subset, len(keys))
    best: tuple[int, float, list[int]] | None = None
    for _ in range(trials if m < len(keys) else 1):
        pick = sorted(rng.choice(len(keys), size=m, replace=False))
        try:
            K, D = _calibrate(board, [dets[keys[i]] for i in pick], size, flags)
        except cv2.error:
            continue
        errs = {k: view_rms_px(board, dets[k], K, D) for k in keys}
        inl = [k for k in keys if errs[k] < inlier_px]
        score = (len(inl), -float(np.median([errs[k] for k in inl])) if inl else -np.inf)
        if best is None or score > (best[0], best[1]):
            best = (score[0], score[1], inl)
    if best is None or len(best[2]) < MIN_VIEWS:
        inl = keys
    else:
        inl = best[2]
    K = D = np.zeros(0)
    for _round in range(2):
        K, D = _calibrate(board, [dets[k] for k in inl], size, flags)
        errs = {k: view_rms_px(board, dets[k], K, D) for k in keys}
        limit = max(inlier_px, 3.0 * float(np.median([errs[k] for k in inl])))
        inl = [k for k in keys if errs[k] <= limit]
        if len(inl) < MIN_VIEWS:
            raise BracketryError(f"only {len(inl)} views agree on one camera model (at least {MIN_VIEWS} needed): "
                                 "check the board definition and capture more sharp views")
    K, D = _calibrate(board, [dets[k] for k in inl], size, flags)
    errs = {k: view_rms_px(board, dets[k], K, D) for k in keys}
    rms = float(np.sqrt(np.mean([errs[k] ** 2 for k in inl])))
    return CameraSolution(K, D, rms, errs, inl)


def _refit(board: BoardSpec, dets: dict[int, Detection], old: CameraSolution, K: np.ndarray, D: np.ndarray
           ) -> CameraSolution:
    """``old`` with the camera (K, D) of the joint refinement: per-view RMS measured again."""
    errs = {k: view_rms_px(board, d, K, D) for k, d in dets.items()}
    rms = float(np.sqrt(np.mean([errs[k] ** 2 for k in old.used])))
    return CameraSolution(K, D.ravel()[:5], rms, errs, old.used)


def _usable(dets: Sequence[Detection | None], side: str, max_blur_px: float, dropped: list[DroppedView]
            ) -> dict[int, Detection]:
    out = {}
    for k, d in enumerate(dets):
        if d is None:
            dropped.append(DroppedView(k, side, "board not detected"))
        elif d.n < MIN_CORNERS:
            dropped.append(DroppedView(k, side, f"only {d.n} corners"))
        elif not (d.blur_px <= max_blur_px):
            dropped.append(DroppedView(k, side, f"blurred ({d.blur_px:.1f} px > {max_blur_px:g} px)"))
        else:
            out[k] = d
    return out


def solve_stereo(left: Sequence[Detection | None], right: Sequence[Detection | None], board: BoardSpec,
                 size: tuple[int, int], seed: int = 0, trials: int = TRIALS, subset: int = SUBSET,
                 inlier_px: float = INLIER_PX, max_blur_px: float = MAX_BLUR_PX, fix_k3: bool = True,
                 joint: bool = True) -> StereoSolution:
    """Calibrate the pair from per-view detections (None: board not found), view k of ``left`` taken with view k
    of ``right``. ``size``: (width, height) px of every image. See the module docstring for the scheme."""
    if len(left) != len(right):
        raise BracketryError(f"{len(left)} left views but {len(right)} right views: give image pairs")
    dropped: list[DroppedView] = []
    flags = cv2.CALIB_FIX_K3 if fix_k3 else 0
    rng = np.random.default_rng(seed)
    sols = {}
    usable = {}
    for side, dets in (("left", left), ("right", right)):
        usable[side] = _usable(dets, side, max_blur_px, dropped)
        n = len(usable[side])
        if n == 0:
            raise BracketryError(f"the board was not found in any {side} image: check the board definition "
                                 "(board.yaml or --board) and that the board is in view of the {side} camera"
                                 .replace("{side}", side))
        if n < MIN_VIEWS:
            raise BracketryError(f"only {n} usable {side} views (board detected and sharp; at least {MIN_VIEWS} "
                                 "needed): capture more views")
        sols[side] = _robust_camera(board, usable[side], size, rng, trials, subset, inlier_px, flags)
        for k in sorted(set(usable[side]) - set(sols[side].used)):
            dropped.append(DroppedView(k, side, f"reprojection outlier ({sols[side].view_rms_px[k]:.2f} px)"))
    both = sorted(set(sols["left"].used) & set(sols["right"].used))
    pairs = {}
    for k in both:
        ids, a, b = common(usable["left"][k], usable["right"][k])
        if ids.size >= MIN_CORNERS:
            pairs[k] = (ids, a, b)
        else:
            dropped.append(DroppedView(k, "stereo", f"only {ids.size} corners seen by both cameras"))
    L, Rt = sols["left"], sols["right"]
    used = sorted(pairs)
    R: np.ndarray = np.eye(3)
    T: np.ndarray = np.zeros(3)
    per_view: dict[int, float] = {}
    stereo_rms = float("nan")
    for _round in range(3):
        if len(used) < MIN_STEREO_VIEWS:
            raise BracketryError(f"only {len(used)} views show the board to both cameras (at least "
                                 f"{MIN_STEREO_VIEWS} needed): capture views where both cameras see the board")
        obj = [board.object_points()[pairs[k][0]].reshape(-1, 1, 3) for k in used]
        ia = [pairs[k][1].reshape(-1, 1, 2) for k in used]
        ib = [pairs[k][2].reshape(-1, 1, 2) for k in used]
        crit = (cv2.TERM_CRITERIA_COUNT + cv2.TERM_CRITERIA_EPS, 100, 1e-10)
        out = cv2.stereoCalibrateExtended(obj, ia, ib, L.K.copy(), L.D.copy(), Rt.K.copy(), Rt.D.copy(), size,
                                          np.eye(3), np.zeros((3, 1)), flags=cv2.CALIB_FIX_INTRINSIC,
                                          criteria=crit)
        stereo_rms, R, T = float(out[0]), np.asarray(out[5], np.float64), np.asarray(out[6], np.float64).ravel()
        errs = np.asarray(out[-1]).reshape(len(used), 2).max(axis=1)
        per_view = {k: float(e) for k, e in zip(used, errs, strict=True)}
        limit = max(inlier_px, 3.0 * float(np.median(errs)))
        keep = [k for k in used if per_view[k] <= limit]
        if keep == used:
            break
        for k in sorted(set(used) - set(keep)):
            dropped.append(DroppedView(k, "stereo", f"stereo reprojection outlier ({per_view[k]:.2f} px)"))
        used = keep
    if joint:  # both cameras and their rigid pair refined together on the pair's views
        flags_j = cv2.CALIB_USE_INTRINSIC_GUESS | (cv2.CALIB_FIX_K3 if fix_k3 else 0)
        out = cv2.stereoCalibrateExtended(obj, ia, ib, L.K.copy(), L.D.copy(), Rt.K.copy(), Rt.D.copy(), size,
                                          R.copy(), T.reshape(3, 1).copy(), flags=flags_j, criteria=crit)
        if np.isfinite(out[0]) and float(out[0]) <= 1.5 * stereo_rms:
            stereo_rms, R, T = float(out[0]), np.asarray(out[5], np.float64), np.asarray(out[6], np.float64).ravel()
            errs = np.asarray(out[-1]).reshape(len(used), 2).max(axis=1)
            per_view = {k: float(e) for k, e in zip(used, errs, strict=True)}
            L = _refit(board, usable["left"], L, np.asarray(out[1], np.float64), np.asarray(out[2], np.float64))
            Rt = _refit(board, usable["right"], Rt, np.asarray(out[3], np.float64), np.asarray(out[4], np.float64))
    R1, R2, P1, P2, Q, _v1, _v2 = cv2.stereoRectify(L.K, L.D, Rt.K, Rt.D, size, R, T.reshape(3, 1),
                                                    flags=cv2.CALIB_ZERO_DISPARITY, alpha=0.0)
    scheme = {"trials": trials, "subset": subset, "seed": seed, "inlier_px": inlier_px,
              "max_blur_px": max_blur_px, "fix_k3": fix_k3, "min_views": MIN_VIEWS, "joint": joint}
    return StereoSolution(size, L, Rt, R, T, {"R1": R1, "R2": R2, "P1": P1, "P2": P2, "Q": Q}, stereo_rms,
                          per_view, used, sorted(dropped, key=lambda d: (d.view, d.camera)), scheme)
