"""Motion blur by reprojection: one render with its range, moved to the instants of an exposure and averaged.

A frame exposed from ``t_s`` for ``E`` integrates the scene over [t_s, t_s + E]. Ray casting it densely (a full
render every pixel of image motion: ~12 renders for a 32 ms frame at 5 km/h at 640x400) costs too much, so the world
is ray cast once (at a reference instant: a frame's mid-exposure offline, the middle of a bracket cycle in the
simulated rig) and that image is moved:

1. :func:`cell_flow`: the point each 2x2 Bayer cell of the reference render sees (the ray and range of its top-left
   pixel; the sky at infinity) projected, with the lens distortion, into the camera at another pose: the cell's image
   motion (pixels, float32 (H/2, W/2) per axis). One flow for the four pixels of a cell: the four channel planes of
   the mosaic move together, with one remap.
2. :class:`Motion`: a frame's motion, linear in time over its exposure (flow at mid-exposure + velocity; the walk's
   bounce and sway take ~0.6 s, an exposure at most 32 ms).
3. :func:`sub_instants`: n equal slices of the exposure, n from the largest motion of any cell over the exposure so
   that consecutive instants move at most ``blur_px`` pixels: a continuous streak, not a few ghosts.
4. :func:`average_warps`: the image at each instant by the backward warp ``I_t(x) = I_ref(x - flow(x))`` (the flow
   of the cell the target pixel sits in), bilinear in the channel planes (``cv2.remap`` of the four planes as one
   4-channel image: R, G and B samples never mix), averaged.

Error: where the flow jumps (the edge of a near trunk against far ground) the backward warp takes the flow of the
target cell rather than of the surface that moves there, a disoccluded background repeats its neighbours, and one
point-sampled render keeps its aliasing (a mean of dense renders averages it out).
``benchmarks/bench_sim_render.py`` measures the error against the mean of dense full renders.

Pure functions on numpy arrays, no BLAS: elementwise float32/float64 arithmetic in a fixed order and OpenCV's remap
(as the renderer's texture lookups), so frames are the same bits on every x86-64 CPU.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import cv2
import numpy as np

from bracketry_emulator.synth.calibration import CameraIntrinsics

#: offsets (row, column) of the four channel planes of a 2x2 Bayer cell, in the order of the stacked planes
_CELL = ((0, 0), (0, 1), (1, 0), (1, 1))


@dataclass(frozen=True)
class CellRays:
    """The top-left pixel of every 2x2 cell of one camera: ``rays`` float32 (3, (H/2)*(W/2)) unit camera-frame rays,
    ``u``, ``v`` float32 (H/2, W/2) its pixel coordinates, ``gx``, ``gy`` float32 (H/2, W/2) the cell grid (plane
    coordinates)."""

    rays: np.ndarray
    u: np.ndarray
    v: np.ndarray
    gx: np.ndarray
    gy: np.ndarray

    @classmethod
    def of(cls, pixel_rays: np.ndarray, width: int, height: int) -> CellRays:
        """From the renderer's pixel rays float32 (3, H*W)."""
        r = pixel_rays.reshape(3, height, width)[:, 0::2, 0::2]
        gy, gx = np.mgrid[0:height // 2, 0:width // 2].astype(np.float32)
        return cls(np.ascontiguousarray(r.reshape(3, -1)), 2 * gx, 2 * gy, gx, gy)


def _relative_pose(R_ref: np.ndarray, p_ref: np.ndarray, R_t: np.ndarray,
                   p_t: np.ndarray) -> tuple[list[list[float]], list[float]]:
    """(R_t^T R_ref, R_t^T (p_ref - p_t)) as Python floats: the reference camera's frame in the target camera's.

    Summed in a fixed order in IEEE double (Python's float arithmetic has no fused multiply-add): the same bits on
    every CPU, without the exactly rounded (and slower) products of :func:`~bracketry_emulator.synth.trajectory.mat_mul`
    that the poses themselves need."""
    rt, rr = np.asarray(R_t, np.float64).tolist(), np.asarray(R_ref, np.float64).tolist()
    d = (np.asarray(p_ref, np.float64) - np.asarray(p_t, np.float64)).tolist()
    M = [[(rt[0][i] * rr[0][j] + rt[1][i] * rr[1][j]) + rt[2][i] * rr[2][j] for j in range(3)] for i in range(3)]
    b = [(rt[0][i] * d[0] + rt[1][i] * d[1]) + rt[2][i] * d[2] for i in range(3)]
    return M, b


def cell_flow(cells: CellRays, range_m: np.ndarray, intr: CameraIntrinsics, R_ref: np.ndarray, p_ref: np.ndarray,
              R_t: np.ndarray, p_t: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Image motion (du, dv) float32 (H/2, W/2), pixels, of each cell's point from a render at pose (R_ref, p_ref) to
    the camera at pose (R_t, p_t).

    ``range_m`` float32 (H, W): the render's range (inf: sky, a direction only). Poses: camera-to-world rotation
    float64 (3, 3), optical centre float64 (3,) m. A point behind the target camera does not move."""
    f32 = np.float32
    M, b = _relative_pose(R_ref, p_ref, R_t, p_t)
    inv_r = np.divide(f32(1.0), np.ascontiguousarray(range_m[0::2, 0::2]).ravel(), dtype=f32)  # 0: sky
    rays = cells.rays
    c = []
    for i in range(3):  # M @ ray + b / r: the point in the target camera, scaled by 1 / r (the same projection)
        acc = rays[0] * f32(M[i][0])
        acc += rays[1] * f32(M[i][1])
        acc += rays[2] * f32(M[i][2])
        acc += inv_r * f32(b[i])
        c.append(acc)
    ok = c[2] > f32(1e-3)
    inv_z = np.divide(f32(1.0), np.where(ok, c[2], f32(1.0)), dtype=f32)
    lim = f32(4.0)  # near the field of view: the distortion polynomial is monotonic there
    xn = np.clip(c[0] * inv_z, -lim, lim)
    yn = np.clip(c[1] * inv_z, -lim, lim)
    k1, k2, p1, p2, k3 = (f32(x) for x in intr.dist)
    r2 = xn * xn + yn * yn
    radial = f32(1.0) + r2 * (k1 + r2 * (k2 + r2 * k3))
    xy = xn * yn
    xd = xn * radial + f32(2.0) * p1 * xy + p2 * (r2 + f32(2.0) * xn * xn)
    yd = yn * radial + p1 * (r2 + f32(2.0) * yn * yn) + f32(2.0) * p2 * xy
    shape = cells.u.shape
    du = (f32(intr.fx) * xd + f32(intr.cx)).reshape(shape) - cells.u
    dv = (f32(intr.fy) * yd + f32(intr.cy)).reshape(shape) - cells.v
    bad = ~ok.reshape(shape)
    du[bad] = 0.0
    dv[bad] = 0.0
    return du, dv


@dataclass(frozen=True)
class Motion:
    """A frame's image motion relative to its reference render, linear in time: the flow of each cell at instant
    ``t_s`` (``du``, ``dv`` float32 (H/2, W/2), pixels; None: zero, the render's own instant) plus ``(t - t_s)``
    times its velocity (``vu``, ``vv``, pixels per second)."""

    t_s: float
    du: np.ndarray | None
    dv: np.ndarray | None
    vu: np.ndarray
    vv: np.ndarray

    def max_px(self, span_s: float) -> float:
        """Largest motion of any cell over ``span_s`` seconds, pixels."""
        speed2 = self.vu * self.vu + self.vv * self.vv
        return float(math.sqrt(float(speed2.max()))) * span_s

    def static(self) -> bool:
        return self.du is None and not bool(self.vu.any() or self.vv.any())


def sub_instants(t_s: float, exposure_us: float, motion_px: float, blur_px: float = 1.0,
                 max_samples: int = 64) -> list[float]:
    """Centres of n equal slices of the exposure [t_s, t_s + exposure_us]: n = ceil(motion_px / blur_px), within
    1..max_samples (one slice: the mid-exposure instant)."""
    n = int(min(max(1, math.ceil(motion_px / blur_px - 1e-9)), max_samples))
    span_s = exposure_us * 1e-6
    return [float(t_s) + (k + 0.5) / n * span_s for k in range(n)]


def stack_planes(radiance: np.ndarray) -> np.ndarray:
    """The four channel planes of an RGGB mosaic float32 (H, W) as one float32 (H/2, W/2, 4) image."""
    return np.ascontiguousarray(np.stack([radiance[dy::2, dx::2] for dy, dx in _CELL], axis=-1))


def unstack_planes(planes: np.ndarray) -> np.ndarray:
    """Inverse of :func:`stack_planes`."""
    h2, w2, _ = planes.shape
    out = np.empty((2 * h2, 2 * w2), planes.dtype)
    for c, (dy, dx) in enumerate(_CELL):
        out[dy::2, dx::2] = planes[..., c]
    return out


def average_warps(radiance: np.ndarray, cells: CellRays, motion: Motion, times_s: Sequence[float]) -> np.ndarray:
    """Mean over ``times_s`` of the reference image ``radiance`` (float32 (H, W) RGGB mosaic) moved by ``motion`` to
    each instant. Returns float32 (H, W); a copy of ``radiance`` when nothing moves (one instant at the render's own
    time, or a static camera)."""
    f32 = np.float32
    if motion.static() or (motion.du is None and len(times_s) == 1 and times_s[0] == motion.t_s):
        return radiance.copy()
    planes = stack_planes(radiance)
    acc = np.zeros_like(planes)
    half = f32(0.5)
    for t in times_s:
        dt = f32(t - motion.t_s)
        # backward warp: source = x - flow(t), in plane coordinates (a cell's planes move by half its pixel motion)
        fu = motion.vu * dt
        fv = motion.vv * dt
        if motion.du is not None and motion.dv is not None:
            fu += motion.du
            fv += motion.dv
        mx = cells.gx - fu * half
        my = cells.gy - fv * half
        acc += cv2.remap(planes, mx, my, cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE)
    acc *= f32(1.0 / len(times_s))
    return unstack_planes(acc)
