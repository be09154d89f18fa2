"""The synthetic world as a frame source: ``World(preset, seed, resolution)``, ``render``, ``pose``.

Frames of the simulated stereo rig: :meth:`World.render` gives the raw RGGB 12-bit codes a camera side would record
at time ``t_s`` with exposure ``exposure_us``; :meth:`World.pose` gives the ground-truth pose of a camera at ``t_s``
in the ground-truth frame (the left camera's optical frame at t = 0; x right, y down, z forward), the frame of
``groundtruth.txt``.
"""

from __future__ import annotations

import dataclasses
import inspect
import itertools
import json
from collections import OrderedDict
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np

from bracketry_base.errors import BracketryError
from bracketry_base.options import parse_resolution as parse_resolution
from bracketry_emulator.synth import blur
from bracketry_emulator.synth.blur import Motion
from bracketry_emulator.synth.calibration import SIDES, StereoCalibration, default_calibration
from bracketry_emulator.synth.camera_model import CameraModel
from bracketry_emulator.synth.render import RenderResult, SideRenderer
from bracketry_emulator.synth.scenario import (
    LightField,
    Scenario,
    calibration_from_dict,
    calibration_to_dict,
    scenario_from_dict,
    scenario_scene,
)
from bracketry_emulator.synth.scene import PRESETS, Scene, build_scene
from bracketry_emulator.synth.trajectory import LoopTrajectory, mat_mul

DEFAULT_RESOLUTION = (960, 600)
#: how a frame's exposure interval is integrated (see :class:`World`)
BLUR_METHODS = ("reproject", "render")
_SCENE_CACHE: OrderedDict[tuple, Scene] = OrderedDict()
_SCENE_CACHE_SIZE = 2


def cached_scene(preset: str, seed: int, trajectory: LoopTrajectory, detail: float) -> Scene:
    """:func:`build_scene`, remembering the last two scenes (a scene is read-only once built)."""
    key = (preset, seed, detail, tuple((f.name, repr(getattr(trajectory, f.name)))
                                       for f in dataclasses.fields(trajectory) if f.init))
    scene = _SCENE_CACHE.get(key)
    if scene is None:
        scene = build_scene(preset, seed, trajectory, detail)
        _SCENE_CACHE[key] = scene
        while len(_SCENE_CACHE) > _SCENE_CACHE_SIZE:
            _SCENE_CACHE.popitem(last=False)
    _SCENE_CACHE.move_to_end(key)
    return scene



