"""Stereo calibration of the synthetic rig: intrinsics from the real BorealHDR calibration, scaled to a resolution.

The defaults are the numbers of the real sample's ``calibration/left.yaml`` and ``right.yaml`` (1920x1200, plumb_bob).
The synthetic rig is an ideal parallel pair: both cameras share the orientation, the right camera sits
``baseline_m`` along the left camera's +x axis. Each side keeps its own camera matrix and distortion (rendered
exactly, see :meth:`CameraIntrinsics.pixel_rays`), and the rectified projection matrices come from
``cv2.stereoRectify`` on that geometry, so ``initUndistortRectifyMap(K, D, R, P)`` of the written YAMLs yields a
rectified pair with disparity ``fx_rect * baseline_m / Z``.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np
import yaml

from bracketry_base.calibration.camera_info import camera_info_fields
from bracketry_base.errors import BracketryError

#: Full resolution of the real cameras (width, height) in pixels.
NATIVE_SIZE = (1920, 1200)
#: Left camera of the real sample: fx, fy, cx, cy (pixels, 1920x1200) and plumb_bob k1 k2 p1 p2 k3.
DEFAULT_LEFT_K = (1180.80514, 1183.71696, 960.74428, 582.60369)
DEFAULT_LEFT_D = (-0.219776, 0.067229, -0.000356, 0.000265, 0.0)
#: Right camera of the real sample.
DEFAULT_RIGHT_K = (1179.32708, 1182.67031, 958.34025, 572.08905)
DEFAULT_RIGHT_D = (-0.220877, 0.068444, -0.000254, 0.000213, 0.0)
#: Baseline of the synthetic rig in metres.
DEFAULT_BASELINE_M = 0.18
#: Camera-info file names, as in the real sample's calibration folder.
YAML_NAMES = {"left": "left.yaml", "right": "right.yaml"}
SIDES = ("left", "right")


@dataclass(frozen=True)
class CameraIntrinsics:
    """Pinhole + plumb_bob model of one camera.

    Attributes:
        width, height: image size in pixels.
        fx, fy, cx, cy: camera matrix entries in pixels (pixel centres at integer coordinates).
        dist: plumb_bob coefficients (k1, k2, p1, p2, k3).
    """

    width: int
    height: int
    fx: float
    fy: float
    cx: float
    cy: float
    dist: tuple[float, float, float, float, float]

    @property
    def K(self) -> np.ndarray:
        """Camera matrix, float64 (3, 3)."""
        return np.array([[self.fx, 0.0, self.cx], [0.0, self.fy, self.cy], [0.0, 0.0, 1.0]])

    @property
    def D(self) -> np.ndarray:
        """Distortion coefficients, float64 (5,)."""
        return np.array(self.dist, dtype=np.float64)

    def scaled(self, width: int, height: int) -> CameraIntrinsics:
        """The same lens on a sensor resampled to ``width`` x ``height`` (pixel-centre convention kept)."""
        sx, sy = width / self.width, height / self.height
        return CameraIntrinsics(width, height, self.fx * sx, self.fy * sy, (self.cx + 0.5) * sx - 0.5,
                                (self.cy + 0.5) * sy - 0.5, self.dist)

    def distort(self, xn: np.ndarray, yn: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Ideal normalized coordinates -> pixel coordinates (float64 arrays of any equal shape)."""
        k1, k2, p1, p2, k3 = self.dist
        r2 = xn * xn + yn * yn
        radial = 1.0 + r2 * (k1 + r2 * (k2 + r2 * k3))
        xd = xn * radial + 2 * p1 * xn * yn + p2 * (r2 + 2 * xn * xn)
        yd = yn * radial + p1 * (r2 + 2 * yn * yn) + 2 * p2 * xn * yn
        return self.fx * xd + self.cx, self.fy * yd + self.cy

    def undistort(self, u: np.ndarray, v: np.ndarray, iterations: int = 30) -> tuple[np.ndarray, np.ndarray]:
        """Pixel coordinates -> ideal normalized coordinates (fixed-point inversion, float64, error << 1e-6 px)."""
        k1, k2, p1, p2, k3 = self.dist
        xd = (np.asarray(u, dtype=np.float64) - self.cx) / self.fx
        yd = (np.asarray(v, dtype=np.float64) - self.cy) / self.fy
        x, y = xd.copy(), yd.copy()
        for _ in range(iterations):
            r2 = x * x + y * y
            radial = 1.0 + r2 * (k1 + r2 * (k2 + r2 * k3))
            dx = 2 * p1 * x * y + p2 * (r2 + 2 * x * x)
            dy = p1 * (r2 + 2 * y * y) + 2 * p2 * x * y
            x = (xd - dx) / radial
            y = (yd - dy) / radial
        return x, y

    def pixel_rays(self) -> np.ndarray:
        """Unit viewing directions of every pixel centre in the camera frame (x right, y down, z forward).

        Returns float32 (3, H, W).
        """
        v, u = np.mgrid[0:self.height, 0:self.width].astype(np.float64)
        x, y = self.undistort(u, v)
        norm = np.sqrt(x * x + y * y + 1.0)
        return np.stack([x / norm, y / norm, 1.0 / norm]).astype(np.float32)

    def project(self, points_cam: np.ndarray) -> np.ndarray:
        """Camera-frame points float (N, 3) (z > 0) -> pixel coordinates float64 (N, 2), with distortion."""
        p = np.asarray(points_cam, dtype=np.float64)
        u, v = self.distort(p[:, 0] / p[:, 2], p[:, 1] / p[:, 2])
        return np.stack([u, v], axis=1)


