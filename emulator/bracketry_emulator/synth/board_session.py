"""A calibration board session rendered with the synthetic stereo cameras: the known truth for ``calibrate solve``.

A printed board (:class:`bracketry_base.calibration.board.BoardSpec`) is moved by hand in front of the rig: each view
places the board at a random distance (it fills 25-85 % of the image width), at a random place in the image
(some views only partly inside it), tilted up to 40 degrees about its x and y axes and rolled up to 25 degrees.
Some views are over-exposed (the white squares clip), some are motion-blurred a little (a line kernel of 2-4 px) and
a few heavily (12-24 px, which the solver must refuse).

Rendering is exact inverse mapping: every pixel (sampled ``ss`` x ``ss`` times) is undistorted through the camera's
plumb_bob model (:meth:`CameraIntrinsics.undistort`, the same model the world renders with), its ray intersected
with the board plane, and the board's printed image looked up there (bilinear); outside the board a smooth grey
background. The lens adds a Gaussian blur of :data:`LENS_SIGMA_PX`. The reflectance times the illumination, the
Bayer QE and the vignetting give the electron rate, and :meth:`CameraModel.expose` the noisy 12-bit RGGB codes at
the session's fixed short exposure (the capture's calibration mode).
"""

from __future__ import annotations

import json
import math
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import cv2
import numpy as np
import yaml

from bracketry_base.calibration.board import BoardSpec
from bracketry_base.png import write_png
from bracketry_emulator.synth.calibration import CameraIntrinsics, StereoCalibration, write_calibration
from bracketry_emulator.synth.camera_model import CameraModel

#: Gaussian PSF of the lens, px
LENS_SIGMA_PX = 0.6
#: the session's fixed exposure, us (short: a board moved by hand stays sharp)
EXPOSURE_US = 1000.0
#: reflectance of the printed black and white, and of the background's range
BLACK, WHITE = 0.04, 0.85
#: texture resolution of the printed board, px per square
PX_PER_SQUARE = 96


@dataclass(frozen=True)
class ViewSpec:
    """One board pose and how the frame was spoilt.

    Attributes:
        R_cb: board-to-left-camera rotation, float64 (3, 3); t_cb: board origin in the left camera frame, m (3,).
        blur_len_px: length of the motion-blur line kernel (0: none); blur_angle_deg its direction.
        light: illumination relative to the nominal one (> 1.5: over-exposed).
        partial: the board was placed across the image border.
    """

    R_cb: np.ndarray
    t_cb: np.ndarray
    blur_len_px: float = 0.0
    blur_angle_deg: float = 0.0
    light: float = 1.0
    partial: bool = False

    def to_dict(self) -> dict[str, Any]:
        """JSON form (``session.json``)."""
        return {"R_cb": np.round(self.R_cb, 9).tolist(), "t_cb_m": np.round(self.t_cb, 9).tolist(),
                "blur_len_px": round(self.blur_len_px, 3), "blur_angle_deg": round(self.blur_angle_deg, 2),
                "light": round(self.light, 4), "partial": self.partial}


def _rot(axis: int, deg: float) -> np.ndarray:
    a = math.radians(deg)
    c, s = math.cos(a), math.sin(a)
    R = np.eye(3)
    i, j = [k for k in range(3) if k != axis]
    R[i, i], R[i, j], R[j, i], R[j, j] = c, -s, s, c
    return R


def random_views(board: BoardSpec, cam: CameraIntrinsics, n_views: int, rng: np.random.Generator,
                 partial_frac: float = 0.15, blur_frac: float = 0.15, heavy_blur: int = 2,
                 overexposed_frac: float = 0.15) -> list[ViewSpec]:
    """``n_views`` hand-held board poses seen from the left camera ``cam`` (module docstring)."""
    w_m, h_m = board.size_m
    kinds = np.array(["plain"] * n_views, dtype=object)
    order = rng.permutation(n_views)
    n_heavy = min(heavy_blur, n_views)
    kinds[order[:n_heavy]] = "heavy"
    rest = order[n_heavy:]
    n_blur, n_part = round(blur_frac * n_views), round(partial_frac * n_views)
    kinds[rest[:n_blur]] = "blur"
    kinds[rest[n_blur:n_blur + n_part]] = "partial"
    views = []
    for k in range(n_views):
        fill = rng.uniform(0.25, 0.85)
        z = w_m * cam.fx / (fill * cam.width)
        if kinds[k] == "partial":
            edge = rng.integers(4)
            along = rng.uniform(0.2, 0.8)
            out = rng.uniform(-0.02, 0.08)
            uv = [(out, along), (1 - out, along), (along, out), (along, 1 - out)][edge]
        else:
            margin = 0.5 * fill
            uv = (rng.uniform(min(margin, 0.45), max(1 - margin, 0.55)),
                  rng.uniform(min(margin * 1.1, 0.45), max(1 - margin * 1.1, 0.55)))
        x, y = cam.undistort(np.array(uv[0] * (cam.width - 1)), np.array(uv[1] * (cam.height - 1)))
        centre = np.array([float(x), float(y), 1.0]) * z
        R = _rot(2, rng.uniform(-25, 25)) @ _rot(1, rng.uniform(-40, 40)) @ _rot(0, rng.uniform(-40, 40))
        t = centre - R @ np.array([w_m / 2, h_m / 2, 0.0])
        blur = {"heavy": rng.uniform(12, 24), "blur": rng.uniform(2, 4)}.get(str(kinds[k]), 0.0)
        light = rng.uniform(3.0, 6.0) if rng.random() < overexposed_frac else rng.uniform(0.7, 1.2)
        views.append(ViewSpec(R, t, float(blur), float(rng.uniform(0, 180)), float(light),
                              kinds[k] == "partial"))
    return views


