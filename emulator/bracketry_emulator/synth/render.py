"""Ray casting of the synthetic world, vectorised in numpy: one camera pose -> per-pixel radiance and range.

Per camera side, the unit ray of every pixel (with the lens distortion) is precomputed once. A render rotates those
rays into the world (:func:`rotate_rays`), then:

- the ground (z = 0) is intersected analytically and looked up in pre-lit textures with ``cv2.remap`` (three
  resolutions blended by the pixel footprint, the channel of each RGGB pixel selected by offsetting into the
  vertically stacked channel planes, so one single-channel remap serves the mosaic);
- rays that miss the ground within the far treeline radius hit the treeline cylinder or the sky (gradient, halo,
  solar disk);
- primitives (vertical cylinders, spheres, boxes) are culled by clipping their bounding boxes to the view (tree
  trunks are cut into 1 m pieces, frustum-culled by bounding spheres, so that the screen rectangles follow the lean
  of the projected trunk), every (pixel, object) pair inside an object's screen rectangle is intersected in one flat
  batch per primitive type, the nearest hit per pixel is kept (``np.minimum.at``) and only the winners are shaded.

The per-pixel passes run in row blocks of about 50k pixels so that their temporaries stay in the CPU cache.

A frame is the same bits on every x86-64 CPU: no BLAS (whose kernel, picked by CPU, rounds differently: numpy's
``@``, ``np.dot``, ``np.linalg``), only elementwise float64/float32 arithmetic in a fixed order, and no float32
transcendental function whose rounding follows numpy's SIMD dispatch (:func:`exp_f32`, :func:`sin_f32`; float64
sin, cos, arctan2, hypot and sqrt are the same under every dispatch). ``tests/bracketry_emulator/synth/
test_synth_cpu_independence.py`` renders under each OpenBLAS kernel and numpy's baseline dispatch.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import cv2
import numpy as np

from bracketry_emulator.synth.calibration import CameraIntrinsics
from bracketry_emulator.synth.camera_model import BAYER_RGGB
from bracketry_emulator.synth.kernels import synth_kernels
from bracketry_emulator.synth.scene import Scene

_NEAR_M = 0.05
_MAX_OBJ_RANGE_M = 90.0
_PIECE_M = 1.0
_BLOCK_PIXELS = 49152
_EDGES = np.array([(0, 1), (0, 2), (0, 4), (1, 3), (1, 5), (2, 3), (2, 6), (3, 7), (4, 5), (4, 6), (5, 7), (6, 7)])
_CORNER_SIGNS = np.array([[i & 1, (i >> 1) & 1, (i >> 2) & 1] for i in range(8)], dtype=np.float64)


def _remap_flat(src: np.ndarray, u: np.ndarray, v: np.ndarray, cols: int = 1024) -> np.ndarray:
    """Bilinear lookup of ``src`` at flat float32 coordinates (u = column, v = row) -> float32 (len(u),).

    cv2.remap needs 2-D maps smaller than 32767 per side, so the flat list is folded into rows of ``cols``."""
    m = u.size
    rows = -(-m // cols)
    pad = rows * cols - m
    if pad:
        u = np.concatenate([u, np.zeros(pad, np.float32)])
        v = np.concatenate([v, np.zeros(pad, np.float32)])
    res = cv2.remap(src, u.reshape(rows, cols), v.reshape(rows, cols), cv2.INTER_LINEAR,
                    borderMode=cv2.BORDER_REPLICATE)
    return res.ravel()[:m]


def rotate_rays(R: np.ndarray, rays: np.ndarray, block: int = 4 * _BLOCK_PIXELS) -> np.ndarray:
    """``R.astype(float32) @ rays`` (float32 (3, N)), the same bits on every CPU.

    numpy's ``@`` calls OpenBLAS's sgemm, whose kernel (and so rounding) depends on the CPU: the pre-AVX2 kernels
    changed 0.35 % of the pixels of a frame, some from black to white. Each component here is the chain the AVX2 and
    AVX-512 kernels compute, ``fma(r2, z, fma(r1, y, r0 * x))`` rounded to float32 at each step (bit for bit theirs,
    measured on every ray of 60 frames), with elementwise float64 products (exact for float32 factors) and sums."""
    R32 = np.asarray(R, dtype=np.float32).astype(np.float64)
    f32, f64 = np.float32, np.float64
    n = rays.shape[1]
    out = np.empty((3, n), f32)
    m = min(block, n)
    xyz = np.empty((3, m), f64)
    acc, prod, rnd = np.empty(m, f64), np.empty(m, f64), np.empty(m, f32)
    for s0 in range(0, n, block):  # cache-sized chunks
        k = min(block, n - s0)
        x, y, z = xyz[0, :k], xyz[1, :k], xyz[2, :k]
        xyz[:, :k] = rays[:, s0:s0 + k]
        a, b, r = acc[:k], prod[:k], rnd[:k]
        for i in range(3):
            np.multiply(x, R32[i, 0], out=a)
            r[...] = a  # each step rounded to float32, as the kernel's fused multiply-adds do
            a[...] = r
            np.multiply(y, R32[i, 1], out=b)
            a += b
            r[...] = a
            a[...] = r
            np.multiply(z, R32[i, 2], out=b)
            a += b
            out[i, s0:s0 + k] = a
    return out


def rotate_rows(v: np.ndarray, M: np.ndarray) -> np.ndarray:
    """``v @ M`` of float64 points (..., 3) and a (3, k) matrix as explicit sums in a fixed order (the same bits on
    every CPU; numpy's ``@`` calls BLAS)."""
    v = np.asarray(v, dtype=np.float64)
    x, y, z = v[..., 0], v[..., 1], v[..., 2]
    return np.stack([(x * M[0, j] + y * M[1, j]) + z * M[2, j] for j in range(M.shape[1])], axis=-1)


def norm_rows(v: np.ndarray) -> np.ndarray:
    """Euclidean norm along the last axis (length 2 or 3) as explicit sums in index order (float64)."""
    v = np.asarray(v, dtype=np.float64)
    total = v[..., 0] * v[..., 0]
    for k in range(1, v.shape[-1]):
        total += v[..., k] * v[..., k]
    return np.sqrt(total)


_LN2_HI = 6.93147180369123816490e-01  # ln 2 to 32 bits: k * _LN2_HI is exact for |k| < 2**20
_LN2_LO = 1.90821492927058770002e-10
_EXP_TAYLOR = [1.0 / math.factorial(k) for k in range(12, -1, -1)]


def exp_f32(x: np.ndarray) -> np.ndarray:
    """``exp`` of float32 values <= 0 as float32, the same bits on every CPU.

    numpy's float32 exp depends on its SIMD dispatch (AVX2/AVX-512 and the baseline round differently); this one
    uses only float64 +, *, rint and ldexp (IEEE-exact everywhere): x = k ln 2 + r with |r| <= ln 2 / 2, exp(r) by
    its Taylor series to r^12 (relative error below 2e-16), scaled by 2^k, rounded to float32 once."""
    xd = np.maximum(np.asarray(x, dtype=np.float64), -200.0)  # exp(-200) is 0 in float32
    k = np.rint(xd * (1.0 / math.log(2.0)))
    r = xd - k * _LN2_HI
    r -= k * _LN2_LO
    p = r * _EXP_TAYLOR[0]
    p += _EXP_TAYLOR[1]
    for c in _EXP_TAYLOR[2:]:
        p *= r
        p += c
    return np.ldexp(p, k.astype(np.int32)).astype(np.float32)


def sin_f32(x: np.ndarray) -> np.ndarray:
    """``sin`` of float32 values as float32, the same bits on every CPU: numpy's float32 sin rounds differently under
    its SIMD dispatch, its float64 sin does not (measured), so the float64 sine rounded to float32."""
    return np.sin(np.asarray(x, dtype=np.float64)).astype(np.float32)


def pseudo_angle(x: np.ndarray, y: np.ndarray) -> np.ndarray:
    """A cheap monotonic stand-in for atan2(y, x) (13x faster): float32 in [0, 4), 0 along +x, counter-clockwise.

    Used to index periodic textures by azimuth, where only a continuous, monotonic parametrisation matters."""
    f32 = np.float32
    p = y / (np.abs(x) + np.abs(y) + f32(1e-20))
    q = np.where(x >= 0, p, f32(2.0) - p)  # (-1, 3]
    q[q < 0] += f32(4.0)
    return q


#: brick size of the facades (m): course height, brick length, mortar width
BRICK_COURSE_M, BRICK_LENGTH_M, MORTAR_M = 0.25, 0.5, 0.03


def brick_factor(along_m: np.ndarray, height_m: np.ndarray, obj: np.ndarray) -> np.ndarray:
    """Albedo factor of a brick facade at wall coordinates ``along_m``, ``height_m`` (float (N,), metres) of box
    ``obj`` (int (N,)): each brick a hashed shade in [0.7, 1.2], every other course offset by half a brick, mortar
    joints 0.55. float32 (N,). Integer hashing and exact float ops only: the same bytes on every CPU."""
    z = np.asarray(height_m, np.float64) / BRICK_COURSE_M
    course = np.floor(z)
    x = np.asarray(along_m, np.float64) / BRICK_LENGTH_M + 0.5 * (course % 2)
    brick = np.floor(x)
    h = (course.astype(np.int64) * 73856093) ^ (brick.astype(np.int64) * 19349663) \
        ^ (np.asarray(obj, np.int64) * 83492791)
    h &= 0xFFFFFFFF
    h = ((h ^ (h >> 13)) * 1274126177) & 0xFFFFFFFF
    h ^= h >> 16
    shade = 0.7 + 0.5 * (h & 1023).astype(np.float64) / 1023.0
    joint = ((z - course) * BRICK_COURSE_M < MORTAR_M) | ((x - brick) * BRICK_LENGTH_M < MORTAR_M)
    return np.where(joint, 0.55, shade).astype(np.float32)


@dataclass
class RenderResult:
    """Output of one render: ``radiance`` float32 (H, W) in the channel of each RGGB pixel, ``range_m`` float32
    (H, W) distance along the ray to the hit (inf for sky)."""

    radiance: np.ndarray
    range_m: np.ndarray


class SideRenderer:
    """Renderer of one camera (fixed intrinsics and resolution) in one scene."""

    def __init__(self, scene: Scene, intr: CameraIntrinsics) -> None:
        self.scene = scene
        self.intr = intr
        h, w = intr.height, intr.width
        self.shape = (h, w)
        rays = intr.pixel_rays()
        self.rays = rays.reshape(3, -1)
        xn, yn = rays[0] / rays[2], rays[1] / rays[2]
        margin_x, margin_y = 2.0 / intr.fx, 2.0 / intr.fy
        self.fov_xn = (float(xn.min()) - margin_x, float(xn.max()) + margin_x)
        self.fov_yn = (float(yn.min()) - margin_y, float(yn.max()) + margin_y)
        cell = np.array(BAYER_RGGB, dtype=np.int8)
        self.chan = np.tile(cell, (h // 2 + 1, w // 2 + 1))[:h, :w].ravel().copy()
        self.chan_f = self.chan.astype(np.float32)
        #: flat index of every pixel, (H, W) int32: rectangles of it list the pixels of a screen rectangle
        self.pixel_index = np.arange(h * w, dtype=np.int32).reshape(h, w)
        #: row offset of each pixel's channel plane in the ground atlas
        self.atlas_row_off = self.chan_f * np.float32(scene.ground.row_stride)
        # angular size of a pixel (rad) at the image centre (drives the ground texture level)
        self.pix_rad = np.float32(1.0 / np.sqrt(intr.fx * intr.fy))
        cyl = scene.prims.cylinders
        n_pieces = np.maximum(np.ceil(cyl[:, 3] / _PIECE_M), 1).astype(np.int64) if cyl.size else np.zeros(0, int)
        self.cyl_parent = np.repeat(np.arange(len(cyl)), n_pieces)
        k = np.arange(len(self.cyl_parent)) - np.repeat(np.cumsum(n_pieces) - n_pieces, n_pieces)
        z0 = k * _PIECE_M
        z1 = np.minimum(z0 + _PIECE_M, cyl[self.cyl_parent, 3]) if cyl.size else z0
        #: trunk pieces (M, 5): x, y, radius, z0, z1 (metres); cyl_parent (M,) their trunk
        self.cyl_pieces = np.column_stack([cyl[self.cyl_parent, :3], z0, z1]) if cyl.size else np.zeros((0, 5))
        #: the pieces as five contiguous float32 columns (x, y, radius, z0, z1)
        self.cyl_cols = [np.ascontiguousarray(self.cyl_pieces[:, k], dtype=np.float32) for k in range(5)]
        half = 0.5 * (self.cyl_pieces[:, 4] - self.cyl_pieces[:, 3])
        self.cyl_centres = np.column_stack([self.cyl_pieces[:, :2], self.cyl_pieces[:, 3] + half])
        self.cyl_radii = np.hypot(self.cyl_pieces[:, 2], half)
        # frustum side planes (camera frame, unit normals pointing inside) from the field of view
        x0, x1 = self.fov_xn
        y0, y1 = self.fov_yn
        planes = np.array([[1.0, 0.0, -x0], [-1.0, 0.0, x1], [0.0, 1.0, -y0], [0.0, -1.0, y1], [0.0, 0.0, 1.0]])
        self.frustum = planes / norm_rows(planes)[:, None]
        self.cyl_albedo_flat = np.ascontiguousarray(scene.prims.cyl_albedo, dtype=np.float32).ravel()
        self.bark_flat = np.ascontiguousarray(scene.bark, dtype=np.float32).ravel()
        lt = scene.lighting
        self.sun = lt.sun_dir.astype(np.float32)
        self.sun_rgb = np.asarray(lt.sun_rgb, np.float32)
        self.sky_rgb = np.asarray(lt.sky_rgb, np.float32)

        def per_pixel(rgb: tuple[float, float, float] | np.ndarray) -> np.ndarray:
            return np.asarray(rgb, np.float32)[self.chan]

        hor = np.asarray(lt.horizon_rgb, np.float32)
        #: channel-dependent constants as per-pixel maps (flat float32), sliced instead of gathered
        self.chan_maps = {"sun": per_pixel(self.sun_rgb), "sky": per_pixel(self.sky_rgb), "hor": per_pixel(hor),
                          "zen_minus_hor": per_pixel(np.asarray(lt.zenith_rgb, np.float32) - hor),
                          "halo": per_pixel(lt.halo_rgb), "treeline": per_pixel(scene.treeline_albedo)}

    # ------------------------------------------------------------------ helpers
    def _light(self, nx: np.ndarray, ny: np.ndarray, nz: np.ndarray, ch: np.ndarray) -> np.ndarray:
        s = self.sun
        ndots = np.maximum(nx * s[0] + ny * s[1] + nz * s[2], 0.0)
        return self.sun_rgb[ch] * ndots + self.sky_rgb[ch] * (0.5 + 0.5 * nz)

    # ------------------------------------------------------------------ ground
    def _ground(self, o: np.ndarray, dx: np.ndarray, dy: np.ndarray, dz: np.ndarray, sl: slice,
                dz_max: float) -> tuple[np.ndarray, np.ndarray]:
        """Ground radiance and range for the flat pixel range ``sl`` whose world directions are dx, dy, dz (rays
        with dz >= dz_max are treated as dz_max and give values the caller discards).

        Two atlas lookups per ray, blended linearly in the pixel footprint between the levels (L0 at a footprint of
        one finest texel, L1 at 4, L2 at texel_L2 / texel_L0)."""
        at = self.scene.ground
        f32 = np.float32
        dzc = np.minimum(dz, f32(dz_max))
        t = f32(-o[2]) / dzc
        X = t * dx
        X += f32(o[0])
        Y = t * dy
        Y += f32(o[1])
        # footprint on the ground in finest texels; beyond the fine squares only L2 exists
        fp = np.sqrt(-dzc)
        np.divide(t, fp, out=fp)
        fp *= f32(self.pix_rad / at.texel_m[0])
        fp[np.maximum(np.abs(X), np.abs(Y)) > f32(at.half_near_m - 0.5)] = f32(1e6)
        f1 = float(at.texel_m[1] / at.texel_m[0])
        f2 = float(at.texel_m[2] / at.texel_m[0])
        upper = fp >= f32(f1)
        frac = np.where(upper, (fp - f32(f1)) * f32(1.0 / (f2 - f1)), (fp - f32(1.0)) * f32(1.0 / (f1 - 1.0)))
        np.clip(frac, 0.0, 1.0, out=frac)

        def coords(level: int, coord: np.ndarray, origin: np.ndarray, offset: float) -> np.ndarray:
            inv = at.inv_texel[level]
            c = coord * inv
            c += -origin[level] * inv - f32(0.5)
            np.clip(c, 0.0, at.max_uv[level], out=c)
            if offset:
                c += f32(offset)
            return c

        row_off = self.atlas_row_off[sl]
        n_up = int(np.count_nonzero(upper))
        if n_up == 0:
            pair = (0, 1)  # the whole block blends L0 and L1
        elif n_up == upper.size:
            pair = (1, 2)
        else:
            pair = None
        if pair is not None:
            lo, hi = pair
            ua, va = coords(lo, X, at.x0, float(at.col_off[lo])), coords(lo, Y, at.y0, 0.0)
            va += row_off
            val = _remap_flat(at.image, ua, va)
            if pair == (0, 1) and float(fp.max()) <= 1.0:
                return val, t  # magnified ground: the finest level alone
            ub, vb = coords(hi, X, at.x0, float(at.col_off[hi])), coords(hi, Y, at.y0, 0.0)
        else:
            u0, u1, u2 = (coords(lv, X, at.x0, float(at.col_off[lv])) for lv in range(3))
            v0, v1, v2 = (coords(lv, Y, at.y0, 0.0) for lv in range(3))
            va = np.where(upper, v1, v0)
            va += row_off
            val = _remap_flat(at.image, np.where(upper, u1, u0), va)
            ub, vb = np.where(upper, u2, u1), np.where(upper, v2, v1)
        vb += row_off
        val_b = _remap_flat(at.image, ub, vb)
        val_b -= val
        val_b *= frac
        val += val_b
        return val, t

    # ------------------------------------------------------------------ sky and treeline
    def _far(self, o: np.ndarray, dx: np.ndarray, dy: np.ndarray, dz: np.ndarray,
             sl: slice) -> tuple[np.ndarray, np.ndarray]:
        """Radiance and range (inf for sky) of rays that miss the ground (the far treeline or the sky), for the
        flat pixel range ``sl`` whose world directions are dx, dy, dz."""
        cm = {k: v[sl] for k, v in self.chan_maps.items()}
        sc = self.scene
        lt = sc.lighting
        f32 = np.float32
        # the treeline can only be hit below the slope of its highest point seen from the nearest distance
        nearest_m = max(sc.treeline_radius_m - float(np.hypot(o[0], o[1])), 1.0)
        top_slope = (float(sc.treeline_height_m.max()) - o[2]) / nearest_m
        may_hit = float(dz.min()) < top_slope
        if may_hit:
            a = np.maximum(dx * dx + dy * dy, f32(1e-12))
            b = f32(o[0]) * dx + f32(o[1]) * dy
            c = f32(o[0] ** 2 + o[1] ** 2 - sc.treeline_radius_m ** 2)
            t = (np.sqrt(np.maximum(b * b - a * c, 0.0)) - b) / a
            hx = f32(o[0]) + t * dx
            hy = f32(o[1]) + t * dy
            hz = f32(o[2]) + t * dz
            n_az = sc.treeline_height_m.size
            az_bin = np.minimum((pseudo_angle(hx, hy) * f32(n_az / 4.0)).astype(np.int32), n_az - 1)
            top = sc.treeline_height_m[az_bin]
            tree = hz < top
            # treeline: vertical surface facing the ray, vertical streaks, darker near the ground
            streak = f32(0.6) + f32(0.8 / 97.0) * ((az_bin * 7919) % 97).astype(np.float32)
            shade = f32(0.6) + f32(0.4) * np.clip(hz / top, 0.0, 1.0)
            inv_a = f32(1.0) / np.sqrt(a)
            ndots = np.maximum(-(dx * self.sun[0] + dy * self.sun[1]) * inv_a, 0.0)
            light = cm["sun"] * ndots
            light += cm["sky"] * f32(0.5)
            tree_rad = cm["treeline"] * streak * shade * light
        # sky: horizon-to-zenith gradient, halo and solar disk
        sky = cm["zen_minus_hor"] * np.sqrt(np.clip(dz, 0.0, 1.0))
        sky += cm["hor"]
        cosang = dx * self.sun[0] + dy * self.sun[1] + dz * self.sun[2]
        ang = np.sqrt(np.maximum(f32(2.0) * (f32(1.0) - cosang), 0.0))
        sky += cm["halo"] * exp_f32(-ang * f32(1.0 / lt.halo_rad))
        sky[ang < lt.disk_rad] = lt.disk_radiance
        if not may_hit:
            return sky, np.full(sky.shape, np.inf, f32)
        rad = np.where(tree, tree_rad, sky)
        rng = np.where(tree, t, f32(np.inf))
        return rad, rng

    # ------------------------------------------------------------------ primitives
    def _visible_spheres(self, centres: np.ndarray, radii: np.ndarray, R: np.ndarray, p: np.ndarray) -> np.ndarray:
        """Indices of bounding spheres (centres (N, 3), radii (N,)) that may be seen (frustum and range test)."""
        cam = rotate_rows(centres - p, R)
        dist = rotate_rows(cam, self.frustum.T)  # (N, 5) signed distances to the side planes and the image plane
        ok = np.all(dist >= -radii[:, None], axis=1) & (norm_rows(cam) < _MAX_OBJ_RANGE_M + radii)
        return np.nonzero(ok)[0]

    def _rects(self, lo: np.ndarray, hi: np.ndarray, R: np.ndarray, p: np.ndarray) -> np.ndarray:
        """Screen rectangles (N, 4) int (r0, r1, c0, c1) of world AABBs (lo, hi: (N, 3))."""
        corners = lo[:, None, :] + (hi - lo)[:, None, :] * _CORNER_SIGNS[None]
        return self._rects_of_boxes(corners, R, p)

    def _rects_of_boxes(self, corners: np.ndarray, R: np.ndarray, p: np.ndarray) -> np.ndarray:
        """Screen rectangles (N, 4) int (r0, r1, c0, c1), empty when r0 >= r1 or c0 >= c1, of boxes given by their
        corners (N, 8, 3) (corner i at bits (i & 1, i & 2, i & 4) along the box's three edge directions).

        The box is clipped to the near plane, projected to normalized coordinates, its bounding box clipped to the
        field of view, and that box's outline (20 points) mapped through the lens distortion (monotonic for these
        coefficients); the rectangle holds every pixel centre inside."""
        if corners.shape[0] == 0:
            return np.zeros((0, 4), np.int64)
        cam = rotate_rows(corners - p, R)  # (N, 8, 3) camera frame
        z = cam[..., 2]
        ea, eb = cam[:, _EDGES[:, 0]], cam[:, _EDGES[:, 1]]
        za, zb = ea[..., 2], eb[..., 2]
        cross = (za - _NEAR_M) * (zb - _NEAR_M) < 0
        s = np.where(cross, (_NEAR_M - za) / np.where(cross, zb - za, 1.0), 0.0)
        pts_edge = ea + s[..., None] * (eb - ea)
        pts = np.concatenate([cam, pts_edge], axis=1)
        valid = np.concatenate([z >= _NEAR_M, cross], axis=1)
        zz = np.where(valid, pts[..., 2], 1.0)
        xn = pts[..., 0] / zz
        yn = pts[..., 1] / zz
        big = 1e9
        x0 = np.maximum(np.where(valid, xn, big).min(axis=1), self.fov_xn[0])
        x1 = np.minimum(np.where(valid, xn, -big).max(axis=1), self.fov_xn[1])
        y0 = np.maximum(np.where(valid, yn, big).min(axis=1), self.fov_yn[0])
        y1 = np.minimum(np.where(valid, yn, -big).max(axis=1), self.fov_yn[1])
        centre = corners.mean(axis=1)
        size = norm_rows(corners[:, 7] - corners[:, 0])
        dist = norm_rows(centre - p)
        ok = valid.any(axis=1) & (x0 < x1) & (y0 < y1) & (dist < _MAX_OBJ_RANGE_M + size)
        f = np.linspace(0.0, 1.0, 5)
        ox = np.concatenate([f, np.ones(5), f, np.zeros(5)])
        oy = np.concatenate([np.zeros(5), f, np.ones(5), f])
        bx = x0[:, None] + (x1 - x0)[:, None] * ox[None]
        by = y0[:, None] + (y1 - y0)[:, None] * oy[None]
        u, v = self.intr.distort(bx, by)
        h, w = self.shape
        c0 = np.clip(np.floor(u.min(axis=1)), 0, w).astype(np.int64)
        c1 = np.clip(np.ceil(u.max(axis=1)) + 1, 0, w).astype(np.int64)
        r0 = np.clip(np.floor(v.min(axis=1)), 0, h).astype(np.int64)
        r1 = np.clip(np.ceil(v.max(axis=1)) + 1, 0, h).astype(np.int64)
        rects = np.stack([r0, r1, c0, c1], axis=1)
        rects[~ok] = 0
        return rects

    def _pairs(self, rects: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Flat pixel indices and object ids of every pixel of every rectangle."""
        hgt = np.maximum(rects[:, 1] - rects[:, 0], 0)
        wid = np.maximum(rects[:, 3] - rects[:, 2], 0)
        area = hgt * wid
        keep = np.nonzero(area > 0)[0]
        if keep.size == 0:
            return np.zeros(0, np.int32), np.zeros(0, np.int64)
        index = self.pixel_index
        pix = np.concatenate([index[r0:r1, c0:c1].ravel() for r0, r1, c0, c1 in rects[keep].tolist()])
        return pix, np.repeat(keep, area[keep])

    def _cylinders(self, o: np.ndarray, d: np.ndarray, R: np.ndarray) -> tuple | None:
        if self.cyl_pieces.size == 0:
            return None
        keep = self._visible_spheres(self.cyl_centres, self.cyl_radii, R, o)
        if keep.size == 0:
            return None
        pieces = self.cyl_pieces[keep]
        # each trunk is cut into 1 m pieces (their screen rectangles follow the lean of the projected trunk), each
        # bounded by a box turned towards the camera (tighter on screen than the axis-aligned one)
        m = len(pieces)
        toward = o[:2] - pieces[:, :2]
        toward /= np.maximum(norm_rows(toward)[:, None], 1e-9)
        across = np.column_stack([-toward[:, 1], toward[:, 0]])
        r = pieces[:, 2:3]
        base = np.column_stack([pieces[:, :2] - r * toward - r * across, pieces[:, 3]])
        e1 = np.column_stack([2 * r * across, np.zeros(m)])
        e2 = np.column_stack([2 * r * toward, np.zeros(m)])
        e3 = np.column_stack([np.zeros((m, 2)), pieces[:, 4] - pieces[:, 3]])
        corners = (base[:, None, :] + _CORNER_SIGNS[None, :, 0:1] * e1[:, None, :]
                   + _CORNER_SIGNS[None, :, 1:2] * e2[:, None, :] + _CORNER_SIGNS[None, :, 2:3] * e3[:, None, :])
        rects = self._rects_of_boxes(corners, R, o)
        f32 = np.float32
        cols = self.cyl_cols
        # per piece: camera-to-axis offset and the constant term of the quadratic
        ocx_p = f32(o[0]) - cols[0]
        ocy_p = f32(o[1]) - cols[1]
        c_p = ocx_p * ocx_p + ocy_p * ocy_p - cols[2] * cols[2]
        kernels = synth_kernels()
        if kernels is not None:  # the same nearest hits, compiled, without listing the (pixel, piece) pairs
            live = np.nonzero((rects[:, 1] > rects[:, 0]) & (rects[:, 3] > rects[:, 2]))[0]
            if live.size == 0:
                return None
            n = self.shape[0] * self.shape[1]
            best_t = np.full(n, np.inf, f32)
            best_piece = np.full(n, -1, np.int32)
            kernels.nearest_trunks(d[0], d[1], d[2], self.shape[1], np.ascontiguousarray(rects[live], dtype=np.int64),
                   np.ascontiguousarray(keep[live], dtype=np.int64), ocx_p, ocy_p, c_p, cols[3], cols[4],
                   float(f32(o[2])), best_t, best_piece)
            pix = np.flatnonzero(best_piece >= 0).astype(np.int32)
            if pix.size == 0:
                return None
            piece = best_piece[pix].astype(np.int64)
            return pix, self.cyl_parent[piece], best_t[pix], (piece, d, o)
        pix, piece = self._pairs(rects)
        if pix.size == 0:
            return None
        piece = keep[piece]
        t_all = np.empty(pix.size, f32)
        for s0 in range(0, pix.size, _BLOCK_PIXELS):  # cache-sized chunks of (pixel, piece) pairs
            pp, pc = pix[s0:s0 + _BLOCK_PIXELS], piece[s0:s0 + _BLOCK_PIXELS]
            dx, dy, dz = d[0][pp], d[1][pp], d[2][pp]
            a = dx * dx
            a += dy * dy
            np.maximum(a, f32(1e-12), out=a)
            b = ocx_p[pc] * dx
            b += ocy_p[pc] * dy
            disc = b * b
            disc -= a * c_p[pc]
            t = np.sqrt(np.maximum(disc, 0.0))
            t += b
            t /= a
            np.negative(t, out=t)
            z = t * dz
            z += f32(o[2])
            ok = (disc > 0) & (t > 0) & (z >= cols[3][pc]) & (z < cols[4][pc])
            t_all[s0:s0 + _BLOCK_PIXELS] = np.where(ok, t, f32(np.inf))
        return pix, self.cyl_parent[piece], t_all, (piece, d, o)

    def _shade_cylinders(self, win: np.ndarray, pix: np.ndarray, obj: np.ndarray, t: np.ndarray,
                         aux: tuple) -> np.ndarray:
        piece, d, o = aux
        cols = self.cyl_cols
        kernels = synth_kernels()
        if kernels is not None:
            f32 = np.float32
            out = np.empty(win.size, f32)
            kernels.shade_trunks(np.ascontiguousarray(pix[win], np.int32), np.ascontiguousarray(piece[win], np.int64),
                                 np.ascontiguousarray(t[win], f32), d[0], d[1], d[2], cols[0], cols[1], cols[2],
                                 self.cyl_parent, self.chan, np.ascontiguousarray(self.scene.prims.cyl_kind, np.int32),
                                 self.bark_flat,
                                 self.cyl_albedo_flat, self.chan_maps["sun"], self.chan_maps["sky"], float(f32(o[0])),
                                 float(f32(o[1])), float(f32(o[2])), float(self.sun[0]), float(self.sun[1]),
                                 self.scene.bark.shape[1], self.scene.bark.shape[0], out)
            return out
        pw, pcw, tw = pix[win], piece[win], t[win]
        r = cols[2][pcw]
        nx = (np.float32(o[0]) - cols[0][pcw] + tw * d[0][pw]) / r
        ny = (np.float32(o[1]) - cols[1][pcw] + tw * d[1][pw]) / r
        z = np.float32(o[2]) + tw * d[2][pw]
        ch = self.chan[pw]
        prims = self.scene.prims
        ob = obj[win]
        bark = self.scene.bark
        nu, nv = bark.shape[1], bark.shape[0]
        u = np.minimum((pseudo_angle(nx, ny) * np.float32(nu / 4.0)).astype(np.int32), nu - 1)
        v = (z * np.float32(4.0)).astype(np.int32)
        v += (ob * 37) % nv
        v %= nv
        v *= nu
        v += u
        tex = self.bark_flat[v]
        birch = np.nonzero(prims.cyl_kind[ob] == 1)[0]
        if birch.size:
            ob_b = ob[birch]
            marks = ((z[birch] * np.float32(3.1) + ob_b * np.float32(0.37)) % np.float32(1.0) < 0.12) \
                & (((u[birch] >> 4) + ob_b) % 3 != 0)
            tex[birch[marks]] = np.float32(0.15)
        tex *= self.cyl_albedo_flat[ob * 3 + ch]
        # Lambert: horizontal normal (n_z = 0)
        light = nx * self.sun[0]
        light += ny * self.sun[1]
        np.maximum(light, 0.0, out=light)
        light *= self.chan_maps["sun"][pw]
        light += np.float32(0.5) * self.chan_maps["sky"][pw]
        tex *= light
        return tex

    def _spheres(self, o: np.ndarray, d: np.ndarray, R: np.ndarray) -> tuple | None:
        sph = self.scene.prims.spheres
        if sph.size == 0:
            return None
        lo = sph[:, :3] - sph[:, 3:4]
        lo[:, 2] = np.maximum(lo[:, 2], 0.0)
        hi = sph[:, :3] + sph[:, 3:4]
        pix, obj = self._pairs(self._rects(lo, hi, R, o))
        if pix.size == 0:
            return None
        s32 = sph.astype(np.float32)
        dx, dy, dz = d[0][pix], d[1][pix], d[2][pix]
        ocx = np.float32(o[0]) - s32[obj, 0]
        ocy = np.float32(o[1]) - s32[obj, 1]
        ocz = np.float32(o[2]) - s32[obj, 2]
        r = s32[obj, 3]
        b = ocx * dx + ocy * dy + ocz * dz
        c = ocx * ocx + ocy * ocy + ocz * ocz - r * r
        disc = b * b - c
        t = -b - np.sqrt(np.maximum(disc, 0.0))
        z = np.float32(o[2]) + t * dz
        ok = (disc > 0) & (t > 0) & (z > 0)
        t = np.where(ok, t, np.float32(np.inf))
        return pix, obj, t, (dx, dy, dz, ocx, ocy, ocz, r)

    def _shade_spheres(self, win: np.ndarray, pix: np.ndarray, obj: np.ndarray, t: np.ndarray,
                       aux: tuple) -> np.ndarray:
        dx, dy, dz, ocx, ocy, ocz, r = (a[win] for a in aux)
        tw = t[win]
        nx, ny, nz = (ocx + tw * dx) / r, (ocy + tw * dy) / r, (ocz + tw * dz) / r
        ch = self.chan[pix[win]]
        ob = obj[win]
        prims = self.scene.prims
        # cheap solid texture from the normal
        tex = 1.0 + 0.25 * np.sin(nx * 23.0 + ob) * np.sin(ny * 19.0 - ob) * sin_f32(nz * 17.0)
        albedo = prims.sph_albedo[ob, ch] * tex
        if self.scene.snow_caps:
            cap = (prims.sph_kind[ob] == 0) & (nz + 0.15 * sin_f32(nx * 11.0 + ny * 7.0) > 0.55)
            albedo = np.where(cap, np.float32(0.85) * (1.0 + 0.04 * (ch == 2)), albedo)
        return albedo * self._light(nx, ny, nz, ch)

    def _boxes(self, o: np.ndarray, d: np.ndarray, R: np.ndarray) -> tuple | None:
        boxes = self.scene.prims.boxes
        if boxes.size == 0:
            return None
        pix, obj = self._pairs(self._rects(boxes[:, :3], boxes[:, 3:], R, o))
        if pix.size == 0:
            return None
        b32 = boxes.astype(np.float32)
        ds = (d[0][pix], d[1][pix], d[2][pix])
        tmin = np.full(pix.shape, -np.inf, np.float32)
        tmax = np.full(pix.shape, np.inf, np.float32)
        axis = np.zeros(pix.shape, np.int8)
        for k in range(3):
            dk = ds[k]
            inv = np.float32(1.0) / np.where(np.abs(dk) < 1e-9, np.float32(1e-9), dk)
            ta = (b32[obj, k] - np.float32(o[k])) * inv
            tb = (b32[obj, k + 3] - np.float32(o[k])) * inv
            t_near = np.minimum(ta, tb)
            t_far = np.maximum(ta, tb)
            better = t_near > tmin
            axis[better] = k
            tmin = np.maximum(tmin, t_near)
            tmax = np.minimum(tmax, t_far)
        ok = (tmax >= tmin) & (tmin > 0)
        t = np.where(ok, tmin, np.float32(np.inf))
        return pix, obj, t, (ds[0], ds[1], ds[2], axis)

    def _shade_boxes(self, win: np.ndarray, pix: np.ndarray, obj: np.ndarray, t: np.ndarray, aux: tuple,
                     o: np.ndarray) -> np.ndarray:
        dx, dy, dz, axis = (a[win] for a in aux)
        tw = t[win]
        ch = self.chan[pix[win]]
        ob = obj[win]
        hx, hy, hz = o[0] + tw * dx, o[1] + tw * dy, o[2] + tw * dz
        dirs = (dx, dy, dz)
        normal = [np.zeros_like(tw) for _ in range(3)]
        for k in range(3):
            sel = axis == k
            normal[k][sel] = -np.sign(dirs[k][sel])
        prims = self.scene.prims
        albedo = prims.box_albedo[ob, ch].copy()
        light = self._light(normal[0], normal[1], normal[2], ch)
        facade = (prims.box_kind[ob] == 1) & (axis != 2)
        along = np.where(axis == 0, hy, hx)
        window = facade & ((along / 3.0) % 1.0 > 0.25) & ((along / 3.0) % 1.0 < 0.75) \
            & ((hz / 3.5) % 1.0 > 0.3) & ((hz / 3.5) % 1.0 < 0.8) & (hz > 1.0)
        wall = axis != 2
        if wall.any():  # brick courses: a texture a tracker finds corners in, as on real facades
            albedo[wall] *= brick_factor(along[wall], hz[wall], ob[wall])
        out = albedo * light
        if window.any():
            hor = np.asarray(self.scene.lighting.horizon_rgb, np.float32)[ch[window]]
            out[window] = 0.04 * light[window] + 0.25 * hor
            # mullions: a cross of frame bars (5 cm) through each window's middle
            u, v = (along[window] / 3.0) % 1.0, (hz[window] / 3.5) % 1.0
            bar = (np.abs(u - 0.5) * 3.0 < 0.05) | (np.abs(v - 0.55) * 3.5 < 0.05)
            out[window] = np.where(bar, albedo[window] * light[window] * 0.5, out[window])
        return out

    # ------------------------------------------------------------------ main
    def render(self, R_wc: np.ndarray, p_w: np.ndarray) -> RenderResult:
        """Radiance and range seen from the optical centre ``p_w`` (3,) with orientation ``R_wc`` (3, 3)."""
        h, w = self.shape
        n = h * w
        o = np.asarray(p_w, dtype=np.float64)
        d = rotate_rays(R_wc, self.rays)  # (3, N) world directions
        dz = d[2]
        dz_max = -o[2] / self.scene.treeline_radius_m  # rays below this slope hit the ground inside the treeline
        is_ground = dz < dz_max
        rad = np.empty(n, np.float32)
        rng_buf = np.empty(n, np.float32)
        # ground and far passes in row blocks: the temporaries stay in the CPU cache
        rows = max(1, _BLOCK_PIXELS // w)
        for r0 in range(0, h, rows):
            a, b = r0 * w, min(h, r0 + rows) * w
            g = is_ground[a:b]
            n_g = int(np.count_nonzero(g))
            if n_g:
                rad[a:b], rng_buf[a:b] = self._ground(o, d[0, a:b], d[1, a:b], dz[a:b], slice(a, b), dz_max)
            if n_g < b - a:
                far_rad, far_rng = self._far(o, d[0, a:b], d[1, a:b], dz[a:b], slice(a, b))
                if n_g:
                    rad[a:b] = np.where(g, rad[a:b], far_rad)
                    rng_buf[a:b] = np.where(g, rng_buf[a:b], far_rng)
                else:
                    rad[a:b], rng_buf[a:b] = far_rad, far_rng
        hits = [self._cylinders(o, d, R_wc), self._spheres(o, d, R_wc), self._boxes(o, d, R_wc)]
        for hit in hits:
            if hit is not None:
                np.minimum.at(rng_buf, hit[0], hit[2])
        for kind, hit in enumerate(hits):
            if hit is None:
                continue
            pix, obj, t, aux = hit
            win = np.nonzero(np.isfinite(t) & (t <= rng_buf[pix]))[0]
            if win.size == 0:
                continue
            if kind == 0:
                val = self._shade_cylinders(win, pix, obj, t, aux)
            elif kind == 1:
                val = self._shade_spheres(win, pix, obj, t, aux)
            else:
                val = self._shade_boxes(win, pix, obj, t, aux, o)
            rad[pix[win]] = val
        return RenderResult(rad.reshape(h, w), rng_buf.reshape(h, w))
