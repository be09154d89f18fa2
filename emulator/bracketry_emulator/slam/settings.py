"""ORB-SLAM3 stereo settings (OpenCV YAML, the ``File.version: "1.0"`` format) from our rectified stereo calibration.

What ORB-SLAM3's ``Settings`` parser demands, learnt the hard way:

* every real-valued entry is written with a decimal point (``Stereo.ThDepth: 35.0``): it reads them with
  ``FileNode::isReal`` and an integer ``35`` makes the constructor fail with "unknown exception";
* integer entries (``Camera.fps``, ``Camera.width``, ``ORBextractor.nFeatures``...) must be integers, so the bracket
  cycle rate is rounded to the nearest whole frame per second (at least 1; ORB-SLAM uses it only as the maximum
  number of frames between keyframes);
* ``Camera.type: "Rectified"`` segfaults in this build; ``"PinHole"`` with identical ``Camera1.*`` / ``Camera2.*``
  intrinsics and ``Stereo.T_c1_c2`` (the right camera ``baseline_m`` along the left camera's x axis) works; ORB-SLAM
  then computes its own (identity) rectification of our already rectified pairs;
* ORB-SLAM3's extractor aborts (``std::length_error``) when its coarsest pyramid level has fewer than ~32 px
  inside its border: the number of levels is capped so the top level keeps :data:`MIN_TOP_LEVEL_PX` px on the short
  side (960x600 keeps the paper's 13 levels; 320x240 gets 8);
* ``loopClosing: 0`` turns the loop-closing thread off, and with it relocalisation (keyframes reach the
  place-recognition database only through that thread).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from bracketry_emulator.features.orb import OrbSettings

#: smallest short side (px) of ORB-SLAM3's coarsest pyramid level that we let it use
MIN_TOP_LEVEL_PX = 64


def pyramid_levels(width_px: int, height_px: int, levels: int, scale: float) -> int:
    """``levels`` capped so that the coarsest level keeps at least :data:`MIN_TOP_LEVEL_PX` on the short side."""
    short = min(width_px, height_px)
    n = 1
    while n < levels and short / scale ** n >= MIN_TOP_LEVEL_PX:
        n += 1
    return n


@dataclass(frozen=True)
class OrbSlamCamera:
    """The rectified pinhole stereo camera ORB-SLAM3 sees: intrinsics in px, baseline in m, image size in px."""

    fx_px: float
    fy_px: float
    cx_px: float
    cy_px: float
    baseline_m: float
    width_px: int
    height_px: int


def _real(x: float) -> str:
    """A YAML real that OpenCV reads as real (always with a decimal point or exponent)."""
    text = repr(float(x))
    return text if any(c in text for c in ".eEn") else text + ".0"


def _mat(name: str, m: np.ndarray) -> list[str]:
    data = ", ".join(_real(v) for v in np.asarray(m, float).ravel())
    return [f"{name}: !!opencv-matrix", f"   rows: {m.shape[0]}", f"   cols: {m.shape[1]}", "   dt: f",
            f"   data: [{data}]"]


def settings_yaml(cam: OrbSlamCamera, fps: float, loop_closing: bool = True, th_depth: float = 35.0,
                  orb: OrbSettings | None = None) -> str:
    """The settings file text for ORB-SLAM3 stereo on images of ``cam``.

    ``fps``: the bracket-cycle rate (frames per second of one camera's stream at the emulated exposure).
    ``orb``: the ORB extractor (default: the paper's 3000 features, scale 1.2, 13 levels, FAST 15/5).
    """
    o = orb or OrbSettings()
    n_levels = pyramid_levels(cam.width_px, cam.height_px, o.n_levels, o.scale_factor)
    T = np.eye(4)
    T[0, 3] = cam.baseline_m
    lines = ["%YAML:1.0", 'File.version: "1.0"', "", 'Camera.type: "PinHole"']
    for c in ("Camera1", "Camera2"):
        lines += [f"{c}.fx: {_real(cam.fx_px)}", f"{c}.fy: {_real(cam.fy_px)}", f"{c}.cx: {_real(cam.cx_px)}",
                  f"{c}.cy: {_real(cam.cy_px)}", f"{c}.k1: 0.0", f"{c}.k2: 0.0", f"{c}.p1: 0.0", f"{c}.p2: 0.0"]
    lines += [f"Camera.width: {int(cam.width_px)}", f"Camera.height: {int(cam.height_px)}",
              f"Camera.fps: {max(1, round(fps))}", "Camera.RGB: 0", "",
              *_mat("Stereo.T_c1_c2", T), f"Stereo.ThDepth: {_real(th_depth)}", "",
              f"ORBextractor.nFeatures: {int(o.n_features)}", f"ORBextractor.scaleFactor: {_real(o.scale_factor)}",
              f"ORBextractor.nLevels: {n_levels}", f"ORBextractor.iniThFAST: {int(o.ini_th_fast)}",
              f"ORBextractor.minThFAST: {int(o.min_th_fast)}", "",
              f"loopClosing: {1 if loop_closing else 0}", "",
              "Viewer.KeyFrameSize: 0.05", "Viewer.KeyFrameLineWidth: 1.0", "Viewer.GraphLineWidth: 0.9",
              "Viewer.PointSize: 2.0", "Viewer.CameraSize: 0.08", "Viewer.CameraLineWidth: 3.0",
              "Viewer.ViewpointX: 0.0", "Viewer.ViewpointY: -0.7", "Viewer.ViewpointZ: -1.8",
              "Viewer.ViewpointF: 500.0", ""]
    return "\n".join(lines)