@dataclass(frozen=True)
class StereoCalibration:
    """The synthetic stereo rig: per-side intrinsics, the baseline, and the rectification of the pair.

    Attributes:
        left, right: :class:`CameraIntrinsics`.
        baseline_m: right camera centre = left centre + baseline_m along the left camera's +x axis.
    """

    left: CameraIntrinsics
    right: CameraIntrinsics
    baseline_m: float = DEFAULT_BASELINE_M

    def side(self, side: str) -> CameraIntrinsics:
        """Intrinsics of ``side`` ("left" or "right")."""
        if side == "left":
            return self.left
        if side == "right":
            return self.right
        raise BracketryError(f"unknown camera side {side!r} (expected left or right)")

    @property
    def size(self) -> tuple[int, int]:
        """(width, height) in pixels."""
        return self.left.width, self.left.height

    def offset_m(self, side: str) -> np.ndarray:
        """Position of ``side``'s optical centre in the left camera frame, float64 (3,) metres."""
        return np.array([self.baseline_m if side == "right" else 0.0, 0.0, 0.0])

    def rectification(self) -> dict[str, np.ndarray]:
        """``cv2.stereoRectify`` of the pair (alpha 0): keys R1, R2 (3x3), P1, P2 (3x4), Q (4x4)."""
        T = np.array([[-self.baseline_m], [0.0], [0.0]])
        R1, R2, P1, P2, Q, _r1, _r2 = cv2.stereoRectify(self.left.K, self.left.D, self.right.K, self.right.D,
                                                         self.size, np.eye(3), T, alpha=0.0)
        return {"R1": R1, "R2": R2, "P1": P1, "P2": P2, "Q": Q}

    def scaled(self, width: int, height: int) -> StereoCalibration:
        """This rig at another resolution (both sides scaled)."""
        return StereoCalibration(self.left.scaled(width, height), self.right.scaled(width, height), self.baseline_m)


def default_calibration(width: int = NATIVE_SIZE[0], height: int = NATIVE_SIZE[1],
                        baseline_m: float = DEFAULT_BASELINE_M) -> StereoCalibration:
    """The real sample's intrinsics (embedded numbers) scaled to ``width`` x ``height``."""
    w, h = NATIVE_SIZE
    left = CameraIntrinsics(w, h, *DEFAULT_LEFT_K, DEFAULT_LEFT_D)
    right = CameraIntrinsics(w, h, *DEFAULT_RIGHT_K, DEFAULT_RIGHT_D)
    return StereoCalibration(left, right, baseline_m).scaled(width, height)


def _read_camera_info(path: Path) -> CameraIntrinsics:
    try:
        info = yaml.safe_load(path.read_text())
        k = [float(x) for x in info["camera_matrix"]["data"]]
        d = [float(x) for x in info["distortion_coefficients"]["data"]]
        w, h = int(info["image_width"]), int(info["image_height"])
    except (OSError, yaml.YAMLError, KeyError, TypeError, ValueError) as exc:
        raise BracketryError(f"cannot read camera_info {path}: {exc}") from exc
    d = (d + [0.0] * 5)[:5]
    return CameraIntrinsics(w, h, k[0], k[4], k[2], k[5], (d[0], d[1], d[2], d[3], d[4]))


def load_calibration(calibration_dir: Path, width: int, height: int,
                     baseline_m: float = DEFAULT_BASELINE_M) -> StereoCalibration:
    """Intrinsics from a folder holding ``left.yaml`` and ``right.yaml`` (ROS camera_info), scaled to the size."""
    left = _read_camera_info(Path(calibration_dir) / YAML_NAMES["left"])
    right = _read_camera_info(Path(calibration_dir) / YAML_NAMES["right"])
    return StereoCalibration(left.scaled(width, height), right.scaled(width, height), baseline_m)


def camera_info_dict(calib: StereoCalibration, side: str) -> dict:
    """ROS camera_info (the sample's YAML layout) of one side, with the rectification of the pair."""
    cam = calib.side(side)
    rect = calib.rectification()
    R, P = (rect["R1"], rect["P1"]) if side == "left" else (rect["R2"], rect["P2"])
    return camera_info_fields((cam.width, cam.height), f"bracketry_synth/{side}", cam.K, cam.D, R, P, decimals=6)


def write_calibration(calib: StereoCalibration, out_dir: Path) -> list[Path]:
    """Write ``left.yaml``, ``right.yaml`` (camera_info) and ``calib_kitti.txt`` (rectified P0, P1 as 3x4 rows,
    then each side's k1 k2 p1 p2, as in the sample). Returns the written paths."""
    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    written = []
    for side in SIDES:
        path = out_dir / YAML_NAMES[side]
        path.write_text(yaml.safe_dump(camera_info_dict(calib, side), sort_keys=False, default_flow_style=None))
        written.append(path)
    rect = calib.rectification()
    lines = [" ".join(f"{x:.8e}" for x in rect[key].ravel()) for key in ("P1", "P2")]
    lines += [" ".join(f"{x:.6f}" for x in calib.side(s).dist[:4]) for s in SIDES]
    kitti = out_dir / "calib_kitti.txt"
    kitti.write_text("\n".join(lines) + "\n")
    written.append(kitti)
    return written
