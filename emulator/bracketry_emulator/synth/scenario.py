"""Scenarios: a synthetic trajectory's route, pace, time of day, weather and lighting events, as data (YAML).

A scenario file (the shipped ones are in ``synth/scenarios/``; every key is optional except ``preset``)::

    scenario: 1                      # format version
    name: forest-canopy              # default: the file name
    description: dark canopy, then open sunlit snow
    preset: forest-winter            # world content: forest-winter | campus-summer
    seed: 0                          # world seed (the suite sets its own)
    duration_s: 60
    resolution: 640x400
    fps: 22
    brackets_ms: [1, 2, 4, 8, 16, 32]
    route: {length_m: 110, pace_kmh: 3.5, start_fraction: 0.0, wobble: [0.18, 0.08], turn_deg: 0,
            turn_period_s: 7}
    sun: {hour: 10.5, day_of_year: 40, latitude_deg: 46.8, route_heading_deg: 0}
                                     # or {elevation_deg: 20, azimuth_deg: 135} (azimuth: from north, clockwise)
    weather: {overcast: 0.0, glare: 1.0, intensity: 1.0}
    content: {tree_density: 1.0, treeline_scale: 1.0}
    lighting_events:
      - {kind: canopy, from: 0.10, to: 0.40, density: 0.985, edge_m: 1.5}  # route fractions [0, 1), wrap allowed
      - {kind: canopy_patches, from: 0.5, to: 0.9, density: 0.9, period_m: 9, duty: 0.5}
      - {kind: clouds, cover: 0.5, opacity: 0.95, speed_mps: 12, direction_deg: 90, size_m: 45}
      - {kind: fresh_snow, from: 0.55, to: 0.85, contrast: 0.0, open: false}
      - {kind: dimming, times_s: [0, 60], factors: [1.0, 0.1]}

How each part acts (all of it deterministic, from the world seed):

- **sun** (time of day -> elevation/azimuth by the solar declination and hour angle; intensity and colour by the
  air mass: per-channel extinction, redder when low; sky light falls with the elevation and, below the horizon,
  by 10x per 6 degrees: dusk) is baked into the world's pre-lit ground with its cast shadows (a 60 s trajectory
  sees one sun).
- **canopy** / **canopy_patches**: the light reaching every point of a sector of the world (the polar angles about
  the loop's centre that the route crosses between ``from`` and ``to``) is reduced by ``density`` (0.985: 6 stops);
  patches alternate along the route (``period_m``, ``duty``); ``edge_m`` is the width of the sector's soft edge
  (default 1.5 m; a forest edge onto a sunlit field is a few tens of centimetres). **clouds**: bands of cloud shadow
  (cells of ``size_m``, a share ``cover`` covered) drifting at ``speed_mps`` towards ``direction_deg`` (from north,
  clockwise); a shadowed point keeps its sky light and ``1 - opacity`` of the direct sun; the sun itself is hidden
  while the camera is in a cloud's shadow. **dimming**: one factor on all light over time (log-linear between the
  keys). These are applied to each render at the frame's instant ``t_s`` from the world position of every pixel's
  hit.
- **glare**: a veil ``glare * 0.01 * E_v / (angle^2 + 0.01^2)`` around a visible sun within 70 degrees of the
  optical axis (E_v: 2e4 x the atmosphere's transmission x the disk's solid angle, 0.092 of the sun's irradiance
  ``pi * sun_rgb``). The solar disk itself has the radiance that casts the direct light (``sun_rgb / disk_rad^2``):
  in view, it feeds the camera's veiling glare and blooming (:mod:`~bracketry_emulator.synth.camera_model`).
- **fresh_snow**: the ground of the sector becomes smooth, nearly textureless snow; ``contrast`` gives it a natural
  1/f texture of that RMS contrast (wind ripples, sastrugi, tracks: a few per cent), ``open: true`` takes the trees
  out of the sector (an open field or a frozen lake).
- **route.turn_deg** / **turn_period_s**: the walker looks around: a yaw of that amplitude (degrees) and period on
  top of the gait's sway (:class:`~bracketry_emulator.synth.trajectory.LoopTrajectory`).

``bracketry synth trajectory --scenario FILE`` renders one (the World of a scenario:
:func:`~bracketry_emulator.synth.world.world_from_scenario`); :func:`~bracketry_emulator.synth.world.world_from_dataset`
rebuilds the exact world of a written trajectory from its ``camera_model.json``.
"""

from __future__ import annotations

import copy
import dataclasses
import itertools
import math
from collections import OrderedDict
from collections.abc import Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import yaml

from bracketry_base.errors import BracketryError
from bracketry_base.options import parse_resolution
from bracketry_emulator.synth.calibration import SIDES, CameraIntrinsics, StereoCalibration
from bracketry_emulator.synth.render import RenderResult, SideRenderer, pseudo_angle
from bracketry_emulator.synth.scene import DISK_RAD, PRESETS, Lighting, Scene, SceneOptions, build_scene
from bracketry_emulator.synth.trajectory import RIG_PITCH_DEG, LoopTrajectory, mat_mul

