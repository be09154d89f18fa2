"""The synthetic benchmark suite: shipped scenarios rendered into trajectories and a manifest (``synth suite``).

Layout of a rendered suite::

    DIR/manifest.yaml                       trajectories (path, subset, name, split) + suite: {version, size, seed},
                                            warmup_steps (closed-loop steps on each walk's first view)
    DIR/<subset>/<name>/                    one synthetic trajectory (BorealHDR tree, groundtruth.txt,
                                            calibration/, camera_model.json, scenario.yaml: its scenario)

Subsets after the paper's: ``forest``, ``sun-shadow`` (Belair-like), ``glare`` (Campus1-like), ``day-cycle`` (one
campus loop at six times of day, Campus2-like). Sizes: ``full`` (28 trajectories of 60 s at 640x400) and ``demo``
(10 of 10 s at 320x200). A suite is cached by (version, size, seed, code digest) in ``user_cache_dir()/synth-suites``;
the same seed gives the same bytes. Bump :data:`SUITE_VERSION` when what a suite holds changes by design.
"""

from __future__ import annotations

import hashlib
import os
import shutil
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import yaml

from bracketry_base.errors import BracketryError
from bracketry_base.paths import user_cache_dir
from bracketry_emulator.synth.calibration import default_calibration
from bracketry_emulator.synth.scenario import (
    merge,
    read_scenario_doc,
    scenario_from_dict,
    shipped_scenarios,
    sun_pixel,
    sun_position,
)

#: the suite's version: part of its cache key and of its manifest
SUITE_VERSION = "8"
SUBSETS = ("forest", "sun-shadow", "glare", "day-cycle")
DAY_CYCLE_HOURS = (6.0, 9.0, 12.0, 15.0, 18.0, 19.8)
#: the hours of the day-cycle walks in the demo-size suite (morning and sunset: the sun 0.3 degrees above the
#: horizon, the campus in sky light; at 20:12, 3 degrees below, no exposure up to 64 ms holds 500 ORB corners at
#: 320x200, emulator/DATASET.md)
DEMO_HOURS = (9.0, 19.8)


@dataclass(frozen=True)
class SizeSpec:
    """How big each trajectory of a suite size is: resolution (W, H), duration (s), ground texture detail, and the
    RTE/RRE windows (m) its manifest declares (None: the benchmark's default, the paper's 5-50 m)."""

    resolution: tuple[int, int]
    duration_s: float
    detail: float
    windows_m: tuple[float, ...] | None = None


#: the demo's 10 s walks cover 8-25 m: most are shorter than the paper's windows (5-50 m), so they declare 2-8 m ones
SIZES = {"demo": SizeSpec((320, 200), 10.0, 1.0, (2.0, 4.0, 6.0, 8.0)), "full": SizeSpec((640, 400), 60.0, 0.5)}

#: the manifest's ``warmup_steps``: each walk is a stretch of a longer recording, so the benchmark's closed loops first
#: take this many steps on its first view (~4 s of bracket cycles; AE50 settles from 4 ms to any exposure of the
#: suite's scenes within it) and the walk measures how a method follows the light, not how fast it starts up
WARMUP_STEPS = 15


@dataclass(frozen=True)
class Entry:
    """One trajectory of the suite: its subset, name, scenario file (stem), world index (the world seed is drawn
    from the suite seed and the subset's worlds: entries with the same index share a world), overrides of the
    scenario, split, and the sizes it belongs to."""

    subset: str
    name: str
    scenario: str
    world: int
    overrides: tuple[tuple[str, Any], ...] = ()
    split: str = "test"
    sizes: tuple[str, ...] = ("demo", "full")


def _e(subset: str, name: str, scenario: str, world: int, split: str = "test",
       sizes: tuple[str, ...] = ("demo", "full"),
       **overrides: Any) -> Entry:
    return Entry(subset, name, scenario, world, tuple(sorted(overrides.items())), split, sizes)


