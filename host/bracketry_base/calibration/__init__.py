"""Geometric stereo calibration of the rig: a pure library (arrays in, calibration out; no files, no rig).

- :mod:`.board`: the target (ChArUco or checkerboard), its definition as a plain dict (``board.yaml``).
- :mod:`.detect`: corners with sub-pixel accuracy, the sharpness measure, the view's pose parameters.
- :mod:`.coverage`: which views to keep while capturing, the coverage bars (x, y, size, skew) and "enough".
- :mod:`.solve`: per-camera intrinsics and distortion, stereo extrinsics, rectification, with a robust selection
  over random subsets of the views; per-view reprojection errors and the dropped views with their reason.
- :mod:`.camera_info`: the ROS ``camera_info`` documents and the KITTI projection matrices of a result (text and
  dicts; the caller writes them).

Both the rig side (capture) and the offline side (solve, benchmark) import it: it stands in the base layer and needs
numpy and OpenCV (with its aruco module) only.
"""
