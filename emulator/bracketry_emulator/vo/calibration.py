"""Stereo calibration from ROS ``camera_info`` YAML files and rectification maps.

The two YAMLs give, per camera, K (3x3), distortion (plumb_bob k1 k2 p1 p2 k3), R (rectification rotation) and P
(3x4 rectified projection; the right camera's ``P[0, 3] = -fx * baseline_m``). Rows of the two rectified images are
aligned only if both cameras share one rectified camera matrix; real files do not always do that (the BorealHDR
sample's P matrices differ in fy and cy by a few pixels and 12 rows), so both images are remapped to ONE common
pinhole camera: fx = fy = mean of the four P focal lengths, cx and cy the means of the two P principal points. The
baseline is ``-P_right[0, 3] / P_right[0, 0]``. Images of another size than the YAML's are handled by scaling K and P.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

import cv2
import numpy as np
import yaml

from bracketry_base.errors import BracketryError


@dataclass(frozen=True)
class CameraInfo:
    """One ROS camera_info: size in pixels, K 3x3, D (5,), R 3x3, P 3x4 (float64)."""

    width_px: int
    height_px: int
    K: np.ndarray
    D: np.ndarray
    R: np.ndarray
    P: np.ndarray

    @classmethod
    def from_yaml(cls, path: str | Path) -> CameraInfo:
        """Read a ROS camera_info YAML (``image_width``, ``camera_matrix.data``, ...)."""
        try:
            doc = yaml.safe_load(Path(path).read_text())
            return cls(int(doc["image_width"]), int(doc["image_height"]),
                       np.array(doc["camera_matrix"]["data"], float).reshape(3, 3),
                       np.array(doc["distortion_coefficients"]["data"], float).ravel(),
                       np.array(doc.get("rectification_matrix", {"data": np.eye(3).ravel().tolist()})["data"],
                                float).reshape(3, 3),
                       np.array(doc["projection_matrix"]["data"], float).reshape(3, 4))
        except (OSError, KeyError, TypeError, ValueError, yaml.YAMLError) as exc:
            raise BracketryError(f"cannot read camera_info {path}: {exc}") from exc

    def scaled(self, width_px: int, height_px: int) -> CameraInfo:
        """The same camera for images resized to ``width_px x height_px``."""
        sx, sy = width_px / self.width_px, height_px / self.height_px
        S = np.diag([sx, sy, 1.0])
        return CameraInfo(width_px, height_px, S @ self.K, self.D.copy(), self.R.copy(), S @ self.P)


def find_camera_info(calibration_dir: str | Path) -> tuple[Path, Path]:
    """The left and right camera_info YAMLs of a calibration folder (names containing 'left' and 'right')."""
    d = Path(calibration_dir)
    lefts = sorted(p for p in d.glob("*.y*ml") if "left" in p.name.lower())
    rights = sorted(p for p in d.glob("*.y*ml") if "right" in p.name.lower())
    if not lefts or not rights:
        raise BracketryError(f"no left/right camera_info YAML in {d}")
    return lefts[0], rights[0]


@dataclass
class StereoRectifier:
    """Rectified stereo geometry and the remap tables of both cameras.

    Attributes:
        fx, fy, cx, cy: the common rectified pinhole camera (pixels).
        baseline_m: distance between the optical centres (metres).
        width_px, height_px: image size.
    """

    left: CameraInfo
    right: CameraInfo
    fx: float
    fy: float
    cx: float
    cy: float
    baseline_m: float
    width_px: int
    height_px: int
    identity: bool
    _maps: list = field(default_factory=list, repr=False)
    _valid: np.ndarray | None = field(default=None, repr=False)
    row_correction: tuple[float, float] = (0.0, 0.0)

    @classmethod
    def from_camera_info(cls, left: CameraInfo, right: CameraInfo, width_px: int | None = None,
                         height_px: int | None = None) -> StereoRectifier:
        """Build the common rectified camera for images of ``width_px x height_px`` (default: the YAML size)."""
        w = width_px or left.width_px
        h = height_px or left.height_px
        left, right = left.scaled(w, h), right.scaled(w, h)
        fx = float(np.mean([left.P[0, 0], left.P[1, 1], right.P[0, 0], right.P[1, 1]]))
        cx = float((left.P[0, 2] + right.P[0, 2]) / 2)
        cy = float((left.P[1, 2] + right.P[1, 2]) / 2)
        if right.P[0, 0] == 0 or right.P[0, 3] == 0:
            raise BracketryError("right camera_info has no baseline (P[0,3] == 0)")
        baseline = float(-right.P[0, 3] / right.P[0, 0])
        if baseline <= 0:
            raise BracketryError(f"right camera_info gives a non-positive baseline {baseline:.4f} m")
        Kn = np.array([[fx, 0, cx], [0, fx, cy], [0, 0, 1.0]])
        identity = all(np.allclose(c.K, Kn, atol=1e-6) and not np.any(c.D) and np.allclose(c.R, np.eye(3))
                       for c in (left, right))
        rect = cls(left, right, fx, fx, cx, cy, baseline, w, h, identity)
        rect._maps = [cv2.initUndistortRectifyMap(c.K, c.D, c.R, Kn, (w, h), cv2.CV_32FC1) for c in (left, right)]
        return rect

    @classmethod
    def from_dir(cls, calibration_dir: str | Path, width_px: int | None = None,
                 height_px: int | None = None) -> StereoRectifier:
        """Read the left/right camera_info YAMLs of a calibration folder."""
        lp, rp = find_camera_info(calibration_dir)
        return cls.from_camera_info(CameraInfo.from_yaml(lp), CameraInfo.from_yaml(rp), width_px, height_px)

    @property
    def K(self) -> np.ndarray:
        """Common rectified camera matrix, float64 3x3."""
        return np.array([[self.fx, 0, self.cx], [0, self.fy, self.cy], [0, 0, 1.0]])

    @property
    def bf(self) -> float:
        """Baseline times focal length (metres x pixels), ORB-SLAM's ``Camera.bf``."""
        return self.baseline_m * self.fx

    def rectify(self, image: np.ndarray, side: str) -> np.ndarray:
        """Remap a ``side`` ("left"/"right") image (HxW, any dtype) to the common rectified camera (bilinear)."""
        if image.shape[:2] != (self.height_px, self.width_px):
            raise ValueError(f"image {image.shape[:2]} does not match calibration {(self.height_px, self.width_px)}")
        if self.identity:
            return image
        m1, m2 = self._maps[0 if side == "left" else 1]
        return cv2.remap(image, m1, m2, cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE)

    def correct_rows(self, offset_px: float, slope: float) -> None:
        """Shift the right rectified image vertically by ``offset_px + slope * (x - cx)`` pixels.

        For camera_info files that are not a rectified pair (the BorealHDR sample: R = identity in both files and
        P with different cy), rows of the two rectified images disagree by a roughly constant offset and a small roll.
        After this correction a point at row y in the left image is at row y in the right one; x (the disparity, so
        the depth scale) is unchanged. ``offset_px``/``slope`` are the measured ``y_right - y_left`` model.
        """
        if self.identity:
            m1, m2 = np.meshgrid(np.arange(self.width_px, dtype=np.float32),
                                 np.arange(self.height_px, dtype=np.float32))
            self._maps = [(m1, m2), (m1.copy(), m2.copy())]
            self.identity = False
        xs, ys = np.meshgrid(np.arange(self.width_px, dtype=np.float32), np.arange(self.height_px, dtype=np.float32))
        ys_src = (ys + offset_px + slope * (xs - self.cx)).astype(np.float32)
        m1, m2 = self._maps[1]
        self._maps[1] = (cv2.remap(m1, xs, ys_src, cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE),
                         cv2.remap(m2, xs, ys_src, cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE))
        c0, c1 = self.row_correction
        self.row_correction = (c0 + offset_px, c1 + slope)
        self._valid = None

    def valid_mask(self, margin_px: int = 6) -> np.ndarray:
        """uint8 HxW, 255 where both rectified images hold real pixels (eroded by ``margin_px``), else 0.

        Keypoints are only detected inside it, so the replicated borders of the remap make no corners.
        """
        if self._valid is None:
            ones = np.full((self.height_px, self.width_px), 255, np.uint8)
            valid: np.ndarray
            if self.identity:
                valid = ones
            else:
                valid = np.minimum(*[cv2.remap(ones, m1, m2, cv2.INTER_NEAREST, borderMode=cv2.BORDER_CONSTANT,
                                               borderValue=0) for m1, m2 in self._maps])
            if margin_px > 0:
                valid = cv2.erode(valid, np.ones((2 * margin_px + 1, 2 * margin_px + 1), np.uint8))
            self._valid = valid
        return self._valid
