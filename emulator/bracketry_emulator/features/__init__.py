"""Keypoint features for the benchmark: Bayer demosaicing to 8-bit gray, an ORB-SLAM-like ORB extractor, coverage.

The paper ran ORB-SLAM2's extractor (nFeatures 3000, scaleFactor 1.2, nLevels 13, iniThFAST 15, minThFAST 5).
The PyPI binding of that extractor (``python-orb-slam3`` 0.1.1) requires ``numpy<2`` and ``opencv-python<5`` and does
not import under this project's numpy 2, so :class:`OrbExtractor` re-creates its behaviour on OpenCV (see its
docstring for the documented differences).
"""

from bracketry_emulator.features.coverage import grid_coverage
from bracketry_emulator.features.demosaic import bayer12_to_gray8, to_gray8
from bracketry_emulator.features.orb import Features, OrbExtractor, OrbSettings, hamming_distance

__all__ = [
    "Features",
    "OrbExtractor",
    "OrbSettings",
    "bayer12_to_gray8",
    "grid_coverage",
    "hamming_distance",
    "to_gray8",
]
