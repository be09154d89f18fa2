"""Ray casting of the synthetic world, vectorised in numpy: one camera pose -> per-pixel radiance and range.

Per camera side, the unit ray of every pixel (with the lens distortion) is precomputed once. A render rotates those
rays into the world (one 3x3 x 3xN product), then:

- the ground (z = 0) is intersected analytically and looked up in pre-lit textures with ``cv2.remap`` (three
  resolutions blended by the pixel footprint, the channel of each RGGB pixel selected by offsetting into the
  vertically stacked channel planes, so one single-channel remap serves the mosaic);
- rays that miss the ground within the far treeline radius hit the treeline cylinder or the sky (gradient, halo,
  solar disk);
- primitives (vertical cylinders, spheres, boxes) are culled by clipping their bounding boxes to the view, every
  (pixel, object) pair inside an object's screen rectangle is intersected in one flat batch per primitive type, the
  nearest hit per pixel is kept (``np.minimum.at``) and only the winners are shaded.
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np

from bracketry_emulator.synth.calibration import CameraIntrinsics
from bracketry_emulator.synth.camera_model import BAYER_RGGB
from bracketry_emulator.synth.scene import Scene

_NEAR_M = 0.05
_MAX_OBJ_RANGE_M = 90.0
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
        self.col_xn_min, self.col_xn_max = xn.min(axis=0).astype(np.float64), xn.max(axis=0).astype(np.float64)
        self.row_yn_min, self.row_yn_max = yn.min(axis=1).astype(np.float64), yn.max(axis=1).astype(np.float64)
        cell = np.array(BAYER_RGGB, dtype=np.int8)
        self.chan = np.tile(cell, (h // 2 + 1, w // 2 + 1))[:h, :w].ravel().copy()
        self.chan_f = self.chan.astype(np.float32)
        # angular size of a pixel (rad), per pixel: ~ 1/f scaled by the local ray density
        self.pix_rad = np.float32(1.0 / np.sqrt(intr.fx * intr.fy))
        lt = scene.lighting
        self.sun = lt.sun_dir.astype(np.float32)
        self.sun_rgb = np.asarray(lt.sun_rgb, np.float32)
        self.sky_rgb = np.asarray(lt.sky_rgb, np.float32)

    # ------------------------------------------------------------------ helpers
    def _per_chan(self, rgb: np.ndarray | tuple[float, float, float], idx: np.ndarray) -> np.ndarray:
        return np.asarray(rgb, np.float32)[self.chan[idx]]

    def _light(self, nx: np.ndarray, ny: np.ndarray, nz: np.ndarray, ch: np.ndarray) -> np.ndarray:
        s = self.sun
        ndots = np.maximum(nx * s[0] + ny * s[1] + nz * s[2], 0.0)
        return self.sun_rgb[ch] * ndots + self.sky_rgb[ch] * (0.5 + 0.5 * nz)

    # ------------------------------------------------------------------ ground
    def _ground(self, ch: np.ndarray, X: np.ndarray, Y: np.ndarray, lod: np.ndarray) -> np.ndarray:
        """Ground radiance at world (X, Y) (flat float32 arrays) for pixels of channel ``ch`` (float32), with
        ``lod`` = log2(footprint / finest texel): two atlas lookups per pixel, blended."""
        at = self.scene.ground
        lod_l1 = float(np.log2(at.texel_m[1] / at.texel_m[0]))
        lod_l2 = float(np.log2(at.texel_m[2] / at.texel_m[0]))
        # level coordinate s in [0, 2]: 0 = L0, 1 = L1, 2 = L2 (far); outside the near square only L2 exists
        s = np.where(lod <= lod_l1, lod * np.float32(1.0 / lod_l1),
                     np.float32(1.0) + (lod - np.float32(lod_l1)) * np.float32(1.0 / (lod_l2 - lod_l1)))
        outside = (np.abs(X) > at.half_near_m - 0.5) | (np.abs(Y) > at.half_near_m - 0.5)
        s[outside] = 2.0
        np.clip(s, 0.0, 2.0, out=s)
        lo = np.minimum(s.astype(np.int32), 1)
        frac = s - lo
        row_off = ch * np.float32(at.row_stride)
        out = None
        for lvl, weight in ((lo, 1.0 - frac), (lo + 1, frac)):
            inv = at.inv_texel[lvl]
            mx = at.max_uv[lvl]
            u = np.minimum(np.maximum((X - at.x0[lvl]) * inv - np.float32(0.5), 0.0), mx)
            u += at.col_off[lvl]
            v = np.minimum(np.maximum((Y - at.y0[lvl]) * inv - np.float32(0.5), 0.0), mx)
            v += row_off
            val = _remap_flat(at.image, u, v)
            val *= weight
            out = val if out is None else out + val
        assert out is not None
        return out

    # ------------------------------------------------------------------ sky and treeline
    def _far(self, idx: np.ndarray, o: np.ndarray, d: np.ndarray, rng_buf: np.ndarray, rad: np.ndarray) -> None:
        sc = self.scene
        dx, dy, dz = d[0][idx], d[1][idx], d[2][idx]
        ch = self.chan[idx]
        a = dx * dx + dy * dy
        b = np.float32(o[0]) * dx + np.float32(o[1]) * dy
        c = np.float32(o[0] ** 2 + o[1] ** 2 - sc.treeline_radius_m ** 2)
        a_safe = np.maximum(a, np.float32(1e-12))
        t = (-b + np.sqrt(np.maximum(b * b - a * c, 0.0))) / a_safe
        hx, hy, hz = o[0] + t * dx, o[1] + t * dy, o[2] + t * dz
        n_az = sc.treeline_height_m.size
        az_bin = ((np.arctan2(hy, hx) * np.float32(n_az / (2 * np.pi))).astype(np.int32)) % n_az
        tree = (hz < sc.treeline_height_m[az_bin]) & (a > 1e-8)
        ti = np.nonzero(tree)[0]
        if ti.size:
            gi = idx[ti]
            # vertical streaks of the treeline, facing the camera
            streak = 0.6 + 0.8 * ((az_bin[ti] * 7919) % 97).astype(np.float32) / 97.0
            shade = np.float32(0.6) + np.float32(0.4) * np.clip(hz[ti] / sc.treeline_height_m[az_bin[ti]], 0, 1)
            nx, ny = -dx[ti] / np.sqrt(a[ti]), -dy[ti] / np.sqrt(a[ti])
            light = self._light(nx, ny, np.zeros_like(nx), ch[ti])
            rad[gi] = np.asarray(sc.treeline_albedo, np.float32)[ch[ti]] * streak * shade * light
            rng_buf[gi] = t[ti]
        si = np.nonzero(~tree)[0]
        if si.size:
            lt = sc.lighting
            gi = idx[si]
            chs = ch[si]
            el = np.sqrt(np.clip(dz[si], 0.0, 1.0))
            hor = np.asarray(lt.horizon_rgb, np.float32)[chs]
            zen = np.asarray(lt.zenith_rgb, np.float32)[chs]
            sky = hor + (zen - hor) * el
            cosang = dx[si] * self.sun[0] + dy[si] * self.sun[1] + dz[si] * self.sun[2]
            ang = np.sqrt(np.maximum(2.0 * (1.0 - cosang), 0.0))
            sky += np.asarray(lt.halo_rgb, np.float32)[chs] * np.exp(-ang / np.float32(lt.halo_rad))
            sky[ang < lt.disk_rad] = lt.disk_radiance
            rad[gi] = sky
            rng_buf[gi] = np.inf

    # ------------------------------------------------------------------ primitives
    def _rects(self, lo: np.ndarray, hi: np.ndarray, R: np.ndarray, p: np.ndarray) -> np.ndarray:
        """Screen rectangles (N, 4) int (r0, r1, c0, c1), empty when r0 >= r1 or c0 >= c1, of world AABBs."""
        n = lo.shape[0]
        if n == 0:
            return np.zeros((0, 4), np.int64)
        corners = lo[:, None, :] + (hi - lo)[:, None, :] * _CORNER_SIGNS[None]
        cam = (corners - p) @ R  # (N, 8, 3) camera frame
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
        x0 = np.where(valid, xn, big).min(axis=1)
        x1 = np.where(valid, xn, -big).max(axis=1)
        y0 = np.where(valid, yn, big).min(axis=1)
        y1 = np.where(valid, yn, -big).max(axis=1)
        dist = np.linalg.norm((lo + hi) / 2 - p, axis=1)
        ok = valid.any(axis=1) & (dist < _MAX_OBJ_RANGE_M + np.linalg.norm(hi - lo, axis=1))
        c0 = np.searchsorted(self.col_xn_max, x0)
        c1 = np.searchsorted(self.col_xn_min, x1, side="right")
        r0 = np.searchsorted(self.row_yn_max, y0)
        r1 = np.searchsorted(self.row_yn_min, y1, side="right")
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
            return np.zeros(0, np.int64), np.zeros(0, np.int64)
        area, wid = area[keep], wid[keep]
        total = int(area.sum())
        obj = np.repeat(keep, area)
        starts = np.cumsum(area) - area
        local = np.arange(total, dtype=np.int64) - np.repeat(starts, area)
        w_rep = np.repeat(wid, area)
        row = rects[obj, 0] + local // w_rep
        col = rects[obj, 2] + local % w_rep
        return row * self.shape[1] + col, obj

    def _cylinders(self, o: np.ndarray, d: np.ndarray, R: np.ndarray) -> tuple | None:
        cyl = self.scene.prims.cylinders
        if cyl.size == 0:
            return None
        lo = np.column_stack([cyl[:, 0] - cyl[:, 2], cyl[:, 1] - cyl[:, 2], np.zeros(len(cyl))])
        hi = np.column_stack([cyl[:, 0] + cyl[:, 2], cyl[:, 1] + cyl[:, 2], cyl[:, 3]])
        pix, obj = self._pairs(self._rects(lo, hi, R, o))
        if pix.size == 0:
            return None
        c32 = cyl.astype(np.float32)
        dx, dy, dz = d[0][pix], d[1][pix], d[2][pix]
        ocx = np.float32(o[0]) - c32[obj, 0]
        ocy = np.float32(o[1]) - c32[obj, 1]
        r = c32[obj, 2]
        a = dx * dx + dy * dy
        b = ocx * dx + ocy * dy
        c = ocx * ocx + ocy * ocy - r * r
        disc = b * b - a * c
        t = (-b - np.sqrt(np.maximum(disc, 0.0))) / np.maximum(a, np.float32(1e-12))
        z = np.float32(o[2]) + t * dz
        ok = (disc > 0) & (t > 0) & (z > 0) & (z < c32[obj, 3])
        t = np.where(ok, t, np.float32(np.inf))
        return pix, obj, t, (dx, dy, dz, ocx, ocy, r, z)

    def _shade_cylinders(self, win: np.ndarray, pix: np.ndarray, obj: np.ndarray, t: np.ndarray,
                         aux: tuple) -> np.ndarray:
        dx, dy, _dz, ocx, ocy, r, z = (a[win] for a in aux)
        tw = t[win]
        nx = (ocx + tw * dx) / r
        ny = (ocy + tw * dy) / r
        ch = self.chan[pix[win]]
        prims = self.scene.prims
        ob = obj[win]
        ang = np.arctan2(ny, nx)
        bark = self.scene.bark
        u = ((ang + np.pi) * (bark.shape[1] / (2 * np.pi))).astype(np.int32) % bark.shape[1]
        seed = (ob * 37) % bark.shape[0]
        v = ((z * 4.0).astype(np.int32) + seed) % bark.shape[0]
        tex = bark[v, u]
        birch = prims.cyl_kind[ob] == 1
        if birch.any():
            marks = ((z * 3.1 + ob * 0.37) % 1.0 < 0.12) & (np.sin(ang * 3 + ob) > 0.2)
            tex = np.where(birch & marks, np.float32(0.15), tex)
        albedo = prims.cyl_albedo[ob, ch] * tex
        return albedo * self._light(nx, ny, np.zeros_like(nx), ch)

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
        tex = 1.0 + 0.25 * np.sin(nx * 23.0 + ob) * np.sin(ny * 19.0 - ob) * np.sin(nz * 17.0)
        albedo = prims.sph_albedo[ob, ch] * tex
        if self.scene.snow_caps:
            cap = (prims.sph_kind[ob] == 0) & (nz + 0.15 * np.sin(nx * 11.0 + ny * 7.0) > 0.55)
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
        out = albedo * light
        if window.any():
            hor = np.asarray(self.scene.lighting.horizon_rgb, np.float32)[ch[window]]
            out[window] = 0.04 * light[window] + 0.25 * hor
        return out

    # ------------------------------------------------------------------ main
    def render(self, R_wc: np.ndarray, p_w: np.ndarray) -> RenderResult:
        """Radiance and range seen from the optical centre ``p_w`` (3,) with orientation ``R_wc`` (3, 3)."""
        h, w = self.shape
        n = h * w
        o = np.asarray(p_w, dtype=np.float64)
        d = R_wc.astype(np.float32) @ self.rays  # (3, N) world directions
        rad = np.empty(n, np.float32)
        rng_buf = np.empty(n, np.float32)
        dz = d[2]
        horizon_dz = -o[2] / self.scene.treeline_radius_m
        ground = np.nonzero(dz < horizon_dz)[0]
        far = np.nonzero(dz >= horizon_dz)[0]
        if ground.size:
            dzg = dz[ground]
            t = np.float32(-o[2]) / dzg
            X = np.float32(o[0]) + t * d[0][ground]
            Y = np.float32(o[1]) + t * d[1][ground]
            footprint = t * (self.pix_rad / np.float32(self.scene.ground.texel_m[0])) / np.sqrt(-dzg)
            lod = np.log2(np.maximum(footprint, np.float32(1e-6)))
            rad[ground] = self._ground(self.chan_f[ground], X, Y, lod)
            rng_buf[ground] = t
        if far.size:
            self._far(far, o, d, rng_buf, rad)
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