_FULL = ("full",)
_DEMO = ("demo", "full")
#: the suite: 28 trajectories at size full (22 test, 6 train), 10 of them at size demo (8 test, 2 train)
ENTRIES: tuple[Entry, ...] = (
    _e("forest", "forest_canopy_a", "forest-canopy", 0),
    _e("forest", "forest_canopy_b", "forest-canopy", 1, "train", _FULL, route={"start_fraction": 0.5}),
    _e("forest", "forest_fresh_snow_a", "forest-fresh-snow", 2, "test", _FULL),
    _e("forest", "forest_dusk_a", "forest-dusk", 3),
    _e("forest", "forest_fast_a", "forest-fast", 4, "train"),
    _e("forest", "forest_canopy_c", "forest-canopy", 5, "test", _FULL, sun={"hour": 14.5}),
    _e("forest", "forest_fresh_snow_b", "forest-fresh-snow", 6, "test", _FULL, route={"start_fraction": 0.6}),
    _e("forest", "forest_fast_b", "forest-fast", 7, "test", _FULL, route={"pace_kmh": 11.0}),
    _e("forest", "forest_edge_a", "forest-edge", 8),
    _e("forest", "forest_edge_b", "forest-edge", 9, "train", _FULL, route={"start_fraction": 0.48}),
    _e("sun-shadow", "sun_shadow_a", "sun-shadow", 0),
    _e("sun-shadow", "sun_shadow_b", "sun-shadow", 1, "train",
       lighting_events=[{"kind": "clouds", "cover": 0.6, "opacity": 1.0, "speed_mps": 12, "direction_deg": 150,
                         "size_m": 35},
                        {"kind": "canopy_patches", "from": 0.0, "to": 1.0, "density": 0.85, "period_m": 11,
                         "duty": 0.5}]),
    _e("sun-shadow", "sun_shadow_c", "sun-shadow", 2, "test", _FULL, route={"start_fraction": 0.4}),
    _e("sun-shadow", "sun_shadow_d", "sun-shadow", 3, "test", _FULL, sun={"hour": 15.0}),
    _e("sun-shadow", "sun_shadow_e", "sun-shadow", 4, "test", _FULL, route={"pace_kmh": 6.0}),
    _e("sun-shadow", "sun_shadow_f", "sun-shadow", 5, "test", _FULL,
       lighting_events=[{"kind": "clouds", "cover": 0.4, "opacity": 1.0, "speed_mps": 20, "direction_deg": 300,
                         "size_m": 60}]),
    _e("glare", "glare_a", "glare", 0),
    _e("glare", "glare_b", "glare", 1, "train", _FULL, sun={"elevation_deg": 6.0, "azimuth_deg": 180.0}),
    _e("glare", "glare_c", "glare", 2, "test", _DEMO, route={"start_fraction": 0.5}, sun={"elevation_deg": 5.0}),
    _e("glare", "glare_d", "glare", 3, "test", _FULL, sun={"elevation_deg": 6.0, "azimuth_deg": 300.0}),
    # no exposure keeps the frozen lake at the demo's 320x200 (ORB-SLAM3 finds no stereo matches on its ice): a walk
    # that tests no exposure, so the demo's two glare walks are glare_a and glare_c
    _e("glare", "frozen_lake_a", "frozen-lake", 4, "test", _FULL),
    _e("glare", "frozen_lake_b", "frozen-lake", 5, "test", _FULL, sun={"elevation_deg": 3.0, "azimuth_deg": 160.0}),
    *(_e("day-cycle", f"day_cycle_{int(h):02d}{round(h % 1 * 60):02d}", "day-cycle", 0,
         "train" if h == 15.0 else "test", _DEMO if h in DEMO_HOURS else _FULL, sun={"hour": h})
      for h in DAY_CYCLE_HOURS),
)


def entries(size: str) -> list[Entry]:
    """The trajectories of a suite size, in manifest order."""
    if size not in SIZES:
        raise BracketryError(f"unknown suite size {size!r} (choose from {', '.join(SIZES)})")
    return [e for e in ENTRIES if size in e.sizes]


def world_seed(suite_seed: int, entry: Entry) -> int:
    """The world seed of an entry: drawn from the suite seed, the subset and the entry's world index."""
    digest = hashlib.sha256(f"{suite_seed}/{entry.subset}/{entry.world}".encode()).digest()
    return int.from_bytes(digest[:4], "little")


def entry_scenario_doc(entry: Entry, size: str, suite_seed: int) -> dict:
    """The scenario document an entry renders (shipped file + the entry's overrides + the size's settings)."""
    files = shipped_scenarios()
    if entry.scenario not in files:
        raise BracketryError(f"suite entry {entry.name}: no shipped scenario {entry.scenario!r}")
    spec = SIZES[size]
    doc = merge(read_scenario_doc(files[entry.scenario]), dict(entry.overrides))
    w, h = spec.resolution
    doc.update(name=entry.name, subset=entry.subset, seed=world_seed(suite_seed, entry),
               duration_s=spec.duration_s, resolution=f"{w}x{h}")
    for ev in doc.get("lighting_events") or []:  # dimming keys follow the trajectory's duration
        if isinstance(ev, dict) and ev.get("kind") == "dimming" and isinstance(ev.get("times_s"), list):
            last = float(ev["times_s"][-1]) or 1.0
            ev["times_s"] = [float(t) / last * spec.duration_s for t in ev["times_s"]]
    return doc


