"""The cause of a benchmark run's first loss of track, from its files
(:mod:`~bracketry_emulator.metrics.failure_causes`).

Reads the run's ``frames.csv`` (states, keypoints, map matches), its closed loop's ``ae.csv`` (exposures, gain,
saturated and dark shares) and, for the blur length, the trajectory's reference (TUM) and the left camera's focal
length (the rectified ``P[0, 0]`` of its camera_info, in pixels of the calibration's image size: the rendered size
for a synthetic suite).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from bracketry_base.errors import BracketryError
from bracketry_emulator.metrics.failure_causes import FrameLog, frame_log, loss_cause, rotation_blur_px
from bracketry_emulator.trajectory_io import read_frames_csv, read_tum


def blur_of(log: FrameLog, groundtruth: str | None, calibration: str | None) -> np.ndarray:
    """Rotation blur (px) of every frame of ``log``; NaN without a readable reference or calibration."""
    nan = np.full(len(log.states), np.nan)
    if not groundtruth or not calibration or not Path(groundtruth).is_file():
        return nan
    from bracketry_emulator.vo.calibration import CameraInfo, find_camera_info

    try:
        fx = float(CameraInfo.from_yaml(find_camera_info(calibration)[0]).P[0, 0])
        gt_t, gt_p = read_tum(groundtruth)
    except BracketryError:
        return nan
    return rotation_blur_px(gt_t, gt_p, log.times_s, log.camera_exposure_s, fx)


def run_frame_log(vo_dir: Path, run_dir: Path) -> FrameLog | None:
    """The frame log of the run localised in ``vo_dir`` from the closed loop in ``run_dir`` (its ``frames.csv`` and
    ``ae.csv``); None without a ``frames.csv``."""
    frames_csv = Path(vo_dir) / "frames.csv"
    if not frames_csv.is_file():
        return None
    return frame_log(read_frames_csv(frames_csv), Path(run_dir) / "ae.csv")


def run_failure_cause(vo_dir: Path, run_dir: Path, groundtruth: str | None, calibration: str | None) -> str | None:
    """The cause of the first loss of the run localised in ``vo_dir`` from the closed loop in ``run_dir``; None
    when it never lost track (or has no ``frames.csv``)."""
    log = run_frame_log(vo_dir, run_dir)
    return None if log is None else loss_cause(log, blur_of(log, groundtruth, calibration))
