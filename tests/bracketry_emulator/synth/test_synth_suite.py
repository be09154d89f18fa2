"""The synthetic suite and scenario commands: light that decides the exposure (measured on rendered radiance),
the manifest, determinism, the cache, and bad input."""

from __future__ import annotations

import hashlib
import json
from pathlib import Path

import numpy as np
import pytest
import yaml

from bracketry.cli import main
from bracketry_emulator.metrics.manifest import load_manifest
from bracketry_emulator.synth import suite
from bracketry_emulator.synth.scenario import load_scenario, scenario_from_dict, shipped_scenarios
from bracketry_emulator.synth.suite import (
    SUBSETS,
    brightness_change,
    entries,
    entry_scenario_doc,
    scene_brightness,
    sun_in_view,
    sun_in_view_share,
    view_dynamic_range_stops,
)
from bracketry_emulator.synth.world import world_from_scenario


class _Res:
    def __init__(self, exit_code: int, output: str) -> None:
        self.exit_code, self.output = exit_code, output


def _run(capsys: pytest.CaptureFixture[str], args: list[str]) -> _Res:
    capsys.readouterr()
    rc = main(["synth", *args])
    cap = capsys.readouterr()
    return _Res(rc, cap.out + cap.err)


def _world(name: str, **kw: object):
    doc = entry_scenario_doc(next(e for e in entries("full") if e.name == name), "full", 0)
    return world_from_scenario(scenario_from_dict(doc), resolution=(160, 100), detail=0.25, **kw)


def test_canopy_and_open_snow_span_11_stops_in_one_view() -> None:
    # a dense spruce stand passes about 5 % of the open light (forest-canopy.yaml): 4.3 stops below the open snow
    world = _world("forest_canopy_a")
    stops = [view_dynamic_range_stops(world.radiance("left", t).radiance) for t in (2.0, 6.0, 10.0)]
    assert min(stops) >= 11.0, stops
    # the preset alone (no canopy) does not
    plain = world_from_scenario(scenario_from_dict({"preset": "forest-winter", "sun": {"hour": 11.5}}),
                                resolution=(160, 100), detail=0.25)
    assert view_dynamic_range_stops(plain.radiance("left", 6.0).radiance) < 8.0


def test_every_full_size_glare_walk_holds_the_sun_in_its_view() -> None:
    # the glare subset is the paper's Campus1: a low sun in the field of view along part of the loop
    shares = {e.name: sun_in_view_share(entry_scenario_doc(e, "full", 0)) for e in entries("full")
              if e.subset == "glare"}
    assert len(shares) == 6 and min(shares.values()) >= 0.1, shares
    # a sun 12 degrees high at azimuth 300 stays above the view of a camera pitched down; one behind it, never in it
    doc = entry_scenario_doc(next(e for e in entries("full") if e.name == "glare_d"), "full", 0)
    assert sun_in_view_share({**doc, "sun": {"elevation_deg": 12.0, "azimuth_deg": 300.0}}) == 0.0
    assert sun_in_view_share({**doc, "sun": {"elevation_deg": 6.0, "azimuth_deg": 60.0}}) == 0.0
    # the share is that of the instants at which the sun lands in the image, and the instants come back in order
    times = np.arange(0.0, 60.0, 0.25)
    seen = sun_in_view(doc, times)
    assert seen.dtype == bool and seen.shape == times.shape and 0 < seen.sum() < seen.size
    assert seen.mean() == pytest.approx(shares["glare_d"])
    assert np.array_equal(sun_in_view(doc, times[::-1]), seen[::-1])
    # below the horizon there is no sun to see
    assert sun_in_view_share({**doc, "sun": {"elevation_deg": -2.0, "azimuth_deg": 300.0}}) == 0.0


def test_sun_and_shadow_change_the_brightness_8x_within_2_s() -> None:
    world = _world("sun_shadow_a")
    times = np.arange(0.0, 30.0, 0.25)
    bright = [scene_brightness(world.radiance("left", float(t)).radiance) for t in times]
    assert brightness_change(times, np.array(bright), 2.0) >= 8.0