def code_digest() -> str:
    """12 hex digits of the SHA-256 of everything that decides what a suite renders: the synth package's sources
    (Python and C) and its scenario files. A cached suite of other code is not reused."""
    root = Path(__file__).parent
    h = hashlib.sha256()
    for p in sorted([*root.glob("*.py"), *root.glob("*.c"), *root.glob("scenarios/*.yaml")]):
        h.update(p.relative_to(root).as_posix().encode() + b"\0" + p.read_bytes() + b"\0")
    return h.hexdigest()[:12]


def suite_id(size: str, seed: int) -> dict:
    """What identifies a rendered suite (its manifest's ``suite:`` block): version, size, seed and code digest."""
    return {"version": SUITE_VERSION, "size": size, "seed": int(seed), "code": code_digest()}


def cache_dir(size: str, seed: int) -> Path:
    """Where the suite of (size, seed) at this version and code is cached."""
    return user_cache_dir() / "synth-suites" / f"v{SUITE_VERSION}-{size}-seed{int(seed)}-{code_digest()}"


def read_suite_id(folder: Path) -> dict | None:
    """The ``suite:`` block of ``folder/manifest.yaml`` when it is a complete rendered suite, else None."""
    try:
        doc = yaml.safe_load((folder / "manifest.yaml").read_text())
    except (OSError, yaml.YAMLError):
        return None
    return doc.get("suite") if isinstance(doc, dict) and isinstance(doc.get("suite"), dict) else None


def _render_one(args: tuple[Path, dict, float]) -> str:
    from bracketry_emulator.synth.world import world_from_scenario
    from bracketry_emulator.synth.writer import write_trajectory

    out, doc, detail = args
    sc = scenario_from_dict(doc)
    world = world_from_scenario(sc, detail=detail)
    tmp = out.with_name(out.name + ".partial")
    if tmp.exists():
        shutil.rmtree(tmp)
    write_trajectory(world, tmp, seconds=sc.duration_s, brackets_ms=sc.brackets_ms, fps=sc.fps)
    (tmp / "scenario.yaml").write_text(yaml.safe_dump(sc.to_dict(), sort_keys=False))
    if out.exists():
        shutil.rmtree(out)
    tmp.rename(out)
    return out.name


def render_suite(out: Path, size: str, seed: int = 0, workers: int = 1,
                 progress: Callable[[int, int], None] | None = None) -> dict:
    """Render the suite of ``size`` and ``seed`` into ``out`` (created; existing trajectories are replaced) and
    write ``out/manifest.yaml`` last. Returns the manifest document. ``workers`` > 1 renders trajectories in that
    many processes (the bytes do not depend on it)."""
    ents = entries(size)
    spec = SIZES[size]
    out.mkdir(parents=True, exist_ok=True)
    manifest = out / "manifest.yaml"
    if manifest.exists():
        manifest.unlink()
    jobs = []
    for e in ents:
        (out / e.subset).mkdir(exist_ok=True)
        jobs.append((out / e.subset / e.name, entry_scenario_doc(e, size, seed), spec.detail))
    for _, doc, _ in jobs:  # every scenario is valid before any work
        scenario_from_dict(doc)
    done = 0
    if workers > 1 and len(jobs) > 1:
        import multiprocessing

        with multiprocessing.get_context("fork").Pool(min(workers, len(jobs))) as pool:
            for _ in pool.imap_unordered(_render_one, jobs):
                done += 1
                if progress is not None:
                    progress(done, len(jobs))
    else:
        for job in jobs:
            _render_one(job)
            done += 1
            if progress is not None:
                progress(done, len(jobs))
    doc = manifest_doc(size, seed)
    manifest.write_text(yaml.safe_dump(doc, sort_keys=False))
    return doc


def manifest_doc(size: str, seed: int) -> dict:
    """The manifest of the suite of ``size`` and ``seed``: its id, a description, ``warmup_steps``, ``windows_m``
    (sizes with short walks) and its trajectories (path, subset, name, split, scenario)."""
    ents = entries(size)
    spec = SIZES[size]
    return {"suite": suite_id(size, seed),
            "description": f"bracketry synthetic suite v{SUITE_VERSION}, size {size}, seed {seed}: "
                           f"{len(ents)} trajectories of {spec.duration_s:g} s at {spec.resolution[0]}x"
                           f"{spec.resolution[1]}",
            "warmup_steps": WARMUP_STEPS,
            **({"windows_m": list(spec.windows_m)} if spec.windows_m else {}),
            "trajectories": [{"path": f"{e.subset}/{e.name}", "subset": e.subset, "name": e.name, "split": e.split,
                              "scenario": e.scenario} for e in ents]}