FORMAT_VERSION = 1
#: folder of the shipped scenario files
SCENARIO_DIR = Path(__file__).with_name("scenarios")
EVENT_KINDS = ("canopy", "canopy_patches", "clouds", "fresh_snow", "dimming")
_N_BINS = 4096  # polar-angle bins of the canopy / fresh-snow tables
_N_CLOUD = 8192  # samples of one period of the cloud pattern
_EDGE_M = 1.5  # soft edge of a canopy sector along the route
_SCENE_CACHE: OrderedDict[tuple, Scene] = OrderedDict()

_TOP_KEYS = {"scenario", "name", "description", "subset", "preset", "seed", "duration_s", "resolution", "fps",
             "brackets_ms", "route", "sun", "weather", "content", "lighting_events"}
_SECTION_KEYS = {
    "route": {"length_m", "pace_kmh", "start_fraction", "wobble", "turn_deg", "turn_period_s"},
    "sun": {"hour", "day_of_year", "latitude_deg", "route_heading_deg", "elevation_deg", "azimuth_deg"},
    "weather": {"overcast", "glare", "intensity"},
    "content": {"tree_density", "treeline_scale"},
}
_EVENT_KEYS = {
    "canopy": {"from", "to", "density", "edge_m"},
    "canopy_patches": {"from", "to", "density", "period_m", "duty", "edge_m"},
    "clouds": {"cover", "opacity", "speed_mps", "direction_deg", "size_m"},
    "fresh_snow": {"from", "to", "contrast", "open"},
    "dimming": {"times_s", "factors"},
}


# ---------------------------------------------------------------------------------------------------- the data
@dataclass(frozen=True)
class Route:
    """The loop walked: its length (m), the pace (km/h), where the walk starts (fraction of the loop from polar
    angle 0, counter-clockwise) and its shape (the 2nd/3rd harmonic wobble of its radius)."""

    length_m: float = 80.0
    pace_kmh: float = 2.0
    start_fraction: float = 0.0
    wobble: tuple[float, float] = (0.18, 0.08)
    turn_deg: float = 0.0
    turn_period_s: float = 7.0


@dataclass(frozen=True)
class Sun:
    """Time of day (local solar hour, day of year, latitude) or an explicit elevation/azimuth (degrees; azimuth from
    north, clockwise); ``route_heading_deg`` turns the sun about the loop (the route's orientation)."""

    hour: float = 11.0
    day_of_year: int = 40
    latitude_deg: float = 46.8
    route_heading_deg: float = 0.0
    elevation_deg: float | None = None
    azimuth_deg: float | None = None


@dataclass(frozen=True)
class Weather:
    """``overcast`` 0 (clear) .. 1 (no direct sun), ``glare`` strength of the lens veil around the sun (0: none),
    ``intensity`` a factor on all light."""

    overcast: float = 0.0
    glare: float = 1.0
    intensity: float = 1.0


@dataclass(frozen=True)
class Content:
    """Factors on the preset's content: number of trees (forest), height of the far treeline."""

    tree_density: float = 1.0
    treeline_scale: float = 1.0


@dataclass(frozen=True)
class Scenario:
    """One scenario (see the module docstring for the file format). ``events``: tuple of dicts, one per lighting
    event, validated."""

    name: str
    preset: str
    description: str = ""
    subset: str = ""
    seed: int = 0
    duration_s: float = 60.0
    resolution: tuple[int, int] = (640, 400)
    fps: float = 22.0
    brackets_ms: tuple[float, ...] = (1.0, 2.0, 4.0, 8.0, 16.0, 32.0)
    route: Route = field(default_factory=Route)
    sun: Sun = field(default_factory=Sun)
    weather: Weather = field(default_factory=Weather)
    content: Content = field(default_factory=Content)
    events: tuple[Mapping[str, Any], ...] = ()

    def to_dict(self) -> dict:
        """The scenario as a document :func:`scenario_from_dict` reads back into an equal scenario."""
        d: dict[str, Any] = {"scenario": FORMAT_VERSION, "name": self.name, "description": self.description,
                             "subset": self.subset, "preset": self.preset, "seed": self.seed,
                             "duration_s": self.duration_s, "resolution": f"{self.resolution[0]}x{self.resolution[1]}",
                             "fps": self.fps, "brackets_ms": list(self.brackets_ms)}
        for key, part in (("route", self.route), ("sun", self.sun), ("weather", self.weather),
                          ("content", self.content)):
            d[key] = {k: (list(v) if isinstance(v, tuple) else v) for k, v in dataclasses.asdict(part).items()
                      if v is not None}
        d["lighting_events"] = [dict(e) for e in self.events]
        return d

    def trajectory(self) -> LoopTrajectory:
        """The walk: a :class:`LoopTrajectory` of the route's length, shape, pace and start."""
        r = self.route
        shape = LoopTrajectory(radius_m=10.0, wobble=r.wobble)
        radius = r.length_m / shape.length_m * 10.0
        base = LoopTrajectory(radius_m=radius, wobble=r.wobble, speed_kmh=r.pace_kmh)
        phase = _theta_of_fraction(base, r.start_fraction)
        return LoopTrajectory(radius_m=radius, wobble=r.wobble, speed_kmh=r.pace_kmh, phase_rad=phase,
                              pitch_deg=RIG_PITCH_DEG, turn_deg=r.turn_deg, turn_period_s=r.turn_period_s)

    def lighting(self) -> Lighting:
        """Sun and sky of the scenario's time of day and weather."""
        elev, az_world = sun_position(self.sun)
        return sky_lighting(elev, az_world, self.weather.overcast)

    def scene_options(self, trajectory: LoopTrajectory) -> SceneOptions:
        """What the scenario changes in the preset's content (lighting, trees, treeline, fresh snow)."""
        base = _base_loop(trajectory)
        snow = np.zeros(_N_BINS, np.float32)
        contrast = np.zeros(_N_BINS, np.float32)
        open_ground = np.zeros(_N_BINS, np.float32)
        for e in self.events:
            if e["kind"] == "fresh_snow":
                w = _sector_weight(base, e["from"], e["to"])
                snow = np.maximum(snow, w)
                contrast = np.where(w > 0, np.maximum(contrast, np.float32(e.get("contrast", 0.0))), contrast)
                if e.get("open"):
                    open_ground = np.maximum(open_ground, w)
        return SceneOptions(lighting=self.lighting(), tree_density=self.content.tree_density,
                            treeline_scale=self.content.treeline_scale,
                            fresh_snow=snow if np.any(snow > 0) else None,
                            snow_contrast=contrast.astype(np.float32) if np.any(contrast > 0) else None,
                            open_ground=open_ground if np.any(open_ground > 0) else None)