def _motion_kernel(length_px: float, angle_deg: float) -> np.ndarray:
    n = math.ceil(length_px) | 1
    k = np.zeros((n, n), np.float32)
    c = n // 2
    a = math.radians(angle_deg)
    for s in np.linspace(-length_px / 2, length_px / 2, 4 * n):
        k[round(c + s * math.sin(a)), round(c + s * math.cos(a))] += 1.0
    return k / k.sum()


@dataclass
class BoardRenderer:
    """Renders board views for one stereo rig (rays cached per camera).

    Attributes:
        board: the printed board; calib: the true rig; camera: response and noise; ss: samples per pixel axis.
    """

    board: BoardSpec
    calib: StereoCalibration
    camera: CameraModel = field(default_factory=CameraModel)
    ss: int = 2
    exposure_us: float = EXPOSURE_US
    _rays: dict[str, np.ndarray] = field(default_factory=dict, repr=False)
    _gain: dict[str, np.ndarray] = field(default_factory=dict, repr=False)
    _texture: np.ndarray | None = field(default=None, repr=False)

    def _side_rays(self, side: str) -> np.ndarray:
        if side not in self._rays:
            cam = self.calib.side(side)
            s = self.ss
            off = (np.arange(s) + 0.5) / s - 0.5
            u = (np.arange(cam.width)[:, None] + off[None, :]).ravel()
            v = (np.arange(cam.height)[:, None] + off[None, :]).ravel()
            uu, vv = np.meshgrid(u, v)
            x, y = cam.undistort(uu, vv)
            self._rays[side] = np.stack([x, y]).astype(np.float64)
            self._gain[side] = (self.camera.qe_map(cam.width, cam.height)
                                * self.camera.vignetting_map(cam.width, cam.height, cam.cx, cam.cy))
        return self._rays[side]

    def texture(self) -> np.ndarray:
        """The printed board's reflectance, float32 (H, W), half a square of white margin."""
        if self._texture is None:
            img = self.board.image(PX_PER_SQUARE, margin_squares=0.5).astype(np.float32) / 255.0
            self._texture = BLACK + (WHITE - BLACK) * img
        return self._texture

    def reflectance(self, side: str, view: ViewSpec, background: np.ndarray) -> np.ndarray:
        """What ``side`` sees, before blur and light: reflectance float32 (H, W)."""
        cam = self.calib.side(side)
        xy = self._side_rays(side)
        R = view.R_cb
        t = view.t_cb - self.calib.offset_m(side)  # the rig is parallel: right centre = left + baseline along x
        n = R[:, 2]
        nd = n[0] * xy[0] + n[1] * xy[1] + n[2]
        with np.errstate(divide="ignore", invalid="ignore"):
            s = float(n @ t) / nd
        coords = []
        for axis in (0, 1):
            r = R[:, axis]
            coords.append(s * (r[0] * xy[0] + r[1] * xy[1] + r[2]) - float(r @ t))
        tex = self.texture()
        px_per_m = PX_PER_SQUARE / self.board.square_m
        margin_m = 0.5 * self.board.square_m
        mx = ((coords[0] + margin_m) * px_per_m - 0.5)
        my = ((coords[1] + margin_m) * px_per_m - 0.5)
        bad = ~(s > 0)
        mx[bad], my[bad] = -1e6, -1e6
        hi = cv2.remap(tex, mx.astype(np.float32), my.astype(np.float32), cv2.INTER_LINEAR,
                       borderMode=cv2.BORDER_CONSTANT, borderValue=-1.0)
        bg = cv2.resize(background, (hi.shape[1], hi.shape[0]), interpolation=cv2.INTER_LINEAR)
        hi = np.where(hi < 0, bg, hi)
        return cv2.resize(hi, (cam.width, cam.height), interpolation=cv2.INTER_AREA)

    def render(self, side: str, view: ViewSpec, background: np.ndarray, rng: np.random.Generator,
               exposure_us: float | None = None) -> np.ndarray:
        """One raw frame of ``side``: uint16 (H, W) RGGB 12-bit codes. The scene's light puts the white squares at
        60 % of full well at :attr:`exposure_us`; ``exposure_us`` (default that one) is the exposure the camera
        takes (a simulated camera set to another exposure reads proportionally more or less)."""
        refl = self.reflectance(side, view, background)
        refl = cv2.GaussianBlur(refl, (0, 0), LENS_SIGMA_PX)
        if view.blur_len_px > 0:
            refl = cv2.filter2D(refl, -1, _motion_kernel(view.blur_len_px, view.blur_angle_deg),
                                borderType=cv2.BORDER_REFLECT)
        white_e_per_us = 0.6 * self.camera.full_well_e / self.exposure_us / WHITE
        rate = (refl * np.float32(white_e_per_us * view.light) * self._gain[side]).astype(np.float32)
        return self.camera.expose(rate, self.exposure_us if exposure_us is None else float(exposure_us), rng)