class World:
    """A procedural HDR world seen by the synthetic stereo rig.

    Args:
        preset: "forest-winter" or "campus-summer".
        seed: integer; the world content, the path and every noise draw follow from it.
        resolution: (width, height) in pixels, both even.
        calibration: the stereo rig; default: the real sample's intrinsics scaled to ``resolution``, baseline 0.18 m.
        camera: the camera model (default :class:`CameraModel`: sRGB-encoded 12-bit codes like the real sample).
        trajectory: the walk (default :class:`LoopTrajectory`, 2 km/h).
        scenario: a :class:`~bracketry_emulator.synth.scenario.Scenario` (its sun, content and lighting events over
            time: the radiance at ``t_s`` is lit as at ``t_s``); None: the preset's fixed light. Its preset must be
            ``preset`` (see :func:`world_from_scenario`).
        detail: ground texture resolution factor (1.0: 4 cm texels near the path).
        motion_blur: integrate the moving scene over each exposure [t_s, t_s + exposure] (on by default; off:
            the frame is the instantaneous render at its mid-exposure instant, the time of its ground-truth pose).
        blur_px: the image motion between consecutive instants of an exposure, at most (pixels; the number of
            instants follows from the fastest-moving pixel over the exposure, up to ``blur_max``).
        blur_method: "reproject" (one render at the frame's mid-exposure, warped by its range to every instant: see
            :mod:`bracketry_emulator.synth.blur`) or "render" (a full render at every instant: exact, costly).
        blur_renders: with "reproject", ray cast a frame up to this many times (each render moved to its share of
            the instants): more renders average out more of the aliasing of a point-sampled render.
    """

    def __init__(self, preset: str = "forest-winter", seed: int = 0,
                 resolution: tuple[int, int] = DEFAULT_RESOLUTION, calibration: StereoCalibration | None = None,
                 camera: CameraModel | None = None, trajectory: LoopTrajectory | None = None,
                 scenario: Scenario | None = None,
                 detail: float = 1.0, cache_size: int = 8, motion_blur: bool = True,
                 blur_px: float = 1.0, blur_max: int = 64, blur_method: str = "reproject",
                 blur_renders: int = 1) -> None:
        if preset not in PRESETS:
            raise BracketryError(f"unknown preset {preset!r} (choose from {', '.join(PRESETS)})")
        w, h = int(resolution[0]), int(resolution[1])
        if w % 2 or h % 2 or w < 16 or h < 16:
            raise BracketryError(f"resolution {w}x{h}: width and height must be even and >= 16")
        self.preset = preset
        self.seed = int(seed)
        if blur_method not in BLUR_METHODS:
            raise BracketryError(f"unknown blur method {blur_method!r} (choose from {', '.join(BLUR_METHODS)})")
        if not blur_px > 0:
            raise BracketryError(f"blur_px must be > 0 (got {blur_px})")
        self.motion_blur = bool(motion_blur)
        self.blur_px = float(blur_px)
        self.blur_max = max(1, int(blur_max))
        self.blur_method = blur_method
        self.blur_renders = max(1, int(blur_renders))
        self.resolution = (w, h)
        self.calibration = calibration if calibration is not None else default_calibration(w, h)
        if self.calibration.size != (w, h):
            self.calibration = self.calibration.scaled(w, h)
        self.camera = camera if camera is not None else CameraModel()
        self.trajectory = trajectory if trajectory is not None else LoopTrajectory()
        self.detail = float(detail)
        self.scenario = scenario
        self._light: LightField | None = None
        if scenario is None:
            self.scene: Scene = cached_scene(preset, self.seed, self.trajectory, detail)
        else:
            if scenario.preset != preset:
                raise BracketryError(f"scenario {scenario.name!r} is of preset {scenario.preset!r}, not {preset!r}")
            self.scene = scenario_scene(scenario, self.seed, self.trajectory, self.detail)
            self._light = LightField(scenario, self.scene, self.trajectory, self.seed)
        self._renderers: dict[str, SideRenderer] = {}
        self._cell_rays: dict[str, blur.CellRays] = {}
        self._gain: dict[str, np.ndarray] = {}
        self._cache: OrderedDict[tuple[str, float], RenderResult] = OrderedDict()
        self._cache_size = cache_size
        R0, p0 = self.trajectory.pose(0.0)
        self._R_gw = R0.T  # world -> ground-truth frame rotation
        self._p0 = p0

    # ------------------------------------------------------------------ geometry
    def _check_side(self, side: str) -> None:
        if side not in SIDES:
            raise BracketryError(f"unknown camera side {side!r} (expected left or right)")

    def world_pose(self, t_s: float, side: str = "left") -> tuple[np.ndarray, np.ndarray]:
        """Pose of a camera in the scene frame (z up): (R_wc float64 (3, 3), optical centre p_w float64 (3,) m)."""
        self._check_side(side)
        R, p = self.trajectory.pose(float(t_s))
        return R, p + mat_mul(R, self.calibration.offset_m(side))

    def pose(self, t_s: float, side: str = "left") -> np.ndarray:
        """Ground-truth pose: camera-to-frame transform, float64 (4, 4), in the ground-truth frame (the left camera's
        optical frame at t = 0), i.e. what ``groundtruth.txt`` holds for the left camera."""
        R, p = self.world_pose(t_s, side)
        T = np.eye(4)
        T[:3, :3] = mat_mul(self._R_gw, R)
        T[:3, 3] = mat_mul(self._R_gw, p - self._p0)
        return T

    # ------------------------------------------------------------------ rendering
    def _renderer(self, side: str) -> SideRenderer:
        self._check_side(side)
        if side not in self._renderers:
            intr = self.calibration.side(side)
            self._renderers[side] = SideRenderer(self.scene, intr)
            w, h = self.resolution
            self._gain[side] = (self.camera.qe_map(w, h) *
                                self.camera.vignetting_map(w, h, intr.cx, intr.cy)).astype(np.float32)
        return self._renderers[side]

    def radiance(self, side: str, t_s: float) -> RenderResult:
        """Scene radiance and range seen by ``side`` at ``t_s`` (cached for the last few calls)."""
        key = (side, float(t_s))
        hit = self._cache.get(key)
        if hit is not None:
            self._cache.move_to_end(key)
            return hit
        renderer = self._renderer(side)
        R, p = self.world_pose(t_s, side)
        res = renderer.render(R, p)
        if self._light is not None:  # the scenario's light at this instant
            res = self._light.apply(res, renderer, R, p, float(t_s))
        self._cache[key] = res
        while len(self._cache) > self._cache_size:
            self._cache.popitem(last=False)
        return res

    def _cells(self, side: str) -> blur.CellRays:
        if side not in self._cell_rays:
            w, h = self.resolution
            self._cell_rays[side] = blur.CellRays.of(self._renderer(side).rays, w, h)
        return self._cell_rays[side]

    def motions(self, side: str, t_ref_s: float, intervals: Sequence[tuple[float, float]]) -> list[Motion]:
        """The image motion of each frame exposed over ``(t_s, exposure_us)`` in ``intervals`` relative to the render
        of ``side`` at ``t_ref_s``, linear over its exposure (see :mod:`bracketry_emulator.synth.blur`).

        Flows are projected at each frame's mid-exposure (the render's own instant has none); a frame's velocity is
        the difference of the flows of its neighbours in time (with the render's instant), or, for a lone frame,
        of the flows at the ends of its exposure."""
        res = self.radiance(side, t_ref_s)
        cells = self._cells(side)
        intr = self.calibration.side(side)
        R_ref, p_ref = self.world_pose(t_ref_s, side)
        memo: dict[float, tuple[np.ndarray, np.ndarray] | None] = {float(t_ref_s): None}

        def flow(t: float) -> tuple[np.ndarray, np.ndarray] | None:
            if t not in memo:
                R, p = self.world_pose(t, side)
                memo[t] = blur.cell_flow(cells, res.range_m, intr, R_ref, p_ref, R, p)
            return memo[t]

        def diff(a: float, b: float) -> tuple[np.ndarray, np.ndarray]:
            fa, fb = flow(a), flow(b)
            zero = np.zeros_like(cells.gx)
            (ua, va), (ub, vb) = fa if fa is not None else (zero, zero), fb if fb is not None else (zero, zero)
            inv = np.float32(1.0 / (b - a))
            return (ub - ua) * inv, (vb - va) * inv

        mids = [self.mid_exposure_s(t, e) for t, e in intervals]
        points = sorted({*mids, float(t_ref_s)})
        out = []
        for (t_s, exposure_us), mid in zip(intervals, mids):
            if len(points) < 2:
                vu, vv = diff(float(t_s), float(t_s) + float(exposure_us) * 1e-6)
            else:
                i = points.index(mid)
                vu, vv = diff(points[max(0, i - 1)], points[min(len(points) - 1, i + 1)])
            f = flow(mid)
            out.append(Motion(mid, None if f is None else f[0], None if f is None else f[1], vu, vv))
        return out

    def blur_times_s(self, t_s: float, exposure_us: float, side: str = "left",
                     t_ref_s: float | None = None) -> list[float]:
        """Instants averaged for a frame of ``side`` exposed from ``t_s`` for ``exposure_us``: the mid-exposure
        instant without motion blur; else the centres of n equal slices of the exposure, n such that no pixel moves
        more than ``blur_px`` between consecutive instants (at most ``blur_max``; measured on the render at
        ``t_ref_s``, default mid-exposure)."""
        mid = self.mid_exposure_s(t_s, exposure_us)
        if not self.motion_blur:
            return [mid]
        motion = self.motions(side, mid if t_ref_s is None else float(t_ref_s), [(t_s, exposure_us)])[0]
        return blur.sub_instants(t_s, exposure_us, motion.max_px(exposure_us * 1e-6), self.blur_px, self.blur_max)

    def _gained(self, side: str, radiance: np.ndarray) -> np.ndarray:
        """The rate of photo-electrons of every pixel: radiance x QE x vignetting, with the lens's veiling glare."""
        self._renderer(side)
        return self.camera.veil(radiance * self._gain[side])

    def rates_e_per_us(self, side: str, intervals: Sequence[tuple[float, float]],
                       t_ref_s: float | None = None) -> list[np.ndarray]:
        """Expected photo-electrons per microsecond of every pixel (radiance x QE x vignetting), float32 (H, W), of
        each frame exposed over ``(t_s, exposure_us)`` in ``intervals``, averaged over its exposure (see
        :meth:`blur_times_s`); without motion blur, at its mid-exposure instant.

        ``t_ref_s`` (method "reproject"): the one render every frame is warped from (default: each frame's own
        mid-exposure). The simulated rig renders one instant per bracket cycle this way."""
        if not self.motion_blur:
            return [self._gained(side, self.radiance(side, self.mid_exposure_s(t, e)).radiance) for t, e in intervals]
        if t_ref_s is None:  # each frame from its own render(s)
            return [self._gained(side, self._frame_radiance(side, t, e)) for t, e in intervals]
        out = []
        for (t_s, exposure_us), motion in zip(intervals, self.motions(side, float(t_ref_s), intervals)):
            times = blur.sub_instants(t_s, exposure_us, motion.max_px(exposure_us * 1e-6), self.blur_px,
                                      self.blur_max)
            if self.blur_method == "render":
                rad = self.integrate(side, times)
            else:
                rad = blur.average_warps(self.radiance(side, float(t_ref_s)).radiance, self._cells(side), motion,
                                         times)
            out.append(self._gained(side, rad))
        return out

    def _frame_radiance(self, side: str, t_s: float, exposure_us: float) -> np.ndarray:
        """Radiance float32 (H, W) of one frame averaged over its exposure from its own renders: the instants of
        :meth:`blur_times_s` cut into ``min(blur_renders, n)`` equal runs, each run ray cast at its middle and that
        render moved to the run's instants (several renders average out the aliasing of a point-sampled render)."""
        mid = self.mid_exposure_s(t_s, exposure_us)
        motion = self.motions(side, mid, [(t_s, exposure_us)])[0]
        times = blur.sub_instants(t_s, exposure_us, motion.max_px(exposure_us * 1e-6), self.blur_px, self.blur_max)
        if self.blur_method == "render":
            return self.integrate(side, times)
        k = min(self.blur_renders, len(times))
        if k == 1:
            return blur.average_warps(self.radiance(side, mid).radiance, self._cells(side), motion, times)
        bounds = [round(i * len(times) / k) for i in range(k + 1)]
        acc = np.zeros_like(self.radiance(side, mid).radiance)
        for a, b in itertools.pairwise(bounds):
            run = times[a:b]
            ref = 0.5 * (run[0] + run[-1])
            m = self.motions(side, ref, [(t_s, exposure_us)])[0]
            acc += blur.average_warps(self.radiance(side, ref).radiance, self._cells(side), m, run) * \
                np.float32(len(run) / len(times))
        return acc

    def integrate(self, side: str, times_s: Sequence[float]) -> np.ndarray:
        """Mean radiance float32 (H, W) of full renders at ``times_s`` (the exact integral, as dense as the
        instants)."""
        rad = self.radiance(side, times_s[0]).radiance.copy()
        for t in times_s[1:]:
            rad += self.radiance(side, t).radiance
        rad *= np.float32(1.0 / len(times_s))
        return rad

    def rate_e_per_us(self, side: str, t_s: float, exposure_us: float | None = None) -> np.ndarray:
        """Expected photo-electrons per microsecond of every pixel (radiance x QE x vignetting), float32 (H, W).

        Without ``exposure_us``: at the instant ``t_s``; with it: of the frame exposed from ``t_s`` for
        ``exposure_us`` (see :meth:`rates_e_per_us`)."""
        if exposure_us is None:
            return self._gained(side, self.radiance(side, float(t_s)).radiance)
        return self.rates_e_per_us(side, [(t_s, exposure_us)])[0]

    @staticmethod
    def mid_exposure_s(t_s: float, exposure_us: float) -> float:
        """The mid-exposure instant of a frame triggered at ``t_s`` (s) exposed ``exposure_us``: its timestamp and
        the time of its ground-truth pose (the rig's ``FrameMeta.mid_exposure_host_ns``)."""
        return float(t_s) + 0.5 * float(exposure_us) * 1e-6

    def frame_rng(self, side: str, t_s: float, exposure_us: float) -> np.random.Generator:
        """The deterministic noise generator of one frame (from the seed, the side, the time and the exposure)."""
        key = [self.seed, SIDES.index(side), round(t_s * 1e9), round(exposure_us * 1e3)]
        return np.random.default_rng(np.random.SeedSequence(key))

    def render(self, side: str, t_s: float, exposure_us: float, rng: np.random.Generator | None = None,
               noise: bool = True) -> np.ndarray:
        """One raw frame: uint16 (H, W) RGGB Bayer 12-bit codes (0..4094) of ``side`` at ``t_s`` (seconds since the
        start of the walk) exposed ``exposure_us`` microseconds.

        ``rng`` draws the noise; None uses :meth:`frame_rng` (so the same call gives the same frame).
        ``noise=False`` gives the exact noise-free image. The exposure starts at ``t_s`` (the trigger); with
        ``motion_blur`` the scene is integrated over [t_s, t_s + exposure], else rendered at mid-exposure
        (``t_s + exposure / 2``: the instant of the frame's ground-truth pose, see :meth:`mid_exposure_s`)."""
        rate = self.rate_e_per_us(side, t_s, exposure_us)
        if not noise:
            return self.camera.expose(rate, exposure_us, None)
        return self.camera.expose(rate, exposure_us, rng if rng is not None else self.frame_rng(side, t_s,
                                                                                                exposure_us))

    def describe(self) -> dict:
        """World parameters for ``camera_model.json``."""
        tr = self.trajectory
        lt = self.scene.lighting
        return {
            "preset": self.preset,
            "seed": self.seed,
            "detail": self.detail,
            "trajectory_init": {f.name: (list(v) if isinstance(v := getattr(tr, f.name), tuple) else v)
                                for f in dataclasses.fields(tr) if f.init},
            "calibration": calibration_to_dict(self.calibration),
            "scenario": self.scenario.to_dict() if self.scenario is not None else None,
            "resolution": list(self.resolution),
            "baseline_m": self.calibration.baseline_m,
            "trajectory": {"kind": "loop", "length_m": tr.length_m, "speed_kmh": tr.speed_kmh,
                           "height_m": tr.height_m, "pitch_deg": tr.pitch_deg, "step_hz": tr.step_hz,
                           "bounce_m": tr.bounce_m, "roll_deg": tr.roll_deg, "sway_m": tr.sway_m},
            "sun": {"direction_world": [float(x) for x in lt.sun_dir],
                    "elevation_deg": float(np.degrees(np.arcsin(lt.sun_dir[2]))),
                    "disk_radiance": lt.disk_radiance},
            "groundtruth_frame": "left camera optical frame (x right, y down, z forward) at t = 0",
            "motion_blur": {"enabled": self.motion_blur, "method": self.blur_method, "max_step_px": self.blur_px,
                            "max_instants": self.blur_max, "renders_per_frame": self.blur_renders,
                            "exposure": "[trigger, trigger + exposure]",
                            "pose_and_timestamp": "mid-exposure (trigger + exposure / 2)"},
        }