# ---------------------------------------------------------------------------------------------------- parsing
def _num(where: str, value: Any, lo: float, hi: float, *, lo_open: bool = False) -> float:
    if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value):
        raise BracketryError(f"{where} must be a number (got {value!r:.40})")
    v = float(value)
    if v < lo or v > hi or (lo_open and v == lo):
        raise BracketryError(f"{where} must be in {'(' if lo_open else '['}{lo:g}, {hi:g}] (got {v:g})")
    return v


def _mapping(where: str, value: Any, allowed: set[str]) -> dict:
    if value is None:
        return {}
    if not isinstance(value, dict):
        raise BracketryError(f"{where} must be a mapping (got {value!r:.40})")
    unknown = sorted(set(value) - allowed)
    if unknown:
        raise BracketryError(f"{where}: unknown key {unknown[0]!r} (known: {', '.join(sorted(allowed))})")
    return value


def _event(where: str, e: Any) -> dict:
    if not isinstance(e, dict) or e.get("kind") not in EVENT_KINDS:
        raise BracketryError(f"{where} must be a mapping with kind: one of {', '.join(EVENT_KINDS)} "
                             f"(got {e!r:.60})")
    kind = e["kind"]
    _mapping(where, {k: v for k, v in e.items() if k != "kind"}, _EVENT_KEYS[kind])
    out: dict[str, Any] = {"kind": kind}
    if kind in ("canopy", "canopy_patches", "fresh_snow"):
        for k in ("from", "to"):
            if k not in e:
                raise BracketryError(f"{where} ({kind}) needs '{k}' (a route fraction in [0, 1])")
            out[k] = _num(f"{where}.{k}", e[k], 0.0, 1.0)
    if kind in ("canopy", "canopy_patches"):
        out["density"] = _num(f"{where}.density", e.get("density", 0.95), 0.0, 0.9999)
        if "edge_m" in e:
            out["edge_m"] = _num(f"{where}.edge_m", e["edge_m"], 0.05, 20.0)
    if kind == "fresh_snow":
        if "contrast" in e:
            out["contrast"] = _num(f"{where}.contrast", e["contrast"], 0.0, 0.5)
        if "open" in e:
            if not isinstance(e["open"], bool):
                raise BracketryError(f"{where}.open must be true or false (got {e['open']!r:.40})")
            out["open"] = e["open"]
    if kind == "canopy_patches":
        out["period_m"] = _num(f"{where}.period_m", e.get("period_m", 8.0), 1.0, 1000.0)
        out["duty"] = _num(f"{where}.duty", e.get("duty", 0.5), 0.05, 0.95)
    if kind == "clouds":
        out["cover"] = _num(f"{where}.cover", e.get("cover", 0.5), 0.0, 1.0)
        out["opacity"] = _num(f"{where}.opacity", e.get("opacity", 0.95), 0.0, 1.0)
        out["speed_mps"] = _num(f"{where}.speed_mps", e.get("speed_mps", 10.0), 0.0, 100.0)
        out["direction_deg"] = _num(f"{where}.direction_deg", e.get("direction_deg", 90.0), -360.0, 360.0)
        out["size_m"] = _num(f"{where}.size_m", e.get("size_m", 40.0), 5.0, 5000.0)
    if kind == "dimming":
        times, factors = e.get("times_s"), e.get("factors")
        if not isinstance(times, list) or not isinstance(factors, list) or not times or len(times) != len(factors):
            raise BracketryError(f"{where} (dimming) needs lists times_s and factors of the same non-zero length")
        t = [_num(f"{where}.times_s[{i}]", x, 0.0, 1e6) for i, x in enumerate(times)]
        if any(b <= a for a, b in itertools.pairwise(t)):
            raise BracketryError(f"{where}.times_s must increase")
        out["times_s"] = t
        out["factors"] = [_num(f"{where}.factors[{i}]", x, 0.0, 1e3, lo_open=True) for i, x in enumerate(factors)]
    return out


