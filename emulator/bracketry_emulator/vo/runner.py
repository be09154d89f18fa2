"""Run the stereo VO over an emulated run folder and write its per-frame log and trajectory segments.

Input: a run folder ``<run>/<method>/`` holding ``images_left/<t_ns>.png`` and ``images_right/<t_ns>.png`` (RGGB
Bayer mosaics, 12-bit codes in 16-bit PNGs or 8-bit), listed in time order by ``times_images_left|right.txt`` (first
column, ns; or by the file names when those are absent); the k-th left image is paired with the k-th right image.
Output (``out_dir``): ``frames.csv`` (t_ns, state, segment, n_keypoints, coverage, n_stereo, n_ref_matches,
n_map_matches, reason) and ``CameraTrajectory<n>.txt`` (TUM, one per segment, n from 0 as the ORB-SLAM2 fork
numbers its maps).
"""

from __future__ import annotations

import itertools
import json
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np

from bracketry_base.errors import BracketryError
from bracketry_emulator.features.demosaic import to_gray8
from bracketry_emulator.features.orb import OrbExtractor, OrbSettings
from bracketry_emulator.trajectory_io import write_frames_csv, write_tum
from bracketry_emulator.vo.calibration import StereoRectifier
from bracketry_emulator.vo.tracker import FrameResult, StereoVO, VOSettings


def list_side_images(run_dir: str | Path, side: str) -> list[tuple[int, Path]]:
    """(t_ns, path) of one side of a run, in time order."""
    run = Path(run_dir)
    folder = run / f"images_{side}"
    if not folder.is_dir():
        raise BracketryError(f"{run} has no images_{side}/ folder")
    times_file = run / f"times_images_{side}.txt"
    if times_file.is_file():
        out = []
        for line in times_file.read_text().splitlines():
            tokens = line.split()
            if not tokens or tokens[0].startswith("#"):
                continue
            tok = tokens[0]  # RunWriter lines: "<t_ns> <t_ns> <target_exposure_ms>"; ORB-SLAM: "<t_ns>"
            t_ns = int(tok) if "." not in tok else round(float(tok) * 1e9)
            out.append((t_ns, folder / f"{t_ns}.png"))
        return out
    return sorted((int(p.stem), p) for p in folder.glob("*.png") if p.stem.isdigit())


def read_gray8(path: Path, bayer: bool = True) -> np.ndarray:
    """An image of a run as uint8 gray HxW (16-bit images are RGGB mosaics of 12-bit codes when ``bayer``)."""
    img = cv2.imread(str(path), cv2.IMREAD_UNCHANGED)
    if img is None:
        raise BracketryError(f"cannot read image {path}")
    return to_gray8(img, bayer=bayer)


@dataclass
class VORun:
    """Per-frame results of one run and the folder they were written to."""

    frames: list[FrameResult]
    out_dir: Path

    @property
    def n_segments(self) -> int:
        return len({f.segment for f in self.frames if f.tracked})


def estimate_row_offset(rect: StereoRectifier, left_gray8: np.ndarray, right_gray8: np.ndarray,
                        extractor: OrbExtractor | None = None) -> tuple[float, float, int]:
    """Measure the row disagreement ``y_right - y_left = a + b (x - cx)`` of a rectified pair from ORB matches.

    Brute-force matches (ratio 0.7, Hamming < 50, positive disparity), then a least-squares line on the matches
    within 3 px of the median. Returns (a px, b, number of matches used); (0, 0, n) when fewer than 50 matches.
    """
    ex = extractor or OrbExtractor(OrbSettings(n_features=2000))
    mask = rect.valid_mask()
    fl = ex.detect_and_compute(rect.rectify(left_gray8, "left"), mask)
    fr = ex.detect_and_compute(rect.rectify(right_gray8, "right"), mask)
    if len(fl) < 2 or len(fr) < 2:
        return 0.0, 0.0, 0
    knn = cv2.BFMatcher(cv2.NORM_HAMMING).knnMatch(fl.descriptors, fr.descriptors, k=2)
    pairs = [(p[0].queryIdx, p[0].trainIdx) for p in knn
             if len(p) == 2 and p[0].distance < 50 and p[0].distance < 0.7 * p[1].distance]
    if len(pairs) < 50:
        return 0.0, 0.0, len(pairs)
    li, ri = np.array(pairs).T
    ok = fl.xy_px[li, 0] > fr.xy_px[ri, 0]
    li, ri = li[ok], ri[ok]
    dy = (fr.xy_px[ri, 1] - fl.xy_px[li, 1]).astype(np.float64)
    x = fl.xy_px[li, 0].astype(np.float64) - rect.cx
    near = np.abs(dy - np.median(dy)) < 3.0
    if near.sum() < 50:
        return 0.0, 0.0, int(near.sum())
    a, b = np.linalg.lstsq(np.c_[np.ones(near.sum()), x[near]], dy[near], rcond=None)[0]
    return float(a), float(b), int(near.sum())