def _link_tree(src: Path, dst: Path) -> None:
    """Copy every file of ``src`` (the cache) into ``dst``: copies, never hard links, so writing into a suite folder
    cannot change the cache nor any later suite made from it (``os.copy_file_range`` under ``shutil.copy2`` shares
    extents where the file system can; a demo-size suite is about 140 MB)."""
    for root, _dirs, files in os.walk(src):
        rel = Path(root).relative_to(src)
        (dst / rel).mkdir(parents=True, exist_ok=True)
        for f in files:
            target = dst / rel / f
            if target.exists():
                target.unlink()
            shutil.copy2(Path(root) / f, target)


def make_suite(out: Path, size: str, seed: int = 0, overwrite: bool = False, use_cache: bool = True,
               workers: int = 1, progress: Callable[[int, int], None] | None = None) -> tuple[dict, str]:
    """The suite of (size, seed) in ``out``: reused when ``out`` already holds it, linked from the cache when the
    cache holds it, else rendered (into the cache, then linked; or straight into ``out`` without cache).

    Returns (suite id, how: "reused" | "cached" | "rendered"). A non-empty ``out`` that holds anything else is
    refused unless ``overwrite`` (then it is replaced)."""
    entries(size)
    want = suite_id(size, seed)
    if read_suite_id(out) == want:
        return want, "reused"
    if out.exists() and any(out.iterdir()):
        if not overwrite:
            raise BracketryError(f"--out {out} is not empty and does not hold this suite ({size}, seed {seed}, "
                                 f"version {SUITE_VERSION}); use --overwrite to replace it")
        shutil.rmtree(out)
    if not use_cache:
        render_suite(out, size, seed, workers, progress)
        return want, "rendered"
    cache = cache_dir(size, seed)
    how = "cached"
    if read_suite_id(cache) != want:
        render_suite(cache, size, seed, workers, progress)
        how = "rendered"
    _link_tree(cache, out)
    return want, how


# ---------------------------------------------------------------------------------------------------- measures
def view_dynamic_range_stops(radiance: np.ndarray, lo_pct: float = 1.0, hi_pct: float = 99.0) -> float:
    """Dynamic range of one view in stops: log2 of the ``hi_pct`` over the ``lo_pct`` percentile of the radiance
    (float (H, W); the darkest and brightest 1 % of the pixels by default)."""
    lo, hi = np.percentile(np.asarray(radiance, np.float64), [lo_pct, hi_pct])
    return float(np.log2(hi / max(lo, 1e-12)))


def sun_in_view(doc: dict, times_s: np.ndarray) -> np.ndarray:
    """Whether the sun's centre lands in the left image at each instant of ``times_s`` (float (N,), seconds; clipped
    to the walk's start) of a scenario document: bool (N,). The rig's left lens at the scenario's resolution, as the
    renderer places the sun (:func:`~bracketry_emulator.synth.scenario.sun_pixel`); trees and terrain are not traced;
    all False for a sun below the horizon."""
    sc = scenario_from_dict(doc)
    times = np.asarray(times_s, np.float64)
    if sun_position(sc.sun)[0] <= 0.0:
        return np.zeros(times.shape, bool)
    traj = sc.trajectory()
    cam = default_calibration(*sc.resolution).left
    sun_w = np.asarray(sc.lighting().sun_dir, np.float64)
    return np.array([sun_pixel(cam, traj.pose(max(float(t), 0.0))[0].T @ sun_w) is not None for t in times], bool)


def sun_in_view_share(doc: dict, step_s: float = 0.25) -> float:
    """Share of a scenario's instants (every ``step_s`` over its duration, in seconds) at which the sun's centre lands
    in the left image (:func:`sun_in_view`)."""
    seen = sun_in_view(doc, np.arange(0.0, float(scenario_from_dict(doc).duration_s), step_s))
    return float(seen.mean()) if seen.size else 0.0


def scene_brightness(radiance: np.ndarray) -> float:
    """The brightness of a view: the median radiance (robust to the sky and the sun)."""
    return float(np.median(radiance))


def brightness_change(times_s: np.ndarray, brightness: np.ndarray, window_s: float = 2.0) -> float:
    """Largest ratio of brightness between two instants at most ``window_s`` apart (>= 1)."""
    t = np.asarray(times_s, np.float64)
    b = np.asarray(brightness, np.float64)
    best = 1.0
    for i in range(t.size):
        near = (t >= t[i]) & (t <= t[i] + window_s + 1e-9)
        hi, lo = b[near].max(), b[near].min()
        best = max(best, float(hi / max(lo, 1e-12)))
    return best


