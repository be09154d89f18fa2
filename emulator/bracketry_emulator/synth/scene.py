"""Content of a synthetic world: lighting, sky, primitives and the pre-lit ground textures.

Radiance unit: photo-electrons per microsecond on a green pixel at the image centre (see ``camera_model``).
Surfaces are Lambertian: ``L_c = albedo_c * (sun_c * max(n . s, 0) * lit + sky_c * (0.5 + 0.5 n_z))``.
The ground (plane z = 0) is pre-lit into textures (with the cast shadows of every primitive); primitives are shaded
per pixel. All content is drawn from one ``numpy.random.Generator`` seeded by the world seed.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import cv2
import numpy as np

from bracketry_base.errors import BracketryError
from bracketry_emulator.synth.noise import ValueNoise, smoothstep
from bracketry_emulator.synth.trajectory import LoopTrajectory

PRESETS = ("forest-winter", "campus-summer")


#: angular radius of the solar disk (rad)
DISK_RAD = 0.00465


@dataclass(frozen=True)
class Lighting:
    """Sun and sky.

    Attributes:
        sun_dir: unit vector towards the sun (world), float64 (3,).
        sun_rgb: radiance of an albedo-1 surface facing the sun (direct part), per channel.
        sky_rgb: radiance of an albedo-1 horizontal surface lit by the sky only, per channel.
        zenith_rgb, horizon_rgb: sky radiance at the zenith / the horizon.
        halo_rgb: extra sky radiance next to the sun (decays as exp(-angle / halo_rad)).
        disk_radiance: radiance of the solar disk (all channels).
        disk_rad: angular radius of the solar disk.
        veil_radiance: the disk radiance the scenario's glare veil is scaled on
            (:class:`~bracketry_emulator.synth.scenario.LightField`; None: ``disk_radiance``).
    """

    sun_dir: np.ndarray
    sun_rgb: tuple[float, float, float]
    sky_rgb: tuple[float, float, float]
    zenith_rgb: tuple[float, float, float]
    horizon_rgb: tuple[float, float, float]
    halo_rgb: tuple[float, float, float]
    halo_rad: float = 0.12
    disk_radiance: float = 2.0e4
    disk_rad: float = DISK_RAD
    veil_radiance: float | None = None


@dataclass
class Primitives:
    """Analytic objects. Albedos are float32 (N, 3) RGB; ``kind`` selects the texture.

    cylinders: vertical, columns (x, y, radius, height) metres; kind 0 dark bark, 1 birch.
    spheres: columns (x, y, z, radius) metres; kind 0 rock (snow cap if ``snow_caps``), 1 foliage.
    boxes: axis-aligned, columns (x0, y0, z0, x1, y1, z1) metres; kind 0 plain, 1 facade with windows.
    """

    cylinders: np.ndarray = field(default_factory=lambda: np.zeros((0, 4)))
    cyl_albedo: np.ndarray = field(default_factory=lambda: np.zeros((0, 3), np.float32))
    cyl_kind: np.ndarray = field(default_factory=lambda: np.zeros(0, np.int32))
    spheres: np.ndarray = field(default_factory=lambda: np.zeros((0, 4)))
    sph_albedo: np.ndarray = field(default_factory=lambda: np.zeros((0, 3), np.float32))
    sph_kind: np.ndarray = field(default_factory=lambda: np.zeros(0, np.int32))
    boxes: np.ndarray = field(default_factory=lambda: np.zeros((0, 6)))
    box_albedo: np.ndarray = field(default_factory=lambda: np.zeros((0, 3), np.float32))
    box_kind: np.ndarray = field(default_factory=lambda: np.zeros(0, np.int32))


@dataclass
class GroundTexture:
    """A pre-lit ground radiance texture over a square: three channel planes stacked vertically.

    Attributes:
        origin_m: world (x, y) of the texture's corner (texel (0, 0) starts there).
        texel_m: texel size in metres.
        size: texels per side (N).
        stacked: float32 (3 * (N + pad), N): plane c occupies rows c * (N + pad) .. + N (rows = y, cols = x).
    """

    origin_m: tuple[float, float]
    texel_m: float
    size: int
    pad: int
    stacked: np.ndarray


@dataclass
class GroundAtlas:
    """All ground levels in one float32 texture, for one ``cv2.remap`` per lookup.

    Level l, channel c occupies rows ``c * row_stride .. + size[l]`` and columns ``col_off[l] .. + size[l]``.
    Per-level float32 arrays (n_levels,): ``x0``, ``y0`` (world corner, m), ``inv_texel`` (texels per metre),
    ``col_off``, ``max_uv`` (size - 1); ``texel_m`` float64.
    """

    image: np.ndarray
    row_stride: int
    x0: np.ndarray
    y0: np.ndarray
    inv_texel: np.ndarray
    col_off: np.ndarray
    max_uv: np.ndarray
    texel_m: np.ndarray
    half_near_m: float


def build_atlas(levels: list[GroundTexture]) -> GroundAtlas:
    """Pack ground levels (channel planes stacked vertically) side by side into one texture."""
    pad = 4
    stride = max(lv.size for lv in levels) + pad
    widths = [lv.size + pad for lv in levels]
    col_off = np.cumsum([0, *widths[:-1]])
    image = np.zeros((3 * stride, int(sum(widths))), np.float32)
    for lv, c0 in zip(levels, col_off):
        for ch in range(3):
            src = lv.stacked[ch * (lv.size + lv.pad):ch * (lv.size + lv.pad) + lv.size]
            block = np.pad(src, ((0, pad), (0, pad)), mode="edge")
            image[ch * stride:ch * stride + lv.size + pad, c0:c0 + lv.size + pad] = block
    f32 = np.float32
    return GroundAtlas(image=image, row_stride=stride,
                       x0=np.array([lv.origin_m[0] for lv in levels], f32),
                       y0=np.array([lv.origin_m[1] for lv in levels], f32),
                       inv_texel=np.array([1.0 / lv.texel_m for lv in levels], f32),
                       col_off=col_off.astype(f32), max_uv=np.array([lv.size - 1 for lv in levels], f32),
                       texel_m=np.array([lv.texel_m for lv in levels]),
                       half_near_m=-levels[0].origin_m[0])


@dataclass
class Scene:
    """Everything the renderer needs besides the camera."""

    preset: str
    lighting: Lighting
    prims: Primitives
    ground: GroundAtlas
    treeline_radius_m: float
    treeline_height_m: np.ndarray  # float32 (n_az,): height of the far treeline per azimuth bin
    treeline_albedo: tuple[float, float, float]
    bark: np.ndarray  # float32 (64, 256): bark modulation texture (rows = height, cols = angle)
    snow_caps: bool


@dataclass(frozen=True)
class SceneOptions:
    """What a scenario changes in the content of a preset's world (defaults: the preset as it is).

    Attributes:
        lighting: sun and sky (default: the preset's).
        tree_density: factor on the number of trees of the forest preset (the same draws when 1.0).
        treeline_scale: factor on the height of the far treeline.
        fresh_snow: float32 (n,) weight in [0, 1] of fresh, texture-poor snow per polar-angle bin of the ground
            (bin i covers angles -pi + 2 pi i / n .. + 2 pi / n about the loop centre), or None.
        snow_contrast: float32 (n,) RMS contrast of the fresh snow's natural texture per bin (a 1/f field: wind
            ripples, sastrugi, tracks), or None (the smooth snow alone).
        open_ground: float32 (n,) per bin: trees whose bin is above 0.5 are not there (an open field or lake),
            or None.
    """

    lighting: Lighting | None = None
    tree_density: float = 1.0
    treeline_scale: float = 1.0
    fresh_snow: np.ndarray | None = None
    snow_contrast: np.ndarray | None = None
    open_ground: np.ndarray | None = None

    def key(self) -> tuple:
        """A hashable summary (for scene caches)."""
        lt = self.lighting
        lkey = None if lt is None else (tuple(lt.sun_dir.tolist()), lt.sun_rgb, lt.sky_rgb, lt.zenith_rgb,
                                        lt.horizon_rgb, lt.halo_rgb, lt.halo_rad, lt.disk_radiance, lt.disk_rad,
                                        lt.veil_radiance)
        def raw(a: np.ndarray | None) -> bytes | None:
            return None if a is None else np.asarray(a, np.float32).tobytes()

        return (lkey, self.tree_density, self.treeline_scale, raw(self.fresh_snow), raw(self.snow_contrast),
                raw(self.open_ground))


def _sun_dir(elev_deg: float, az_deg: float) -> np.ndarray:
    e, a = np.radians(elev_deg), np.radians(az_deg)
    return np.array([np.cos(e) * np.cos(a), np.cos(e) * np.sin(a), np.sin(e)])


def _lighting(preset: str) -> Lighting:
    if preset == "forest-winter":
        return Lighting(sun_dir=_sun_dir(17.0, 35.0), sun_rgb=(3.6, 3.3, 2.8), sky_rgb=(0.30, 0.38, 0.52),
                        zenith_rgb=(0.9, 1.6, 3.2), horizon_rgb=(3.0, 3.4, 3.9), halo_rgb=(60.0, 55.0, 45.0))
    return Lighting(sun_dir=_sun_dir(15.0, 250.0), sun_rgb=(3.0, 2.9, 2.7), sky_rgb=(0.45, 0.55, 0.75),
                    zenith_rgb=(1.2, 2.2, 4.5), horizon_rgb=(4.0, 4.5, 5.2), halo_rgb=(40.0, 38.0, 34.0))


def _place_away_from_path(rng: np.random.Generator, n: int, half_m: float, path_xy: np.ndarray,
                          clearance_m: np.ndarray | float, min_r_m: float = 0.0) -> np.ndarray:
    """Uniform points in [-half, half]^2 whose distance to the path exceeds ``clearance`` (and to the origin
    ``min_r_m``); returns float64 (M, 2), M <= n."""
    pts = rng.uniform(-half_m, half_m, (n, 2))
    clear = np.broadcast_to(np.asarray(clearance_m, dtype=np.float64), (n,))
    keep = np.hypot(pts[:, 0], pts[:, 1]) >= min_r_m
    for i in range(0, n, 256):
        d = np.min(np.linalg.norm(pts[i:i + 256, None, :] - path_xy[None, ::4, :], axis=2), axis=1)
        keep[i:i + 256] &= d > clear[i:i + 256]
    return pts[keep]


def _bin_of_xy(table: np.ndarray, xy: np.ndarray) -> np.ndarray:
    """Value of a polar-angle table (see :class:`SceneOptions`) at world points ``xy`` float64 (M, 2): (M,)."""
    nb = table.size
    phi = np.arctan2(xy[:, 1], xy[:, 0])
    return np.asarray(table)[np.clip(((phi + np.pi) * (nb / (2 * np.pi))).astype(np.int64), 0, nb - 1)]


def _clear_open(prims: Primitives, open_ground: np.ndarray | None) -> Primitives:
    """``prims`` without the trees standing in open ground (its bins above 0.5)."""
    if open_ground is None or prims.cylinders.size == 0:
        return prims
    keep = _bin_of_xy(open_ground, prims.cylinders[:, :2]) <= 0.5
    return Primitives(cylinders=prims.cylinders[keep], cyl_albedo=prims.cyl_albedo[keep],
                      cyl_kind=prims.cyl_kind[keep], spheres=prims.spheres, sph_albedo=prims.sph_albedo,
                      sph_kind=prims.sph_kind, boxes=prims.boxes, box_albedo=prims.box_albedo,
                      box_kind=prims.box_kind)


def _forest_prims(rng: np.random.Generator, path_xy: np.ndarray, density: float = 1.0) -> Primitives:
    n = max(1, round(520 * density))
    radius = rng.uniform(0.07, 0.32, n)
    xy = rng.uniform(-48.0, 48.0, (n, 2))
    d = np.min(np.linalg.norm(xy[:, None, :] - path_xy[None, ::4, :], axis=2), axis=1)
    keep = d > 1.6 + radius
    xy, radius = xy[keep], radius[keep]
    m = len(xy)
    height = rng.uniform(6.0, 16.0, m)
    birch = rng.random(m) < 0.22
    dark = np.stack([rng.uniform(0.07, 0.13, m), rng.uniform(0.06, 0.10, m), rng.uniform(0.05, 0.08, m)], 1)
    white = np.stack([rng.uniform(0.55, 0.7, m)] * 3, 1) * np.array([1.0, 0.98, 0.93])
    albedo = np.where(birch[:, None], white, dark).astype(np.float32)
    cylinders = np.column_stack([xy, radius, height])
    rocks = _place_away_from_path(rng, 40, 40.0, path_xy, 3.0)
    rr = rng.uniform(0.3, 1.1, len(rocks))
    spheres = np.column_stack([rocks, rr * 0.25, rr])
    sph_albedo = (np.stack([rng.uniform(0.18, 0.3, len(rocks))] * 3, 1) * np.array([1.0, 0.97, 0.95]))
    return Primitives(cylinders=cylinders, cyl_albedo=albedo, cyl_kind=birch.astype(np.int32), spheres=spheres,
                      sph_albedo=sph_albedo.astype(np.float32), sph_kind=np.zeros(len(rocks), np.int32))


def _campus_prims(rng: np.random.Generator, path_xy: np.ndarray) -> Primitives:
    boxes, box_albedo = [], []
    n_b = 9
    for i in range(n_b):
        az = 2 * np.pi * (i + rng.uniform(-0.25, 0.25)) / n_b
        dist = rng.uniform(26.0, 38.0)
        w, dpt, h = rng.uniform(10.0, 22.0), rng.uniform(8.0, 14.0), rng.uniform(7.0, 22.0)
        cx, cy = dist * np.cos(az), dist * np.sin(az)
        boxes.append([cx - w / 2, cy - dpt / 2, 0.0, cx + w / 2, cy + dpt / 2, h])
        tone = rng.uniform(0.25, 0.55)
        box_albedo.append(np.array([tone, tone * rng.uniform(0.9, 1.0), tone * rng.uniform(0.8, 0.95)]))
    trees = _place_away_from_path(rng, 160, 24.0, path_xy, 2.5)
    trees = trees[:45]
    m = len(trees)
    radius = rng.uniform(0.12, 0.3, m)
    height = rng.uniform(3.0, 5.0, m)
    crown = rng.uniform(1.6, 2.8, m)
    cylinders = np.column_stack([trees, radius, height])
    cyl_albedo = np.stack([rng.uniform(0.09, 0.14, m), rng.uniform(0.08, 0.11, m), rng.uniform(0.06, 0.08, m)], 1)
    spheres = np.column_stack([trees, height + crown * 0.6, crown])
    sph_albedo = np.stack([rng.uniform(0.05, 0.09, m), rng.uniform(0.10, 0.16, m), rng.uniform(0.03, 0.05, m)], 1)
    return Primitives(cylinders=cylinders, cyl_albedo=cyl_albedo.astype(np.float32), cyl_kind=np.zeros(m, np.int32),
                      spheres=spheres, sph_albedo=sph_albedo.astype(np.float32), sph_kind=np.ones(m, np.int32),
                      boxes=np.array(boxes), box_albedo=np.array(box_albedo, np.float32),
                      box_kind=np.ones(n_b, np.int32))


def _shadow_mask(prims: Primitives, sun_dir: np.ndarray, origin_m: tuple[float, float], texel_m: float,
                 size: int) -> np.ndarray:
    """Cast shadows of all primitives on the ground: float32 (N, N) in [0, 1] (1 = full shadow)."""
    mask = np.zeros((size, size), np.uint8)
    shift = -sun_dir[:2] / sun_dir[2]  # ground offset per metre of height

    def fill(points3: np.ndarray) -> None:
        ground = points3[:, :2] + points3[:, 2:3] * shift
        px = (ground - np.asarray(origin_m)) / texel_m
        if px.max() < -1 or px.min() > size + 1 or np.ptp(px[:, 0]) > 4 * size:
            return
        hull = cv2.convexHull(np.round(px * 16).astype(np.int32))
        cv2.fillConvexPoly(mask, hull, 255, lineType=cv2.LINE_AA, shift=4)

    ang = np.linspace(0, 2 * np.pi, 16, endpoint=False)
    ring = np.stack([np.cos(ang), np.sin(ang)], 1)
    for x, y, r, h in prims.cylinders:
        base = np.column_stack([x + r * ring[:, 0], y + r * ring[:, 1], np.zeros(16)])
        top = base.copy()
        top[:, 2] = h
        fill(np.vstack([base, top]))
    sph = np.array([[np.cos(a) * np.cos(b), np.sin(a) * np.cos(b), np.sin(b)]
                    for a in ang for b in np.linspace(-1.4, 1.4, 7)])
    for x, y, z, r in prims.spheres:
        pts = np.array([x, y, z]) + r * sph
        pts[:, 2] = np.maximum(pts[:, 2], 0.0)
        fill(pts)
    for x0, y0, z0, x1, y1, z1 in prims.boxes:
        corners = np.array([[a, b, c] for a in (x0, x1) for b in (y0, y1) for c in (z0, z1)])
        fill(corners)
    soft = cv2.GaussianBlur(mask.astype(np.float32) / 255.0, (0, 0), sigmaX=max(0.6, 0.05 / texel_m))
    return soft


def _fresh_snow_weight(table: np.ndarray, half_m: float, texel_m: float, n: int) -> np.ndarray:
    """Fresh-snow weight of every texel of the square [-half_m, half_m]^2 from its polar angle: float32 (N, N)."""
    c = (np.arange(n, dtype=np.float64) + 0.5) * texel_m - half_m
    phi = np.arctan2(c[:, None], c[None, :])  # rows = y, cols = x
    nb = table.size
    idx = np.clip(((phi + np.pi) * (nb / (2 * np.pi))).astype(np.int64), 0, nb - 1)
    return np.asarray(table, np.float32)[idx]


#: RMS of a :class:`ValueNoise` field of 5 octaves (0.28 measured over 10^6 samples; divides it to unit RMS)
_FINE_RMS = 0.28
#: RMS contrast (std / mean of the albedo) of the forest ground's 1/f texture: the real sample's ground at 320x200
#: has a median local contrast of 0.21 (8x8-pixel blocks of the linear green level, 16 ms, emulator/DATASET.md)
GROUND_RMS_CONTRAST = 0.2
#: albedo of the forest snow and of its scattered litter (twigs and needles covering part of a texel: a Michelson
#: contrast of 0.31 against the snow, where a bare dark twig (0.12) would give 0.76)
SNOW_ALBEDO = 0.86
SPECK_ALBEDO = 0.45


def _ground_albedo(preset: str, noises: dict[str, ValueNoise], path_dist_m: np.ndarray, half_m: float,
                   texel_m: float, fresh_snow: np.ndarray | None = None,
                   snow_contrast: np.ndarray | None = None) -> list[np.ndarray]:
    """Per-channel ground albedo of the square [-half_m, half_m]^2 (three float32 (N, N) arrays, rows = y).

    ``fresh_snow`` (see :class:`SceneOptions`) covers the ground by smooth, nearly textureless snow where it is 1;
    ``snow_contrast`` gives that snow a natural 1/f texture of that RMS contrast."""
    albedo = _base_albedo(preset, noises, path_dist_m, half_m, texel_m)
    if fresh_snow is None or not np.any(fresh_snow > 0):
        return albedo
    n = path_dist_m.shape[0]
    w = _fresh_snow_weight(fresh_snow, half_m, texel_m, n)
    smooth = np.float32(0.9) + np.float32(0.012) * noises["big"].grid(-half_m, -half_m, texel_m, n)
    if snow_contrast is not None and np.any(snow_contrast > 0):
        c = _fresh_snow_weight(snow_contrast, half_m, texel_m, n)
        smooth += np.float32(0.9 / _FINE_RMS) * c * noises["fine"].grid(-half_m, -half_m, texel_m, n)
    return [(a * (1 - w) + w * smooth * np.float32(c)).astype(np.float32)
            for a, c in zip(albedo, (1.0, 1.02, 1.06))]


def _base_albedo(preset: str, noises: dict[str, ValueNoise], path_dist_m: np.ndarray, half_m: float,
                 texel_m: float) -> list[np.ndarray]:
    n = path_dist_m.shape[0]

    def field(name: str) -> np.ndarray:
        return noises[name].grid(-half_m, -half_m, texel_m, n)

    fine = field("fine")
    big = field("big")
    mid = field("mid")
    # small scattered objects (twigs, needles, stones): texture for visual odometry
    specks = smoothstep(0.42, 0.5, field("speck"))
    if preset == "forest-winter":
        # every ground surface carries a 1/f texture of the real ground's local contrast (tracks, sastrugi, needle
        # litter, dirt); the specks are scattered litter partly covering a texel (emulator/DATASET.md)
        tex = np.float32(GROUND_RMS_CONTRAST / _FINE_RMS) * fine
        snow = np.float32(SNOW_ALBEDO) * (1 + tex)
        snow = snow * (1 - specks) + specks * np.float32(SPECK_ALBEDO)
        bare = smoothstep(0.32, 0.40, big)  # bare patches: litter and earth
        trail = 1.0 - smoothstep(0.55, 0.95, path_dist_m + 0.25 * fine)
        out = []
        for snow_c, litter_c, trail_c in ((1.0, 0.15, 0.46), (1.02, 0.115, 0.43), (1.07, 0.085, 0.39)):
            a = snow * np.float32(snow_c)
            a = a * (1 - bare) + bare * np.float32(litter_c) * (1 + tex)
            a = a * (1 - trail) + trail * np.float32(trail_c) * (1 + tex)
            out.append(a.astype(np.float32))
        return out
    grass = 1 + np.float32(GROUND_RMS_CONTRAST / _FINE_RMS) * fine + 0.5 * specks
    path = 1.0 - smoothstep(1.0, 1.3, path_dist_m)
    plaza = smoothstep(0.30, 0.36, big)
    # paving slabs of the plazas: 1.2 m grid of dark joints
    c = (np.arange(n, dtype=np.float32) + 0.5) * np.float32(texel_m) - np.float32(half_m)
    jx = np.abs((c / np.float32(1.2)) % 1.0 - 0.5) > 0.47
    joints = (jx[None, :] | jx[:, None]).astype(np.float32)
    plaza_tex = (1 + 0.08 * fine) * (1 - 0.6 * joints)
    out = []
    for grass_c, asphalt_c, plaza_c in ((0.10, 0.11, 0.36), (0.16, 0.11, 0.35), (0.06, 0.12, 0.32)):
        a = np.float32(grass_c) * grass
        a = a * (1 - plaza) + plaza * np.float32(plaza_c) * plaza_tex
        a = a * (1 - path) + path * np.float32(asphalt_c) * (1 + 0.3 * mid)
        out.append(a.astype(np.float32))
    return out


def _ground_level(preset: str, lighting: Lighting, prims: Primitives, noises: dict[str, ValueNoise],
                  path_xy: np.ndarray, half_m: float, size: int, pad: int = 4,
                  fresh_snow: np.ndarray | None = None, snow_contrast: np.ndarray | None = None) -> GroundTexture:
    texel = 2 * half_m / size
    origin = (-half_m, -half_m)
    canvas = np.full((size, size), 255, np.uint8)
    pts = np.round((path_xy - np.asarray(origin)) / texel * 16).astype(np.int32)
    cv2.polylines(canvas, [pts], True, 0, thickness=1, lineType=cv2.LINE_8, shift=4)
    path_dist = cv2.distanceTransform(canvas, cv2.DIST_L2, 5).astype(np.float32) * np.float32(texel)
    albedo = _ground_albedo(preset, noises, path_dist, half_m, texel, fresh_snow, snow_contrast)
    if max(lighting.sun_rgb) > 0:
        shadow = _shadow_mask(prims, lighting.sun_dir, origin, texel, size)
        direct = np.float32(max(lighting.sun_dir[2], 0.0)) * (1.0 - shadow)
    else:  # no direct sun (dusk, overcast): no cast shadows to draw
        direct = np.zeros((size, size), np.float32)
    stacked = np.zeros((3 * (size + pad), size), np.float32)
    for ch in range(3):
        light = np.float32(lighting.sun_rgb[ch]) * direct + np.float32(lighting.sky_rgb[ch])
        r0 = ch * (size + pad)
        stacked[r0:r0 + size] = albedo[ch] * light
        stacked[r0 + size:r0 + size + pad] = stacked[r0 + size - 1]
    return GroundTexture(origin, texel, size, pad, stacked)


def _downsample(level: GroundTexture, factor: int) -> GroundTexture:
    """The same ground at ``factor`` x coarser texels (area average of each channel plane)."""
    n = level.size // factor
    stacked = np.zeros((3 * (n + level.pad), n), np.float32)
    for ch in range(3):
        src = level.stacked[ch * (level.size + level.pad):ch * (level.size + level.pad) + level.size]
        r0 = ch * (n + level.pad)
        stacked[r0:r0 + n] = cv2.resize(src, (n, n), interpolation=cv2.INTER_AREA)
        stacked[r0 + n:r0 + n + level.pad] = stacked[r0 + n - 1]
    return GroundTexture(level.origin_m, level.texel_m * factor, n, level.pad, stacked)


def build_scene(preset: str, seed: int, trajectory: LoopTrajectory, detail: float = 1.0,
                options: SceneOptions | None = None) -> Scene:
    """Draw the world of ``preset`` from ``seed``. ``detail`` scales the texture resolutions (1.0: 4 cm near);
    ``options`` (a scenario's lighting and content) default to the preset's own."""
    if preset not in PRESETS:
        raise BracketryError(f"unknown preset {preset!r} (choose from {', '.join(PRESETS)})")
    opts = options if options is not None else SceneOptions()
    rng = np.random.default_rng(np.random.SeedSequence([seed, PRESETS.index(preset)]))
    lighting = opts.lighting if opts.lighting is not None else _lighting(preset)
    path_xy = trajectory.centreline()
    prims = (_forest_prims(rng, path_xy, opts.tree_density) if preset == "forest-winter"
             else _campus_prims(rng, path_xy))
    prims = _clear_open(prims, opts.open_ground)
    noises = {"fine": ValueNoise(rng, 0.6, octaves=5), "mid": ValueNoise(rng, 0.25, octaves=3),
              "big": ValueNoise(rng, 9.0, octaves=4), "speck": ValueNoise(rng, 0.16, octaves=2)}
    n0 = round(2048 * detail / 64) * 64
    snow = opts.fresh_snow
    sc = opts.snow_contrast
    fine = _ground_level(preset, lighting, prims, noises, path_xy, 40.96, n0, fresh_snow=snow, snow_contrast=sc)
    levels = [fine, _downsample(fine, 4),
              _ground_level(preset, lighting, prims, noises, path_xy, 128.0, 512, fresh_snow=snow, snow_contrast=sc)]
    n_az = 1440
    tl = ValueNoise(rng, 0.05, octaves=4, lattice=64)
    az = np.linspace(0.0, 1.0, n_az, endpoint=False, dtype=np.float32)[None, :]
    hnoise = tl(az * 3.2, np.zeros_like(az))[0]
    base = 17.0 if preset == "forest-winter" else 11.0
    heights = (base + 6.0 * hnoise + 2.0 * rng.standard_normal(n_az) * 0.3).astype(np.float32)
    if opts.treeline_scale != 1.0:
        heights = (heights * np.float32(opts.treeline_scale)).astype(np.float32)
    bark = (1.0 + 0.35 * ValueNoise(rng, 1.0, octaves=4, lattice=64)(
        *np.meshgrid(np.arange(256, dtype=np.float32) / 5.0, np.arange(64, dtype=np.float32) / 40.0))).astype(
        np.float32)
    treeline_albedo = (0.05, 0.06, 0.045) if preset == "forest-winter" else (0.06, 0.09, 0.04)
    return Scene(preset, lighting, prims, build_atlas(levels), 120.0, heights, treeline_albedo, bark,
                 snow_caps=preset == "forest-winter")