def png_frames(run_dir: str | Path, bayer: bool = True, max_frames: int | None = None
               ) -> tuple[int, Iterator[tuple[int, np.ndarray, np.ndarray]]]:
    """(number of frames, iterator of (t_ns, left gray8, right gray8)) of a run folder's PNG pairs (the k-th left
    with the k-th right), read lazily; BracketryError when the sides differ in count or are empty."""
    left = list_side_images(run_dir, "left")
    right = list_side_images(run_dir, "right")
    if not left or len(left) != len(right):
        raise BracketryError(f"{run_dir}: {len(left)} left and {len(right)} right images (need equal, > 0)")
    if max_frames is not None:
        left, right = left[:max_frames], right[:max_frames]
    pairs = list(zip(left, right))
    return len(pairs), ((tl, read_gray8(pl, bayer), read_gray8(pr, bayer)) for (tl, pl), (_tr, pr) in pairs)


def raw_to_gray8(frames: Iterator[tuple[int, np.ndarray, np.ndarray]], bayer: bool = True
                 ) -> Iterator[tuple[int, np.ndarray, np.ndarray]]:
    """(t_ns, left, right) images as a run stores them (uint16 12-bit / uint8 mosaics) -> the same in gray8, exactly
    as :func:`read_gray8` converts a decoded PNG."""
    for t_ns, left, right in frames:
        yield t_ns, to_gray8(left, bayer=bayer), to_gray8(right, bayer=bayer)


def run_vo(run_dir: str | Path, calibration_dir: str | Path, out_dir: str | Path,
           settings: VOSettings | None = None, bayer: bool = True, max_frames: int | None = None,
           fix_rows: bool = True) -> VORun:
    """Track a whole run folder (its PNG pairs); write ``frames.csv``, ``CameraTrajectory<n>.txt`` and
    ``rectification.json`` (see :func:`track_frames`)."""
    _n, frames = png_frames(run_dir, bayer, max_frames)
    return track_frames(frames, calibration_dir, out_dir, settings, fix_rows=fix_rows)


def track_frames(frames: Iterator[tuple[int, np.ndarray, np.ndarray]], calibration_dir: str | Path,
                 out_dir: str | Path, settings: VOSettings | None = None, max_frames: int | None = None,
                 fix_rows: bool = True) -> VORun:
    """Track stereo frames (t_ns, left gray8 HxW, right gray8 HxW; from files or in memory) with the built-in VO;
    write ``frames.csv``, ``CameraTrajectory<n>.txt`` and ``rectification.json``. Frames beyond ``max_frames``
    are consumed but not tracked.

    ``fix_rows``: measure the row disagreement of the rectified pair on the first frame
    (:func:`estimate_row_offset`) and correct the right image when it exceeds 0.5 px anywhere in the image
    (:meth:`StereoRectifier.correct_rows`); the measurement is written to ``rectification.json``.
    """
    it = iter(frames)
    first_frame = next(it, None)
    if first_frame is None:
        raise BracketryError("no stereo frame to track")
    _t0, first, first_r = first_frame
    rect = StereoRectifier.from_dir(calibration_dir, first.shape[1], first.shape[0])
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    info: dict = {"fx_px": rect.fx, "cx_px": rect.cx, "cy_px": rect.cy, "baseline_m": rect.baseline_m,
                  "row_offset_px": 0.0, "row_slope": 0.0, "row_matches": 0, "row_corrected": False}
    if fix_rows:
        a, b, n = estimate_row_offset(rect, first, first_r)
        info.update(row_offset_px=a, row_slope=b, row_matches=n)
        if abs(a) + abs(b) * rect.width_px / 2 > 0.5:
            rect.correct_rows(a, b)
            info["row_corrected"] = True
    (out / "rectification.json").write_text(json.dumps(info, indent=1))
    vo = StereoVO(rect, settings)
    results = []
    for k, (t_ns, gl, gr) in enumerate(itertools.chain([first_frame], it)):
        if max_frames is None or k < max_frames:
            results.append(vo.track(t_ns, gl, gr))
    write_frames_csv(out / "frames.csv", results)
    for seg in sorted({f.segment for f in results if f.tracked}):
        seg_frames = [f for f in results if f.tracked and f.segment == seg]
        write_tum(out / f"CameraTrajectory{seg}.txt", [f.t_ns * 1e-9 for f in seg_frames],
                  [f.pose_wc for f in seg_frames if f.pose_wc is not None])
    return VORun(results, out)