def test_light_depends_on_the_instant_not_only_the_pose() -> None:
    doc = {"preset": "forest-winter", "lighting_events": [{"kind": "dimming", "times_s": [0, 10], "factors": [1, 0.1]}]}
    world = world_from_scenario(scenario_from_dict(doc), resolution=(64, 40), detail=0.1)
    a = world.radiance("left", 0.0).radiance
    b = world.radiance("left", 10.0).radiance
    c = world_from_scenario(scenario_from_dict({"preset": "forest-winter"}), resolution=(64, 40),
                            detail=0.1).radiance("left", 10.0).radiance
    assert np.allclose(b, c * np.float32(0.1), rtol=1e-5)
    assert scene_brightness(a) > 5 * scene_brightness(b)


def test_dusk_exposes_well_only_at_the_longest_brackets() -> None:
    world = _world("forest_dusk_a", motion_blur=False)
    codes = {ms: float(np.median(world.render("left", 1.0, ms * 1000.0, noise=False))) for ms in (1, 32)}
    # 1 ms: the median pixel in the bottom 5 % of the codes; 32 ms: within 15-85 %
    assert codes[1] < 0.05 * 4095 and 0.15 * 4095 < codes[32] < 0.85 * 4095, codes


def test_the_day_cycle_sunset_walk_needs_long_exposures() -> None:
    """The demo's last day-cycle walk (sunset, emulator/DATASET.md): the longest exposure the benchmark emulates
    (64 ms) finds at least 1.5x the ORB corners of 4 ms in the view (its ground texture needs the light)."""
    import cv2

    entry = next(e for e in entries("demo") if e.subset == "day-cycle" and e.name != "day_cycle_0900")
    world = world_from_scenario(scenario_from_dict(entry_scenario_doc(entry, "demo", 5)))
    orb = cv2.ORB_create(3000, fastThreshold=15)

    def corners(exposure_us: float) -> int:
        codes = world.render("left", 5.0, exposure_us, noise=True)
        gray = cv2.cvtColor((np.clip(codes, 0, 4095) >> 4).astype(np.uint8), cv2.COLOR_BayerBG2GRAY)
        return len(orb.detect(gray, None))

    long_, short = corners(64000.0), corners(4000.0)
    assert long_ >= 1.5 * short and short < 150, (long_, short)


def test_the_manifest_names_subsets_splits_and_version() -> None:
    for size, n_min in (("demo", 10), ("full", 28)):
        ents = entries(size)
        assert len(ents) >= n_min
        assert {e.subset for e in ents} == set(SUBSETS)
        assert {e.split for e in ents} == {"train", "test"}
        assert len({e.name for e in ents}) == len(ents)
        day = [e for e in ents if e.subset == "day-cycle"]
        # one loop at six times of day (the demo: the morning and sunset of them)
        assert len(day) == (6 if size == "full" else 2) and len({suite.world_seed(0, e) for e in day}) == 1
        # the demo's walks are long enough to lose track in
        assert all(suite.SIZES[size].duration_s >= (60 if size == "full" else 10) for _ in ents)
    with pytest.raises(Exception, match="unknown suite size"):
        entries("huge")