def world_from_scenario(scenario: Scenario, seed: int | None = None, resolution: tuple[int, int] | None = None,
                        **kwargs: Any) -> World:
    """The World of ``scenario`` (its preset, route and light) with ``seed`` / ``resolution`` (default: the
    scenario's); other keyword arguments go to :class:`World` (camera, calibration, detail, ...)."""
    return World(scenario.preset, scenario.seed if seed is None else seed,
                 scenario.resolution if resolution is None else resolution, trajectory=scenario.trajectory(),
                 scenario=scenario, **kwargs)


def world_from_dataset(path: str | Path) -> World:
    """The exact World that wrote the synthetic trajectory folder ``path`` (from its ``camera_model.json``: camera
    model, world seed/resolution/detail, walk, calibration, blur settings and the scenario, if any).

    Frame k of the folder was exposed from world time ``t_s = start_s + k / fps`` (``recording`` in the same file:
    ``t0_ns``, ``start_s``, ``fps``); ``world.render(side, t_s, exposure_us)`` renders any exposure at that instant.
    Raises BracketryError when the folder is not a synthetic trajectory."""
    p = Path(path)
    info_path = p / "camera_model.json" if p.is_dir() else p
    try:
        info = json.loads(info_path.read_text())
        wd = info["world"]
    except (OSError, ValueError, KeyError, TypeError) as exc:
        raise BracketryError(f"not a synthetic dataset (no readable camera_model.json with 'world'): {p}") from exc
    cam_fields = {f.name for f in dataclasses.fields(CameraModel)}
    cam_args: dict[str, Any] = {k: (tuple(v) if isinstance(v, list) and k != "pcalib" else v) for k, v in info.items()
                if k in cam_fields}
    for name in ("dark_current_e_per_s", "blooming", "veiling_glare"):  # a camera written without them had none
        cam_args.setdefault(name, 0.0)
    camera = CameraModel(**cam_args)
    traj_d = dict(wd.get("trajectory_init") or {})
    if "wobble" in traj_d:
        traj_d["wobble"] = tuple(traj_d["wobble"])
    trajectory = LoopTrajectory(**traj_d) if traj_d else LoopTrajectory(
        speed_kmh=float(wd.get("trajectory", {}).get("speed_kmh", 2.0)))
    scenario = scenario_from_dict(wd["scenario"]) if wd.get("scenario") else None
    calib = calibration_from_dict(wd["calibration"]) if wd.get("calibration") else None
    blur = wd.get("motion_blur") or {}
    params = inspect.signature(World).parameters
    kwargs: dict[str, Any] = {}
    for key, name, kind in (("enabled", "motion_blur", bool), ("method", "blur_method", str),
                            ("max_step_px", "blur_px", float), ("max_instants", "blur_max", int),
                            ("renders_per_frame", "blur_renders", int),
                            ("slice_us", "blur_slice_us", float), ("max_slices", "blur_max", int)):
        if key in blur and name in params:
            kwargs[name] = kind(blur[key])
    world = World(wd["preset"], int(wd["seed"]), tuple(wd["resolution"]), calibration=calib, camera=camera,
                  trajectory=trajectory, detail=float(wd.get("detail", 1.0)), scenario=scenario, **kwargs)
    recorded_sun = wd.get("sun") or {}
    if not isinstance(recorded_sun, dict):
        raise BracketryError(f"{info_path}: world.sun is not a mapping")
    differ = sun_differences(recorded_sun, world.describe()["sun"])
    if differ:
        raise BracketryError(f"{p} was rendered with another sun than this code builds ({'; '.join(differ)}): "
                             "render it again (bracketry synth suite, or synth trajectory)")
    return world


def sun_differences(recorded: dict, rebuilt: dict, rel_tol: float = 1e-9) -> list[str]:
    """The entries of a ``camera_model.json`` world's ``sun`` (``recorded``; those it holds) that differ from
    ``rebuilt`` (:meth:`World.describe`'s): ``"key recorded -> rebuilt"`` each, numbers compared within ``rel_tol``."""
    out = []
    for key, was in recorded.items():
        now = rebuilt.get(key)
        try:
            a = np.atleast_1d(np.asarray(was, np.float64))
            b = np.atleast_1d(np.asarray(now, np.float64))
            same = a.shape == b.shape and bool(np.allclose(a, b, rtol=rel_tol, atol=0.0))
        except (TypeError, ValueError):  # not numbers (or None): the same only if equal
            same = was == now
        if not same:
            out.append(f"{key} {was} -> {now}")
    return out
