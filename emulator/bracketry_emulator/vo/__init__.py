"""Stereo visual odometry (OpenCV) mimicking the paper's modified ORB-SLAM2, and the ORB-SLAM file interface."""

from bracketry_emulator.vo.calibration import CameraInfo, StereoRectifier, find_camera_info
from bracketry_emulator.vo.runner import VORun, read_frames_csv, run_vo
from bracketry_emulator.vo.tracker import FrameResult, StereoVO, VOSettings
from bracketry_emulator.vo.tum import read_tum, write_tum

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