def scenario_from_dict(doc: Any, name: str = "scenario") -> Scenario:
    """Validate a scenario document (the parsed YAML). Raises BracketryError with a one-line message naming the key."""
    if not isinstance(doc, dict):
        raise BracketryError("a scenario must be a YAML mapping")
    _mapping("scenario", doc, _TOP_KEYS)
    version = doc.get("scenario", FORMAT_VERSION)
    if version != FORMAT_VERSION:
        raise BracketryError(f"scenario format version {version!r} is not supported (this is version {FORMAT_VERSION})")
    preset = doc.get("preset")
    if preset not in PRESETS:
        raise BracketryError(f"preset must be one of {', '.join(PRESETS)} (got {preset!r})")
    seed = doc.get("seed", 0)
    if isinstance(seed, bool) or not isinstance(seed, int) or not 0 <= seed < 2 ** 32:
        raise BracketryError(f"seed must be an integer in [0, 2^32) (got {seed!r})")
    brackets = doc.get("brackets_ms", [1, 2, 4, 8, 16, 32])
    if not isinstance(brackets, list) or not brackets:
        raise BracketryError("brackets_ms must be a non-empty list of milliseconds")
    br = tuple(_num(f"brackets_ms[{i}]", b, 0.0, 1000.0, lo_open=True) for i, b in enumerate(brackets))
    fps = _num("fps", doc.get("fps", 22.0), 0.0, 200.0, lo_open=True)
    if max(br) >= 1000.0 / fps:
        raise BracketryError(f"brackets_ms: {max(br):g} ms does not fit in the frame period {1000.0 / fps:.1f} ms")
    r = _mapping("route", doc.get("route"), _SECTION_KEYS["route"])
    wobble = r.get("wobble", [0.18, 0.08])
    if not isinstance(wobble, list) or len(wobble) != 2:
        raise BracketryError("route.wobble must be a list of two numbers")
    route = Route(length_m=_num("route.length_m", r.get("length_m", 80.0), 20.0, 200.0),
                  pace_kmh=_num("route.pace_kmh", r.get("pace_kmh", 2.0), 0.0, 20.0, lo_open=True),
                  start_fraction=_num("route.start_fraction", r.get("start_fraction", 0.0), 0.0, 1.0),
                  turn_deg=_num("route.turn_deg", r.get("turn_deg", 0.0), 0.0, 90.0),
                  turn_period_s=_num("route.turn_period_s", r.get("turn_period_s", 7.0), 0.5, 600.0),
                  wobble=(_num("route.wobble[0]", wobble[0], 0.0, 0.3), _num("route.wobble[1]", wobble[1], 0.0, 0.3)))
    s = _mapping("sun", doc.get("sun"), _SECTION_KEYS["sun"])
    explicit = ("elevation_deg" in s, "azimuth_deg" in s)
    if any(explicit) and not all(explicit):
        raise BracketryError("sun: give both elevation_deg and azimuth_deg, or neither (then hour)")
    sun = Sun(hour=_num("sun.hour", s.get("hour", 11.0), 0.0, 24.0),
              day_of_year=int(_num("sun.day_of_year", s.get("day_of_year", 40), 1, 366)),
              latitude_deg=_num("sun.latitude_deg", s.get("latitude_deg", 46.8), -89.0, 89.0),
              route_heading_deg=_num("sun.route_heading_deg", s.get("route_heading_deg", 0.0), -360.0, 360.0),
              elevation_deg=_num("sun.elevation_deg", s["elevation_deg"], -18.0, 90.0) if all(explicit) else None,
              azimuth_deg=_num("sun.azimuth_deg", s["azimuth_deg"], -360.0, 360.0) if all(explicit) else None)
    w = _mapping("weather", doc.get("weather"), _SECTION_KEYS["weather"])
    weather = Weather(overcast=_num("weather.overcast", w.get("overcast", 0.0), 0.0, 1.0),
                      glare=_num("weather.glare", w.get("glare", 1.0), 0.0, 100.0),
                      intensity=_num("weather.intensity", w.get("intensity", 1.0), 0.0, 1e3, lo_open=True))
    c = _mapping("content", doc.get("content"), _SECTION_KEYS["content"])
    content = Content(tree_density=_num("content.tree_density", c.get("tree_density", 1.0), 0.0, 3.0),
                      treeline_scale=_num("content.treeline_scale", c.get("treeline_scale", 1.0), 0.0, 3.0))
    events = doc.get("lighting_events") or []
    if not isinstance(events, list):
        raise BracketryError("lighting_events must be a list")
    res_text = doc.get("resolution", "640x400")
    if not isinstance(res_text, str):
        raise BracketryError(f"resolution must look like 640x400 (got {res_text!r})")
    return Scenario(name=str(doc.get("name") or name), preset=str(preset), description=str(doc.get("description", "")),
                    subset=str(doc.get("subset", "")), seed=seed,
                    duration_s=_num("duration_s", doc.get("duration_s", 60.0), 0.0, 3600.0, lo_open=True),
                    resolution=parse_resolution(res_text, "resolution"), fps=fps, brackets_ms=br, route=route,
                    sun=sun, weather=weather, content=content,
                    events=tuple(_event(f"lighting_events[{i}]", e) for i, e in enumerate(events)))


