"""Stereo visual odometry (OpenCV) mimicking the paper's modified ORB-SLAM2, and the ORB-SLAM file interface."""

from bracketry_emulator.trajectory_io import read_frames_csv, read_tum, write_tum
from bracketry_emulator.vo.calibration import CameraInfo, StereoRectifier, find_camera_info
from bracketry_emulator.vo.runner import VORun, run_vo
from bracketry_emulator.vo.tracker import FrameResult, StereoVO, VOSettings

__all__ = [
    "CameraInfo",
    "FrameResult",
    "StereoRectifier",
    "StereoVO",
    "VORun",
    "VOSettings",
    "find_camera_info",
    "read_frames_csv",
    "read_tum",
    "run_vo",
    "write_tum",
]
