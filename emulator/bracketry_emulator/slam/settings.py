"""ORB-SLAM3 stereo settings (OpenCV YAML, the ``File.version: "1.0"`` format) from our rectified stereo calibration.

What ORB-SLAM3's ``Settings`` parser demands, learnt the hard way:

* every real-valued entry is written with a decimal point (``Stereo.ThDepth: 35.0``): it reads them with
  ``FileNode::isReal`` and an integer ``35`` makes the constructor fail with "unknown exception";
* integer entries (``Camera.fps``, ``Camera.width``, ``ORBextractor.nFeatures``...) must be integers. The bracket
  cycle rate is written as its integer part (at least 1): 3 for 3.67 Hz, what the authors' ORB-SLAM2 keeps of
  their ``Camera.fps: 3.6666666666666667`` (it reads a float into the integer ``mMaxFrames``). ORB-SLAM uses it as
  the most frames between keyframes and as the frames after a relocalisation (and after the start) that must track
  50 map points rather than 30 (:data:`SETTINGS_FORMAT`);
* ``Camera.type: "Rectified"`` segfaults in this build; ``"PinHole"`` with identical ``Camera1.*`` / ``Camera2.*``
  intrinsics and ``Stereo.T_c1_c2`` (the right camera ``baseline_m`` along the left camera's x axis) works; ORB-SLAM
  then computes its own (identity) rectification of our already rectified pairs;
* ORB-SLAM3's extractor aborts (``std::length_error``) when its coarsest pyramid level has fewer than ~32 px
  inside its border: the number of levels is capped so the top level keeps :data:`MIN_TOP_LEVEL_PX` px on the short
  side (960x600 keeps the paper's 13 levels; 320x240 gets 8);
* ``loopClosing: 0`` turns the loop-closing thread off, and with it relocalisation (keyframes reach the
  place-recognition database only through that thread).

The ORB extractor is sized for what the paper's setup sees (:data:`ORB_SIZING` ``field``, the default:
:func:`field_orb_settings`); ``paper`` (:data:`PAPER_ORB` whatever the image size) stays selectable. The
authors ran ORB-SLAM2 on 1920x1200 images with 3000 features, scale factor 1.2, 13 levels, FAST 15/5
(norlab-ulaval/ORB_SLAM2, branch TFR2024, ``Main/stereo/calib_files/stereo-september-2023.yaml``). Its extractor
spreads the 3000 over the levels geometrically (level l gets a share proportional to 1.2^-l), so each level is one
angular scale of the scene. Our 640x400 and 320x200 images resolve only the paper's levels from log_1.2(1920 / W)
on (6.0 and 9.8): :func:`field_orb_settings` keeps the features the paper spent at those scales (794 at 640 px,
242 at 320 px, 1345 at 960 px) instead of its 3000 on a far smaller image (9 to 36 times its density per pixel) or
its density per pixel (83 at 320x200). Floor: :data:`MIN_FIELD_FEATURES` = 750, 1.5 x the 500 keypoints a frame
needs for ORB-SLAM's stereo initialisation (``Tracking::StereoInitialization``), so that an ordinary view whose
extractor fills two thirds of its budget still initialises. Scale factor 1.2 and FAST 15/5 are the paper's (a
per-level step and thresholds in 8-bit levels, neither depends on the image size); the levels run as far as the
pyramid keeps :data:`MIN_TOP_LEVEL_PX` px on the short side (11 at 640x400, 7 at 320x200), near the paper's
coarsest level (135 of 1200 px, 11 % of the short side; ours 16 % and 34 %). ``field`` is the default: on the
demo-size suite (10 walks, 140 runs, 320x200) it tracks about as many runs as ``paper`` at 5.2 CPU-s a run against
about 12 (``emulator/DATASET.md``, "ORB-SLAM3's extractor").
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from bracketry_emulator.features.orb import OrbSettings

#: smallest short side (px) of ORB-SLAM3's coarsest pyramid level that we let it use
MIN_TOP_LEVEL_PX = 64
#: how ORB-SLAM3's extractor is sized: "field" (the default: the paper's features at the scales our image resolves,
#: :func:`field_orb_settings`) or "paper" (its 3000 features and 13 levels whatever the image size); part of the
#: benchmark's cache key
ORB_SIZING = "field"
#: what a settings file holds beyond the options (part of the benchmark's cache key): 2 = ``Camera.fps`` is the
#: bracket-cycle rate's integer part (the authors' ``mMaxFrames``)
SETTINGS_FORMAT = 2
#: the paper's image width (px) and ORB extractor (ORB-SLAM2 on 1920x1200)
PAPER_WIDTH_PX = 1920
PAPER_ORB = OrbSettings(n_features=3000, scale_factor=1.2, n_levels=13, ini_th_fast=15, min_th_fast=5)
#: fewest features of the field sizing: 1.5 x the 500 keypoints of ORB-SLAM's stereo initialisation
MIN_FIELD_FEATURES = 750


def pyramid_levels(width_px: int, height_px: int, levels: int, scale: float) -> int:
    """``levels`` capped so that the coarsest level keeps at least :data:`MIN_TOP_LEVEL_PX` on the short side."""
    short = min(width_px, height_px)
    n = 1
    while n < levels and short / scale ** n >= MIN_TOP_LEVEL_PX:
        n += 1
    return n


def field_orb_settings(width_px: int, height_px: int, paper: OrbSettings = PAPER_ORB,
                       paper_width_px: int = PAPER_WIDTH_PX) -> OrbSettings:
    """The ORB extractor for a ``width_px`` x ``height_px`` image (module docstring): the paper's features at the
    scales the image resolves, at least :data:`MIN_FIELD_FEATURES` (never more than the paper's); its scale factor
    and FAST thresholds; levels capped by :func:`pyramid_levels`."""
    r = 1.0 / paper.scale_factor
    first_level = max(0.0, np.log(paper_width_px / width_px) / np.log(paper.scale_factor))
    share = (r ** first_level - r ** paper.n_levels) / (1.0 - r ** paper.n_levels)
    n = int(min(paper.n_features, max(MIN_FIELD_FEATURES, round(paper.n_features * share))))
    levels = pyramid_levels(width_px, height_px, paper.n_levels, paper.scale_factor)
    return OrbSettings(n_features=n, scale_factor=paper.scale_factor, n_levels=levels,
                       ini_th_fast=paper.ini_th_fast, min_th_fast=paper.min_th_fast)


def slam_orb_settings(width_px: int, height_px: int, sizing: str = ORB_SIZING) -> OrbSettings:
    """ORB-SLAM3's extractor for this image size under ``sizing`` (:data:`ORB_SIZING`)."""
    if sizing == "paper":
        return PAPER_ORB
    if sizing == "field":
        return field_orb_settings(width_px, height_px)
    raise ValueError(f"unknown ORB sizing {sizing!r} (field or paper)")


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


def camera_fps(fps: float) -> int:
    """``Camera.fps`` for a stream of ``fps`` frames per second: its integer part, at least 1 (3 for the bracket
    cycle's 3.67 Hz, as the authors' ORB-SLAM2 reads their 3.67). A rate measured a hair under a whole number
    (3.9999999 from timestamps) counts as that number."""
    return max(1, int(fps + 1e-6))


def settings_yaml(cam: OrbSlamCamera, fps: float, loop_closing: bool = True, th_depth: float = 35.0,
                  orb: OrbSettings | None = None) -> str:
    """The settings file text for ORB-SLAM3 stereo on images of ``cam``.

    ``fps``: the bracket-cycle rate (frames per second of one camera's stream at the emulated exposure).
    ``orb``: the ORB extractor (default: :func:`slam_orb_settings` of the image size).
    """
    o = orb or slam_orb_settings(cam.width_px, cam.height_px)
    n_levels = pyramid_levels(cam.width_px, cam.height_px, o.n_levels, o.scale_factor)
    T = np.eye(4)
    T[0, 3] = cam.baseline_m
    lines = ["%YAML:1.0", 'File.version: "1.0"', "", 'Camera.type: "PinHole"']
    for c in ("Camera1", "Camera2"):
        lines += [f"{c}.fx: {_real(cam.fx_px)}", f"{c}.fy: {_real(cam.fy_px)}", f"{c}.cx: {_real(cam.cx_px)}",
                  f"{c}.cy: {_real(cam.cy_px)}", f"{c}.k1: 0.0", f"{c}.k2: 0.0", f"{c}.p1: 0.0", f"{c}.p2: 0.0"]
    lines += [f"Camera.width: {int(cam.width_px)}", f"Camera.height: {int(cam.height_px)}",
              f"Camera.fps: {camera_fps(fps)}", "Camera.RGB: 0", "",
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