def read_scenario_doc(path: str | Path) -> dict:
    """The parsed YAML of a scenario file (BracketryError if unreadable or not YAML)."""
    p = Path(path)
    try:
        doc = yaml.safe_load(p.read_text())
    except (OSError, UnicodeDecodeError) as exc:
        raise BracketryError(f"cannot read scenario {p}: {exc}") from None
    except yaml.YAMLError as exc:
        line = getattr(getattr(exc, "problem_mark", None), "line", None)
        where = f" (line {line + 1})" if line is not None else ""
        raise BracketryError(f"scenario {p} is not valid YAML{where}") from None
    return doc


def load_scenario(path: str | Path) -> Scenario:
    """Read and validate a scenario file; errors are one line naming the file and the key."""
    p = Path(path)
    try:
        return scenario_from_dict(read_scenario_doc(p), name=p.stem)
    except BracketryError as exc:
        msg = str(exc)
        raise BracketryError(msg if msg.startswith(("cannot read", "scenario ")) else f"scenario {p}: {msg}") from None


def shipped_scenarios() -> dict[str, Path]:
    """The scenario files shipped with the package: {name (file stem): path}."""
    return {p.stem: p for p in sorted(SCENARIO_DIR.glob("*.yaml"))}


def merge(doc: dict, overrides: Mapping[str, Any]) -> dict:
    """``doc`` with ``overrides`` applied (mappings merged key by key, anything else replaced); a new dict."""
    out = copy.deepcopy(doc)
    for k, v in overrides.items():
        if isinstance(v, Mapping) and isinstance(out.get(k), dict):
            out[k] = merge(out[k], v)
        else:
            out[k] = copy.deepcopy(v)
    return out


# ---------------------------------------------------------------------------------------------------- sun and sky
def sun_position(sun: Sun) -> tuple[float, float]:
    """(elevation_deg, azimuth in the world frame in degrees: from +x (east) towards +y (north)).

    From the time of day: declination 23.44 sin(2 pi (284 + day) / 365), hour angle 15 (hour - 12) degrees."""
    if sun.elevation_deg is not None and sun.azimuth_deg is not None:
        elev, az_north = sun.elevation_deg, sun.azimuth_deg
    else:
        lat = math.radians(sun.latitude_deg)
        dec = math.radians(23.44) * math.sin(2 * math.pi * (284 + sun.day_of_year) / 365.0)
        ha = math.radians(15.0 * (sun.hour - 12.0))
        sin_e = math.sin(lat) * math.sin(dec) + math.cos(lat) * math.cos(dec) * math.cos(ha)
        e = math.asin(max(-1.0, min(1.0, sin_e)))
        cos_az = (math.sin(dec) - math.sin(e) * math.sin(lat)) / max(math.cos(e) * math.cos(lat), 1e-9)
        az = math.degrees(math.acos(max(-1.0, min(1.0, cos_az))))
        az_north = 360.0 - az if ha > 0 else az
        elev = math.degrees(e)
    return float(elev), float((90.0 - az_north + sun.route_heading_deg) % 360.0)


def _air_mass(elev_deg: float) -> float:
    """Kasten-Young relative air mass (elevation >= 0)."""
    e = max(elev_deg, 0.0)
    return 1.0 / (math.sin(math.radians(e)) + 0.50572 * (e + 6.07995) ** -1.6364)


def sky_lighting(elev_deg: float, az_world_deg: float, overcast: float = 0.0) -> Lighting:
    """Sun and sky of a sun at ``elev_deg`` (may be below the horizon) and world azimuth ``az_world_deg``.

    Direct sun: (5.0, 5.5, 6.5) x exp(-tau_c m) with tau = (0.10, 0.16, 0.30) per channel and air mass m, x (1 -
    overcast), none below the horizon. Sky light on a horizontal surface: (0.40, 0.50, 0.68) x (0.35 + 0.9 sin e)
    above the horizon, x 0.35 x 10^(e / 6) below (dusk); overcast adds up to 1.5x that. Units as the scene's."""
    e_geo = max(elev_deg, 0.5)  # shadows and the disk need a direction above the horizon
    ea, aa = math.radians(e_geo), math.radians(az_world_deg)
    sun_dir = np.array([math.cos(ea) * math.cos(aa), math.cos(ea) * math.sin(aa), math.sin(ea)])
    if elev_deg > 0:
        m = _air_mass(elev_deg)
        trans = [math.exp(-tau * m) for tau in (0.10, 0.16, 0.30)]
        sky_f = 0.35 + 0.9 * math.sin(math.radians(elev_deg))
    else:
        trans = [0.0, 0.0, 0.0]
        sky_f = 0.35 * 10.0 ** (elev_deg / 6.0)
    clear = 1.0 - overcast
    sun_rgb = tuple(float(s0 * t * clear) for s0, t in zip((5.0, 5.5, 6.5), trans))
    sky_k = sky_f * (1.0 + 1.5 * overcast)
    sky_rgb = tuple(float(c * sky_k) for c in (0.40, 0.50, 0.68))
    zenith = tuple(float(c * sky_k) for c in (1.2, 2.1, 4.2))
    horizon = tuple(float(c * sky_k) for c in (4.0, 4.5, 5.2))
    halo = tuple(float(c * t * clear) for c, t in zip((75.0, 68.0, 56.0), trans))
    # the disk casts the direct light: an albedo-1 surface facing it has radiance sun_rgb, so its irradiance
    # pi * sun_rgb comes from a disk of radiance sun_rgb / DISK_RAD**2 over the solid angle pi * DISK_RAD**2; no sun
    # (below the horizon, overcast): the disk's pixels are sky
    disk = max(float(sun_rgb[1]) / DISK_RAD ** 2, horizon[1])
    # the glare veil's scale: 2e4 x the transmission (the module docstring's E_v)
    veil = max(float(2.0e4 * trans[1] / math.exp(-0.16) * clear), horizon[1])
    return Lighting(sun_dir=sun_dir, sun_rgb=sun_rgb, sky_rgb=sky_rgb, zenith_rgb=zenith,  # type: ignore[arg-type]
                    horizon_rgb=horizon, halo_rgb=halo, disk_radiance=disk,  # type: ignore[arg-type]
                    veil_radiance=veil)


