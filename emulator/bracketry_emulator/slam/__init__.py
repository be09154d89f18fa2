"""SLAM backends of the benchmark beyond the built-in VO: ORB-SLAM3 (through ``pyorbslam3``) and its vocabulary.

* :mod:`~bracketry_emulator.slam.vocabulary` — a DBoW2 vocabulary tree (pure: descriptors in, tree and text out);
* :mod:`~bracketry_emulator.slam.vocabulary_files` — training from images, the cached default, which file a run uses;
* :mod:`~bracketry_emulator.slam.settings` — the ORB-SLAM3 stereo settings from our rectified calibration;
* :mod:`~bracketry_emulator.slam.orbslam3` — one ORB-SLAM3 run in a child process, per-frame states and segments.
"""