def scenario_figures(doc: dict, resolution: tuple[int, int] = (160, 100), step_s: float = 0.5,
                     detail: float = 0.25) -> dict:
    """What a scenario asks of an exposure, measured on its rendered radiance (left camera, every ``step_s`` over
    its duration, at ``resolution``): the dynamic range of one view in stops (median and max over the views, see
    :func:`view_dynamic_range_stops`), the largest brightness change within 2 s (:func:`brightness_change` of
    :func:`scene_brightness`), the brightness range over the walk, and the pace."""
    from bracketry_emulator.synth.world import world_from_scenario

    sc = scenario_from_dict(doc)
    world = world_from_scenario(sc, resolution=resolution, detail=detail, motion_blur=False)
    times = np.arange(0.0, sc.duration_s, step_s)
    stops, bright = [], []
    for t in times:
        rad = world.radiance("left", float(t)).radiance
        stops.append(view_dynamic_range_stops(rad))
        bright.append(scene_brightness(rad))
    b = np.array(bright)
    return {"name": sc.name, "subset": sc.subset, "preset": sc.preset, "pace_kmh": sc.route.pace_kmh,
            "sun_elevation_deg": sun_position(sc.sun)[0],
            "view_range_stops_median": float(np.median(stops)), "view_range_stops_max": float(np.max(stops)),
            "change_2s_x": brightness_change(times, b, 2.0),
            "brightness_range_stops": float(np.log2(b.max() / max(b.min(), 1e-12)))}


def thumbnail_strip(doc: dict, n: int = 6, resolution: tuple[int, int] = (192, 120), exposure_us: float = 4000.0,
                    detail: float = 0.25) -> np.ndarray:
    """A strip of ``n`` views spread over the scenario's duration: top row the radiance tone-mapped over 16 stops
    (log scale: what is there), bottom row the camera's frame at a fixed ``exposure_us`` (what one exposure keeps).
    uint8 BGR (2 H, n W, 3)."""
    import cv2

    from bracketry_emulator.synth.world import world_from_scenario

    sc = scenario_from_dict(doc)
    world = world_from_scenario(sc, resolution=resolution, detail=detail, motion_blur=False)
    top, bottom = [], []
    for t in np.linspace(0.0, sc.duration_s, n, endpoint=False) + 0.5:
        rad = world.radiance("left", float(t)).radiance.astype(np.float64)
        lo = np.log2(max(float(np.percentile(rad, 99.5)), 1e-9)) - 16.0
        tone = np.clip((np.log2(np.maximum(rad, 1e-12)) - lo) / 16.0, 0, 1)
        mosaic = (tone * 255).astype(np.uint8)
        top.append(cv2.cvtColor(mosaic, cv2.COLOR_BayerBG2BGR))
        codes = world.render("left", float(t), exposure_us, noise=False)
        bottom.append(cv2.cvtColor((codes >> 4).astype(np.uint8), cv2.COLOR_BayerBG2BGR))
    return np.vstack([np.hstack(top), np.hstack(bottom)])


def _figures_main(out_dir: Path) -> None:
    """Thumbnail strips of the shipped scenarios into ``out_dir`` and their figures as a Markdown table."""
    import cv2

    out_dir.mkdir(parents=True, exist_ok=True)
    print("| scenario | subset | pace km/h | sun elevation | one view: stops (median / max) | "
          "brightness change within 2 s | brightness over the walk |")
    print("|---|---|---|---|---|---|---|")
    for name, path in shipped_scenarios().items():
        doc = read_scenario_doc(path)
        if name == "day-cycle":
            doc = merge(doc, {"sun": {"hour": 9.0}})
        f = scenario_figures(doc)
        cv2.imwrite(str(out_dir / f"{name}.jpg"), thumbnail_strip(doc), [cv2.IMWRITE_JPEG_QUALITY, 88])
        print(f"| {name} | {f['subset']} | {f['pace_kmh']:g} | {f['sun_elevation_deg']:.1f} deg | "
              f"{f['view_range_stops_median']:.1f} / {f['view_range_stops_max']:.1f} | {f['change_2s_x']:.1f}x | "
              f"{f['brightness_range_stops']:.1f} stops |", flush=True)


if __name__ == "__main__":
    import sys

    _figures_main(Path(sys.argv[1]) if len(sys.argv) > 1 else Path("emulator/docs/scenarios"))