def sun_pixel(intr: CameraIntrinsics, s_c: np.ndarray) -> tuple[int, int] | None:
    """The pixel (column, row) where the sun's centre lands in the image of ``intr`` (its lens distortion included),
    the sun's direction ``s_c`` in that camera's frame (float64 (3,): x right, y down, z forward); None when it lands
    outside the image or behind the camera."""
    if s_c[2] <= 0.0:
        return None
    u, v = intr.distort(np.array([s_c[0] / s_c[2]]), np.array([s_c[1] / s_c[2]]))
    col, row = round(float(u[0])), round(float(v[0]))
    return (col, row) if 0 <= col < intr.width and 0 <= row < intr.height else None


# ---------------------------------------------------------------------------------------------------- route sectors
def _base_loop(trajectory: LoopTrajectory) -> LoopTrajectory:
    """The same loop with its arc length counted from polar angle 0 (route fractions of events refer to it)."""
    return dataclasses.replace(trajectory, phase_rad=0.0)


def _theta_of_fraction(loop: LoopTrajectory, fraction: float) -> float:
    """Polar angle (rad) of the point at ``fraction`` of the loop's length from polar angle 0 (phase 0 loop)."""
    base = _base_loop(loop)
    return float(np.interp((fraction % 1.0) * base.length_m, base._s_table, base._th_table))


def _bin_angles() -> np.ndarray:
    """Centre polar angle (rad, in [-pi, pi)) of each bin of the fresh-snow table."""
    return -np.pi + (np.arange(_N_BINS) + 0.5) * (2 * np.pi / _N_BINS)


def _pseudo_bin_angles() -> np.ndarray:
    """Polar angle (rad) of the centre of each bin of a table indexed by :func:`pseudo_angle` (bins over [0, 4))."""
    q = (np.arange(_N_BINS) + 0.5) * (4.0 / _N_BINS)
    x = np.where(q < 1, 1 - q, np.where(q < 3, -(1 - np.abs(2 - q)), 1 - np.abs(q - 4)))
    y = np.where(q < 1, q, np.where(q < 3, 2 - q, q - 4))
    return np.arctan2(y, x)


def _arc_of_angle(base: LoopTrajectory, phi: np.ndarray) -> np.ndarray:
    """Arc length (m) along the phase-0 loop of the point at polar angle ``phi``."""
    th = np.mod(phi, 2 * np.pi)
    return np.interp(th, base._th_table, base._s_table)


def _window(s: np.ndarray, s0: float, s1: float, length: float, edge: float) -> np.ndarray:
    """1 inside the arc [s0, s1] of a loop of ``length`` (wrapping when s1 < s0), 0 outside, linear edges of width
    ``edge`` centred on the ends (0.5 at s0 and s1)."""
    span = (s1 - s0) % length if s1 != s0 else length
    rel = np.mod(s - s0, length)
    inside = np.minimum(rel, span - rel)
    outside = np.minimum(length - rel, rel - span)  # distance past the far end / before the start, wrapped
    w = np.where(rel <= span, np.clip(0.5 + inside / edge, 0, 1), np.clip(0.5 - outside / edge, 0, 1))
    return w


def _sector_weight(base: LoopTrajectory, f0: float, f1: float, pseudo: bool = False,
                   patches: tuple[float, float] | None = None, edge_m: float = _EDGE_M) -> np.ndarray:
    """Weight (float32 (bins,)) of a route sector between fractions f0 and f1, per polar-angle bin (soft edges of
    ``edge_m``)."""
    phi = _pseudo_bin_angles() if pseudo else _bin_angles()
    s = _arc_of_angle(base, phi)
    length = base.length_m
    w = _window(s, f0 * length, f1 * length, length, edge_m)
    if patches is not None:
        period, duty = patches
        rel = np.mod(s - f0 * length, period)
        on = np.minimum(rel, duty * period - rel)
        off = np.minimum(rel - duty * period, period - rel)
        w = w * np.where(rel <= duty * period, np.clip(0.5 + on / 0.8, 0, 1), np.clip(0.5 - off / 0.8, 0, 1))
    return w.astype(np.float32)