def _tiny_suite(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setattr(suite, "SIZES", {**suite.SIZES, "demo": suite.SizeSpec((48, 30), 0.3, 0.1)})
    keep = {"forest_canopy_a", "sun_shadow_b", "glare_a", "day_cycle_0900", "day_cycle_1948"}
    monkeypatch.setattr(suite, "ENTRIES", tuple(e for e in suite.ENTRIES if e.name in keep))


def _digest(folder: Path) -> str:
    h = hashlib.sha256()
    for p in sorted(folder.rglob("*")):
        if p.is_file():
            h.update(str(p.relative_to(folder)).encode())
            h.update(p.read_bytes())
    return h.hexdigest()


def test_a_suite_is_the_same_bytes_for_the_same_seed_and_cached(tmp_path: Path, monkeypatch: pytest.MonkeyPatch,
                                                                  capsys: pytest.CaptureFixture[str]) -> None:
    _tiny_suite(monkeypatch)
    monkeypatch.setenv("BRACKETRY_CACHE", str(tmp_path / "cache"))
    res = _run(capsys, ["suite", "--out", str(tmp_path / "a"), "--size", "demo", "--seed", "3", "-q",
                                  "--no-cache", "--workers", "1"])
    assert res.exit_code == 0, res.output
    res = _run(capsys, ["suite", "--out", str(tmp_path / "b"), "--size", "demo", "--seed", "3", "-q",
                                  "--workers", "2"])
    assert res.exit_code == 0, res.output
    assert "rendered" in res.output
    assert _digest(tmp_path / "a") == _digest(tmp_path / "b")
    # the manifest: subsets, splits, version; read by the benchmark's loader
    doc = yaml.safe_load((tmp_path / "a" / "manifest.yaml").read_text())
    assert doc["suite"] == {"version": suite.SUITE_VERSION, "size": "demo", "seed": 3, "code": suite.code_digest()}
    specs = load_manifest(tmp_path / "a" / "manifest.yaml")
    assert {s.subset for s in specs} == set(SUBSETS)
    assert {s.split for s in specs} == {"train", "test"}
    assert all((s.path / "groundtruth.txt").is_file() and (s.path / "scenario.yaml").is_file() for s in specs)
    # a second call renders nothing: from the cache into a new folder, and an existing suite is reused
    res = _run(capsys, ["suite", "--out", str(tmp_path / "c"), "--size", "demo", "--seed", "3", "-q"])
    assert res.exit_code == 0 and "cached" in res.output, res.output
    res = _run(capsys, ["suite", "--out", str(tmp_path / "c"), "--size", "demo", "--seed", "3", "-q"])
    assert res.exit_code == 0 and "reused" in res.output, res.output
    assert _digest(tmp_path / "c") == _digest(tmp_path / "a")
    # another seed differs; it is refused into a folder holding this suite unless --overwrite
    res = _run(capsys, ["suite", "--out", str(tmp_path / "c"), "--size", "demo", "--seed", "4", "-q"])
    assert res.exit_code == 2 and "--overwrite" in res.output
    res = _run(capsys, ["suite", "--out", str(tmp_path / "c"), "--size", "demo", "--seed", "4", "-q",
                                  "--overwrite", "--no-cache"])
    assert res.exit_code == 0, res.output
    assert _digest(tmp_path / "c") != _digest(tmp_path / "a")


def test_an_edited_copy_of_a_shipped_scenario_renders_with_the_edit(tmp_path: Path,
                                                                     capsys: pytest.CaptureFixture[str]) -> None:
    src = shipped_scenarios()["glare"]
    text = src.read_text()
    assert "elevation_deg: 8.0" in text
    edited = tmp_path / "my-glare.yaml"
    edited.write_text(text.replace("elevation_deg: 8.0", "elevation_deg: 35.0"))
    outs = {}
    for name, path in (("shipped", src), ("edited", edited)):
        out = tmp_path / name
        res = _run(capsys, ["trajectory", "--scenario", str(path), "--out", str(out), "--duration-s", "0.3",
                                      "--resolution", "48x30", "--detail", "0.1", "-q"])
        assert res.exit_code == 0, res.output
        outs[name] = yaml.safe_load((out / "scenario.yaml").read_text())
        info = json.loads((out / "camera_model.json").read_text())
        outs[name + "_elev"] = info["world"]["sun"]["elevation_deg"]
    assert outs["edited"]["sun"]["elevation_deg"] == 35.0
    assert outs["shipped_elev"] == pytest.approx(8.0, abs=1e-6)
    assert outs["edited_elev"] == pytest.approx(35.0, abs=1e-6)


@pytest.mark.parametrize(("args", "message"), [
    (["suite", "--out", "OUT", "--size", "huge"], "'huge' is not one of"),
    (["trajectory", "--scenario", "BAD", "--out", "OUT"], "is not valid YAML"),
    (["trajectory", "--scenario", "BAD2", "--out", "OUT"], "route.pace_kmh must be in (0, 20]"),
    (["trajectory", "--scenario", "BAD3", "--out", "OUT"], "unknown key 'colour'"),
])
def test_bad_input_is_one_line_and_exit_2(tmp_path: Path, args: list[str], message: str,
                                          capsys: pytest.CaptureFixture[str]) -> None:
    (tmp_path / "bad.yaml").write_text("preset: [x\n")
    (tmp_path / "bad2.yaml").write_text("preset: forest-winter\nroute: {pace_kmh: 99}\n")
    (tmp_path / "bad3.yaml").write_text("preset: forest-winter\nsun: {hour: 9, colour: red}\n")
    subst = {"OUT": str(tmp_path / "out"), "BAD": str(tmp_path / "bad.yaml"), "BAD2": str(tmp_path / "bad2.yaml"),
             "BAD3": str(tmp_path / "bad3.yaml")}
    res = _run(capsys, [subst.get(a, a) for a in args])
    assert res.exit_code == 2, res.output
    assert message in res.output, res.output
    assert len(res.output.strip().splitlines()) == 1, res.output
    assert not (tmp_path / "out").exists() or not any((tmp_path / "out").iterdir())


def test_every_shipped_scenario_reads_back_from_its_own_document() -> None:
    files = shipped_scenarios()
    assert {"forest-canopy", "sun-shadow", "glare", "day-cycle", "forest-dusk"} <= set(files)
    for path in files.values():
        sc = load_scenario(path)
        assert scenario_from_dict(sc.to_dict()) == sc


def test_the_suite_manifest_declares_a_warmup_the_benchmark_takes(tmp_path: Path) -> None:
    """The suite's walks start with a running camera: its manifest declares warmup_steps, each trajectory spec
    carries it (an entry may override it), the benchmark's loop of that trajectory takes it unless
    --warmup-steps overrides it; a bad value is one line."""
    from bracketry_base.errors import BracketryError
    from bracketry_emulator.ae import LoopConfig
    from bracketry_emulator.benchmark.orchestrate import spec_loop

    doc = suite.manifest_doc("demo", 0)
    assert doc["warmup_steps"] == suite.WARMUP_STEPS > 0
    doc["trajectories"][1]["warmup_steps"] = 2
    (tmp_path / "manifest.yaml").write_text(yaml.safe_dump(doc))
    specs = load_manifest(tmp_path / "manifest.yaml")
    assert [s.warmup_steps for s in specs[:3]] == [suite.WARMUP_STEPS, 2, suite.WARMUP_STEPS]
    loop = LoopConfig()
    assert spec_loop(specs[0], loop).warmup_steps == suite.WARMUP_STEPS
    assert spec_loop(specs[1], loop).warmup_steps == 2
    assert spec_loop(specs[0], loop, 0).warmup_steps == 0  # --warmup-steps 0
    assert "warmup_steps" not in loop.to_json()  # keys of runs without a warm-up stay as they were
    assert spec_loop(specs[0], loop).to_json()["warmup_steps"] == suite.WARMUP_STEPS
    for bad in (-1, 1000, "ten", 2.5, True):
        doc["warmup_steps"] = bad
        (tmp_path / "manifest.yaml").write_text(yaml.safe_dump(doc))
        with pytest.raises(BracketryError, match="warmup_steps must be a whole number"):
            load_manifest(tmp_path / "manifest.yaml")


def test_the_demo_suite_declares_rte_windows_its_short_walks_hold(tmp_path: Path) -> None:
    """The demo walks (10 s, 8-25 m) are mostly shorter than the paper's windows (5-50 m): the manifest declares
    2-8 m windows, which every spec carries (an entry may override them); the full suite keeps the paper's; bad
    ones: one line."""
    from bracketry_base.errors import BracketryError

    assert "windows_m" not in suite.manifest_doc("full", 0)
    doc = suite.manifest_doc("demo", 0)
    assert doc["windows_m"] == [2.0, 4.0, 6.0, 8.0]
    doc["trajectories"][0]["windows_m"] = [2, 1]
    (tmp_path / "manifest.yaml").write_text(yaml.safe_dump(doc))
    specs = load_manifest(tmp_path / "manifest.yaml")
    assert specs[0].windows_m == (1.0, 2.0) and specs[1].windows_m == (2.0, 4.0, 6.0, 8.0)
    for bad in ([], [0], [-1, 2], "5", [True]):
        doc["windows_m"] = bad
        (tmp_path / "manifest.yaml").write_text(yaml.safe_dump(doc))
        with pytest.raises(BracketryError, match="windows_m must be a non-empty list"):
            load_manifest(tmp_path / "manifest.yaml")