def background_field(width: int, height: int, rng: np.random.Generator) -> np.ndarray:
    """A smooth random grey background, reflectance float32 (H, W) in about 0.1 .. 0.5."""
    coarse = rng.uniform(0.1, 0.5, size=(6, 9)).astype(np.float32)
    return cv2.resize(coarse, (width, height), interpolation=cv2.INTER_CUBIC).clip(0.05, 0.6)


def render_session(board: BoardSpec, calib: StereoCalibration, seed: int, n_views: int,
                   camera: CameraModel | None = None, ss: int | None = None,
                   progress: Callable[[int, int], None] | None = None,
                   ) -> tuple[list[ViewSpec], list[tuple[np.ndarray, np.ndarray]]]:
    """A seeded board session: the views and their (left, right) raw frames, uint16 (H, W) each.

    ``ss``: samples per pixel axis (default 2 up to 1280 px wide, else 1)."""
    w, h = calib.size
    rng = np.random.default_rng(np.random.SeedSequence([seed, 35]))
    views = random_views(board, calib.left, n_views, rng)
    renderer = BoardRenderer(board, calib, camera or CameraModel(), ss or (2 if w <= 1280 else 1))
    frames = []
    for k, view in enumerate(views):
        bg = background_field(w, h, rng)
        pair = (renderer.render("left", view, bg, rng), renderer.render("right", view, bg, rng))
        frames.append(pair)
        if progress is not None:
            progress(k + 1, n_views)
    return views, frames


def write_board_session(out: Path, board: BoardSpec, calib: StereoCalibration, seed: int, n_views: int,
                        camera: CameraModel | None = None,
                        progress: Callable[[int, int], None] | None = None) -> dict[str, Any]:
    """Render a session into ``out`` (an existing, empty folder) and return its summary.

    Layout: ``left/NNNNNN.png`` and ``right/NNNNNN.png`` (16-bit, RGGB 12-bit codes, the rig's raw frames),
    ``truth/left.yaml``, ``truth/right.yaml`` and ``truth/calib_kitti.txt`` (the true calibration, camera_info as
    BorealHDR ships it), ``board.yaml`` (the board, read by ``calibrate solve``), ``session.json`` (every view's
    pose, blur, light; the camera model).
    """
    cam_model = camera or CameraModel()
    out = Path(out)
    for side in ("left", "right"):
        (out / side).mkdir()
    counts = {"views": n_views, "partial": 0, "blurred": 0, "heavy_blur": 0, "overexposed": 0}
    w, h = calib.size
    rng = np.random.default_rng(np.random.SeedSequence([seed, 35]))
    views = random_views(board, calib.left, n_views, rng)
    renderer = BoardRenderer(board, calib, cam_model, 2 if w <= 1280 else 1)
    for k, view in enumerate(views):
        bg = background_field(w, h, rng)
        for side in ("left", "right"):
            write_png(out / side / f"{k:06d}.png", renderer.render(side, view, bg, rng))
        counts["partial"] += view.partial
        counts["blurred"] += 0 < view.blur_len_px < 10
        counts["heavy_blur"] += view.blur_len_px >= 10
        counts["overexposed"] += view.light > 1.5
        if progress is not None:
            progress(k + 1, n_views)
    write_calibration(calib, out / "truth")
    (out / "board.yaml").write_text(yaml.safe_dump(board.to_dict(), sort_keys=False))
    summary = {"seed": seed, "resolution": [w, h], "baseline_m": calib.baseline_m, "exposure_us": EXPOSURE_US,
               "lens_sigma_px": LENS_SIGMA_PX, "counts": counts, "board": board.to_dict(),
               "camera_model": cam_model.to_dict(), "views": [v.to_dict() for v in views]}
    (out / "session.json").write_text(json.dumps(summary, indent=1) + "\n")
    return summary