# ---------------------------------------------------------------------------------------------------- light over time
class LightField:
    """The scenario's light at each instant, applied to a render: canopy, cloud shadows, dimming and the glare veil.

    ``apply`` multiplies the radiance of every pixel by the light reaching its hit point at ``t_s`` (sky pixels by
    the dimming only; the solar disk also by the camera's cloud cover) and adds the veil. Elementwise float32
    arithmetic in a fixed order: the same bits on every CPU.
    """

    def __init__(self, scenario: Scenario, scene: Scene, trajectory: LoopTrajectory, seed: int) -> None:
        self.scenario = scenario
        self.scene = scene
        base = _base_loop(trajectory)
        canopy = np.ones(_N_BINS, np.float64)
        self.clouds: list[tuple[np.ndarray, float, float, float, float]] = []  # table, cos, sin, speed, period
        self.dimming: list[tuple[list[float], list[float]]] = []
        lt = scene.lighting
        direct_g = lt.sun_rgb[1] * max(float(lt.sun_dir[2]), 0.0)
        sky_g = lt.sky_rgb[1]
        rng = np.random.default_rng(np.random.SeedSequence([seed, 0xC10D]))
        for e in scenario.events:
            kind = e["kind"]
            if kind in ("canopy", "canopy_patches"):
                patches = (e["period_m"], e["duty"]) if kind == "canopy_patches" else None
                w = _sector_weight(base, e["from"], e["to"], pseudo=True, patches=patches,
                                   edge_m=e.get("edge_m", _EDGE_M))
                canopy *= 1.0 - e["density"] * w
            elif kind == "clouds":
                n_cells = 16
                period = n_cells * e["size_m"]
                covered = rng.random(n_cells) < e["cover"]
                u = (np.arange(_N_CLOUD) + 0.5) * (period / _N_CLOUD)
                cover = covered[np.minimum((u / e["size_m"]).astype(np.int64), n_cells - 1)].astype(np.float64)
                k = max(1, round(4.0 / (period / _N_CLOUD)))  # soft edges of ~4 m: a circular moving average
                padded = np.concatenate([cover[-(k // 2):] if k // 2 else cover[:0], cover, cover[:k]])
                csum = np.concatenate([[0.0], np.cumsum(padded)])  # sequential sums: the same bits on every CPU
                soft = np.clip((csum[k:k + _N_CLOUD] - csum[:_N_CLOUD]) / k, 0.0, 1.0)
                total = direct_g + sky_g
                shadow = ((1.0 - e["opacity"]) * direct_g + sky_g) / total if total > 0 else 1.0
                table = (1.0 - (1.0 - shadow) * soft).astype(np.float32)
                a = math.radians(90.0 - e["direction_deg"])  # towards direction_deg (from north, clockwise)
                self.clouds.append((table, math.cos(a), math.sin(a), e["speed_mps"], period))
            elif kind == "dimming":
                self.dimming.append((list(e["times_s"]), [math.log(f) for f in e["factors"]]))
        self.canopy = canopy.astype(np.float32)
        self.has_canopy = bool(np.any(self.canopy < 1.0))
        self.spatial = self.has_canopy or bool(self.clouds)
        self.sun_up = lt.sun_rgb[1] > 0
        e_sun = (lt.disk_radiance if lt.veil_radiance is None else lt.veil_radiance) * math.pi * lt.disk_rad ** 2
        self.veil_k = float(scenario.weather.glare * 0.01 * e_sun) if self.sun_up else 0.0

    def global_factor(self, t_s: float) -> float:
        """The weather intensity times every dimming event at ``t_s``."""
        g = self.scenario.weather.intensity
        for times, logs in self.dimming:
            g *= math.exp(float(np.interp(t_s, times, logs)))
        return g

    def _cloud_at(self, x: np.ndarray, y: np.ndarray, t_s: float) -> np.ndarray:
        out = np.ones(x.shape, np.float32)
        for table, ca, sa, speed, period in self.clouds:
            u = x * np.float32(ca)
            u += y * np.float32(sa)
            u -= np.float32(speed * t_s % period)
            np.mod(u, np.float32(period), out=u)
            idx = (u * np.float32(_N_CLOUD / period)).astype(np.int32)
            np.clip(idx, 0, _N_CLOUD - 1, out=idx)
            out *= table[idx]
        return out

    def sun_cover(self, p_w: np.ndarray, t_s: float) -> float:
        """Fraction of the direct sun reaching the camera centre ``p_w`` (1: clear; the clouds' shadow factor)."""
        if not self.clouds:
            return 1.0
        lt = self.scene.lighting
        # the ground point on the camera's line to the sun: shadowed there <=> the camera is
        xy = np.asarray(p_w[:2], np.float64) - float(p_w[2]) * np.asarray(lt.sun_dir[:2]) / max(lt.sun_dir[2], 1e-3)
        f = float(self._cloud_at(np.array([xy[0]], np.float32), np.array([xy[1]], np.float32), t_s)[0])
        direct = lt.sun_rgb[1] * max(float(lt.sun_dir[2]), 0.0)
        total = direct + lt.sky_rgb[1]
        # f = (sky + d * direct) / total  ->  d = (f * total - sky) / direct
        return float(min(1.0, max(0.0, (f * total - lt.sky_rgb[1]) / direct))) if direct > 0 else 1.0

    def apply(self, res: RenderResult, renderer: SideRenderer, R_wc: np.ndarray, p_w: np.ndarray,
              t_s: float) -> RenderResult:
        """The render ``res`` of ``renderer`` from pose (R_wc, p_w) lit as at ``t_s`` (a new RenderResult)."""
        f32 = np.float32
        rad = res.radiance.ravel()
        rng = res.range_m.ravel()
        g = f32(self.global_factor(t_s))
        sun_vis = self.sun_cover(p_w, t_s) if self.sun_up else 0.0
        lt = self.scene.lighting
        disk = rad >= f32(0.5 * lt.disk_radiance) if self.sun_up else None
        if self.spatial:
            finite = np.isfinite(rng)
            t = np.where(finite, rng, f32(0.0))
            rays = renderer.rays
            R = np.asarray(R_wc, np.float64)
            x = rays[0] * f32(R[0, 0])
            x += rays[1] * f32(R[0, 1])
            x += rays[2] * f32(R[0, 2])
            x *= t
            x += f32(p_w[0])
            y = rays[0] * f32(R[1, 0])
            y += rays[1] * f32(R[1, 1])
            y += rays[2] * f32(R[1, 2])
            y *= t
            y += f32(p_w[1])
            factor = self._cloud_at(x, y, t_s) if self.clouds else np.ones(rad.shape, f32)
            if self.has_canopy:
                idx = (pseudo_angle(x, y) * f32(_N_BINS / 4.0)).astype(np.int32)
                np.clip(idx, 0, _N_BINS - 1, out=idx)
                factor *= self.canopy[idx]
            factor[~finite] = f32(1.0)
            factor *= g
            out = rad * factor
        else:
            out = rad * g
        if disk is not None and sun_vis < 1.0:
            out[disk] *= f32(sun_vis)
        veil = self._veil(renderer, R_wc, p_w, res, sun_vis)
        if veil is not None:
            veil *= g
            out += veil
        h, w = res.radiance.shape
        return RenderResult(out.reshape(h, w), res.range_m)

    def _veil(self, renderer: SideRenderer, R_wc: np.ndarray, p_w: np.ndarray, res: RenderResult,
              sun_vis: float) -> np.ndarray | None:
        """The lens's veiling glare of a visible sun (float32 (N,)), or None when there is none."""
        if self.veil_k <= 0 or sun_vis <= 0:
            return None
        lt = self.scene.lighting
        s_c = mat_mul(np.ascontiguousarray(np.asarray(R_wc, np.float64).T), lt.sun_dir)  # sun in the camera frame
        cos_axis = float(s_c[2])
        reach = min(1.0, max(0.0, (cos_axis - 0.34) / 0.3))  # fades out between 55 and 70 degrees off axis
        if reach <= 0:
            return None
        vis = sun_vis * reach * self._sun_unoccluded(renderer, s_c, p_w, res)
        if vis <= 0:
            return None
        f32 = np.float32
        rays = renderer.rays
        c = rays[0] * f32(s_c[0])
        c += rays[1] * f32(s_c[1])
        c += rays[2] * f32(s_c[2])
        np.subtract(f32(1.0), c, out=c)
        c *= f32(2.0)  # ~ angle^2
        np.maximum(c, f32(0.0), out=c)
        c += f32(1e-4)
        return np.divide(f32(self.veil_k * vis), c).astype(f32)

    def _sun_unoccluded(self, renderer: SideRenderer, s_c: np.ndarray, p_w: np.ndarray, res: RenderResult) -> float:
        """1 if the sun is seen: in the image, its pixel shows sky; outside, it stands above the far treeline."""
        pixel = sun_pixel(renderer.intr, s_c)
        if pixel is not None:
            col, row = pixel
            return 1.0 if not np.isfinite(res.range_m[row, col]) else 0.0
        sc = self.scene
        lt = sc.lighting
        n_az = sc.treeline_height_m.size
        q = float(pseudo_angle(np.array([lt.sun_dir[0]], np.float32), np.array([lt.sun_dir[1]], np.float32))[0])
        top = float(sc.treeline_height_m[min(int(q * n_az / 4.0), n_az - 1)])
        dist = max(sc.treeline_radius_m - math.hypot(float(p_w[0]), float(p_w[1])), 1.0)
        return 1.0 if math.atan2(top - float(p_w[2]), dist) < math.asin(float(lt.sun_dir[2])) else 0.0


# ---------------------------------------------------------------------------------------------------- worlds
def scenario_scene(scenario: Scenario, seed: int, trajectory: LoopTrajectory, detail: float) -> Scene:
    """The world content of ``scenario`` (remembering the last two: a scene is read-only once built)."""
    opts = scenario.scene_options(trajectory)
    key = (scenario.preset, seed, detail, repr(trajectory), opts.key())
    scene = _SCENE_CACHE.get(key)
    if scene is None:
        scene = build_scene(scenario.preset, seed, trajectory, detail, opts)
        _SCENE_CACHE[key] = scene
        while len(_SCENE_CACHE) > 2:
            _SCENE_CACHE.popitem(last=False)
    _SCENE_CACHE.move_to_end(key)
    return scene


def calibration_to_dict(calib: StereoCalibration) -> dict:
    """Exact (float repr) description of the stereo rig, for
    :func:`~bracketry_emulator.synth.world.world_from_dataset`."""
    return {"baseline_m": calib.baseline_m,
            **{side: dataclasses.asdict(calib.side(side)) | {"dist": list(calib.side(side).dist)} for side in SIDES}}


def calibration_from_dict(d: Mapping[str, Any]) -> StereoCalibration:
    """Inverse of :func:`calibration_to_dict`."""
    sides = {s: CameraIntrinsics(**{**d[s], "dist": tuple(d[s]["dist"])}) for s in SIDES}
    return StereoCalibration(sides["left"], sides["right"], float(d["baseline_m"]))
