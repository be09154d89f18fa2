"""A tiny ray-cast stereo corridor with ground truth, to exercise the VO and the benchmark without other modules.

The scene is a box corridor (walls at x = +-3 m, floor y = +1.5 m, ceiling y = -1.5 m, end wall at z = 80 m,
camera frame x right, y down, z forward) covered with random block textures (blocks of 0.12 m, 8-bit levels). The
left camera moves forward with a gentle sinusoidal sway and yaw; the right camera is ``baseline_m`` to its right.
Images are rendered with nearest-neighbour texture lookup (sharp block corners make good FAST corners).

It writes the same layout the benchmark reads: an emulated run
``<run>/<method>/images_left|images_right/<t_ns>.png`` (16-bit PNG, gray codes 0..4095) with
``times_images_left|right.txt`` and ``steps.csv`` (exposure 4 ms x gain), a TUM ``groundtruth.txt`` and
``calibration/left.yaml`` + ``right.yaml`` (ROS camera_info, zero distortion).
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np
import yaml
from scipy.spatial.transform import Rotation

_PLANES = (  # (axis, value, texture id)
    (0, -3.0, 0), (0, 3.0, 1), (1, 1.5, 2), (1, -1.5, 3), (2, 80.0, 4),
)
_BLOCK_M = 0.12


@dataclass(frozen=True)
class ToyWorld:
    """Corridor scene. ``speed_mps`` forward speed, ``fps`` frame rate, image ``width_px x height_px``."""

    width_px: int = 320
    height_px: int = 240
    fx_px: float = 240.0
    baseline_m: float = 0.18
    speed_mps: float = 1.2
    fps: float = 3.6667
    seed: int = 7

    def textures(self) -> list[np.ndarray]:
        rng = np.random.default_rng(self.seed)
        return [rng.integers(20, 236, size=(2048, 2048), dtype=np.uint8) for _ in _PLANES]

    def pose_wc(self, t_s: float) -> np.ndarray:
        """4x4 float64 left-camera-to-world pose at ``t_s``."""
        T = np.eye(4)
        T[:3, :3] = Rotation.from_euler("yxz", [0.08 * np.sin(0.4 * t_s), 0.03 * np.sin(0.7 * t_s), 0.0]).as_matrix()
        T[:3, 3] = [0.6 * np.sin(0.25 * t_s), 0.1 * np.sin(0.5 * t_s), self.speed_mps * t_s]
        return T

    def render(self, T_wc: np.ndarray, textures: list[np.ndarray]) -> np.ndarray:
        """uint8 HxW image seen by a pinhole camera at ``T_wc`` (principal point at the image centre)."""
        h, w = self.height_px, self.width_px
        u, v = np.meshgrid(np.arange(w) + 0.5 - w / 2, np.arange(h) + 0.5 - h / 2)
        d_c = np.stack([u / self.fx_px, v / self.fx_px, np.ones_like(u)], axis=-1)
        d_w = d_c @ T_wc[:3, :3].T
        o = T_wc[:3, 3]
        best_t = np.full((h, w), np.inf)
        img = np.zeros((h, w), np.uint8)
        for axis, value, tex_id in _PLANES:
            with np.errstate(divide="ignore", invalid="ignore"):
                t = (value - o[axis]) / d_w[..., axis]
            hit = (t > 0) & (t < best_t)
            if not hit.any():
                continue
            p = o + d_w[hit] * t[hit][:, None]
            a, b = [k for k in range(3) if k != axis]
            tex = textures[tex_id]
            ia = np.floor(p[:, a] / _BLOCK_M).astype(np.int64) % tex.shape[1]
            ib = np.floor(p[:, b] / _BLOCK_M).astype(np.int64) % tex.shape[0]
            img[hit] = tex[ib, ia]
            best_t[hit] = t[hit]
        return img

    def render_pair(self, t_s: float, textures: list[np.ndarray]) -> tuple[np.ndarray, np.ndarray]:
        T = self.pose_wc(t_s)
        T_r = T.copy()
        T_r[:3, 3] = T[:3, 3] + T[:3, :3] @ np.array([self.baseline_m, 0.0, 0.0])
        return self.render(T, textures), self.render(T_r, textures)

    def camera_info(self, side: str) -> dict:
        cx, cy = self.width_px / 2, self.height_px / 2
        tx = -self.fx_px * self.baseline_m if side == "right" else 0.0
        return {
            "image_width": self.width_px, "image_height": self.height_px, "camera_name": f"toy/{side}",
            "camera_matrix": {"rows": 3, "cols": 3, "data": [self.fx_px, 0.0, cx, 0.0, self.fx_px, cy, 0, 0, 1.0]},
            "distortion_model": "plumb_bob",
            "distortion_coefficients": {"rows": 1, "cols": 5, "data": [0.0] * 5},
            "rectification_matrix": {"rows": 3, "cols": 3, "data": [1.0, 0, 0, 0, 1.0, 0, 0, 0, 1.0]},
            "projection_matrix": {"rows": 3, "cols": 4,
                                  "data": [self.fx_px, 0.0, cx, tx, 0.0, self.fx_px, cy, 0.0, 0, 0, 1.0, 0.0]},
        }

    def write_calibration(self, out_dir: str | Path) -> Path:
        d = Path(out_dir) / "calibration"
        d.mkdir(parents=True, exist_ok=True)
        for side in ("left", "right"):
            (d / f"{side}.yaml").write_text(yaml.safe_dump(self.camera_info(side), sort_keys=False))
        return d

    def write_groundtruth(self, path: str | Path, times_ns: list[int]) -> None:
        lines = []
        for t in times_ns:
            T = self.pose_wc(t * 1e-9)
            q = Rotation.from_matrix(T[:3, :3]).as_quat()
            lines.append(f"{t * 1e-9:.9f} " + " ".join(f"{x:.9f}" for x in (*T[:3, 3], *q)))
        Path(path).write_text("\n".join(lines) + "\n")

    def write_run(self, run_dir: str | Path, method: str, n_frames: int, gain: float | list[float] = 1.0,
                  t0_ns: int = 1_000_000_000) -> list[int]:
        """Render ``n_frames`` stereo pairs into ``run_dir/<method>/`` as 16-bit gray PNGs (codes x16, x gain).

        ``gain`` (scalar or one per frame) multiplies the 8-bit intensity before clipping: large gains saturate.
        Returns the frame timestamps (ns).
        """
        root = Path(run_dir) / method
        textures = self.textures()
        gains = np.broadcast_to(np.asarray(gain, float), (n_frames,))
        times = [t0_ns + round(k * 1e9 / self.fps) for k in range(n_frames)]
        for side in ("left", "right"):
            (root / f"images_{side}").mkdir(parents=True, exist_ok=True)
        for k, t_ns in enumerate(times):
            pair = self.render_pair(t_ns * 1e-9, textures)
            for side, img in zip(("left", "right"), pair):
                codes = np.clip(img.astype(np.float64) * 16.0 * gains[k], 0, 4095).astype(np.uint16)
                cv2.imwrite(str(root / f"images_{side}" / f"{t_ns}.png"), codes)
        for side in ("left", "right"):
            (root / f"times_images_{side}.txt").write_text("".join(f"{t}\n" for t in times))
        rows = "".join(f"{k},{t},{4.0 * gains[k]:.6f},4.000000,{gains[k]:.6f},toy\n" for k, t in enumerate(times))
        (root / "steps.csv").write_text("step,timestamp_ns,target_exposure_ms,source_exposure_ms,factor,selection\n"
                                        + rows)
        return times
