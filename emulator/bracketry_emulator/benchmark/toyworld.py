"""A tiny ray-cast stereo corridor with ground truth, to exercise the VO and the benchmark without other modules.

The scene is a box corridor (walls at x = +-3 m, floor y = +1.5 m, ceiling y = -1.5 m, end wall at z = 80 m,
camera frame x right, y down, z forward) covered with natural 1/f block textures (8-bit levels): :data:`_OCTAVES`
octaves of random blocks from 0.12 m to 1.92 m, each octave half the amplitude of the next coarser one (the 1/f
amplitude spectrum of natural scenes, the persistence 0.5 of the synthetic worlds' ``synth.noise.ValueNoise``). The
left camera moves forward with a gentle sinusoidal sway and yaw; the right camera is ``baseline_m`` to its right.
Each pixel takes the texture at its footprint on the surface, as a camera pixel integrates it (the synthetic worlds'
renderer, ``synth/render.py``, blends texture resolutions by the pixel footprint likewise): mip levels of 2x2 means,
the two levels around the footprint blended linearly, the texel of each level by nearest-neighbour lookup (so blocks
larger than a pixel keep sharp corners, good FAST corners). Blocks of i.i.d. levels looked up at single points made
the far corridor (blocks under a pixel) a pixel noise unrelated between frames and between the left and right view,
and left ORB-SLAM3 too few stable stereo points (``tests/bracketry_emulator/slam/test_bench_orbslam3.py``).

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
#: octaves of the 1/f texture: blocks of _BLOCK_M * 2**k, k < _OCTAVES
_OCTAVES = 5
#: texels per side of a texture (2048 finest blocks: 246 m, the corridor is 80 m long)
_TEXELS = 2048
#: mean and standard deviation (8-bit levels) of a texture, those of uniform levels in [20, 236)
_MEAN_LEVEL = 128.0
_STD_LEVEL = 216.0 / np.sqrt(12.0)


def natural_texture(rng: np.random.Generator, n: int = _TEXELS, octaves: int = _OCTAVES) -> np.ndarray:
    """uint8 (n, n) 1/f block texture: ``octaves`` octaves of uniform random blocks of 1, 2, 4... texels, each half
    the amplitude of the next coarser one, scaled to mean :data:`_MEAN_LEVEL` and standard deviation
    :data:`_STD_LEVEL`, clipped to [20, 235]."""
    v = np.zeros((n, n))
    amp = 1.0
    for k in range(octaves - 1, -1, -1):
        s = 2 ** k
        v += amp * np.repeat(np.repeat(rng.uniform(-1.0, 1.0, (n // s, n // s)), s, axis=0), s, axis=1)
        amp *= 0.5
    return np.clip(_MEAN_LEVEL + v * (_STD_LEVEL / v.std()), 20, 235).astype(np.uint8)


def mip_levels(texture: np.ndarray) -> list[np.ndarray]:
    """float32 mip levels of a square power-of-two ``texture``: level l has texels of 2**l x 2**l (2x2 means)."""
    levels: list[np.ndarray] = [texture.astype(np.float32)]
    while levels[-1].shape[0] > 1:
        levels.append(cv2.resize(levels[-1], None, fx=0.5, fy=0.5, interpolation=cv2.INTER_AREA))
    return levels


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

    def textures(self) -> list[list[np.ndarray]]:
        """Per plane, the :func:`mip_levels` of its :func:`natural_texture` (drawn from ``seed``)."""
        rng = np.random.default_rng(self.seed)
        return [mip_levels(natural_texture(rng)) for _ in _PLANES]

    def pose_wc(self, t_s: float) -> np.ndarray:
        """4x4 float64 left-camera-to-world pose at ``t_s``."""
        T = np.eye(4)
        T[:3, :3] = Rotation.from_euler("yxz", [0.08 * np.sin(0.4 * t_s), 0.03 * np.sin(0.7 * t_s), 0.0]).as_matrix()
        T[:3, 3] = [0.6 * np.sin(0.25 * t_s), 0.1 * np.sin(0.5 * t_s), self.speed_mps * t_s]
        return T

    def render(self, T_wc: np.ndarray, textures: list[list[np.ndarray]]) -> np.ndarray:
        """uint8 HxW image seen by a pinhole camera at ``T_wc`` (principal point at the image centre).

        A pixel's footprint on a plane (in finest blocks) is its depth / ``fx_px`` times ``|d|^2 / |d . n|`` for the
        ray ``d`` (unit depth) and the plane normal ``n`` (the slant stretches it): mip level log2 of that, at least
        0, the two levels around it blended linearly (module docstring)."""
        h, w = self.height_px, self.width_px
        u, v = np.meshgrid(np.arange(w) + 0.5 - w / 2, np.arange(h) + 0.5 - h / 2)
        d_c = np.stack([u / self.fx_px, v / self.fx_px, np.ones_like(u)], axis=-1)
        d_w = d_c @ T_wc[:3, :3].T
        d2 = (d_c ** 2).sum(axis=-1)
        o = T_wc[:3, 3]
        best_t = np.full((h, w), np.inf)
        img = np.zeros((h, w), np.float64)
        for axis, value, tex_id in _PLANES:
            with np.errstate(divide="ignore", invalid="ignore"):
                t = (value - o[axis]) / d_w[..., axis]
            hit = (t > 0) & (t < best_t)
            if not hit.any():
                continue
            p = (o + d_w[hit] * t[hit][:, None]) / _BLOCK_M  # in finest blocks
            a, b = [k for k in range(3) if k != axis]
            levels = textures[tex_id]
            footprint = t[hit] * d2[hit] / (self.fx_px * np.abs(d_w[hit][:, axis]) * _BLOCK_M)
            lod = np.clip(np.log2(np.maximum(footprint, 1e-9)), 0.0, len(levels) - 1.001)
            base = np.floor(lod).astype(np.int64)
            frac: np.ndarray = lod - base
            mixed = np.zeros(len(base))
            blend: list[tuple[np.ndarray, np.ndarray]] = [(base, 1.0 - frac), (base + 1, frac)]
            for level, weight in blend:
                for lv in np.unique(level):
                    m = level == lv
                    tex = levels[lv]
                    ia = np.floor(p[m, a] / 2 ** lv).astype(np.int64) % tex.shape[1]
                    ib = np.floor(p[m, b] / 2 ** lv).astype(np.int64) % tex.shape[0]
                    mixed[m] += weight[m] * tex[ib, ia]
            img[hit] = mixed
            best_t[hit] = t[hit]
        return np.clip(np.rint(img), 0, 255).astype(np.uint8)

    def render_pair(self, t_s: float, textures: list[list[np.ndarray]]) -> tuple[np.ndarray, np.ndarray]:
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
