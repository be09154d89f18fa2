"""Scenarios: parsing (one-line errors), the light they put in the world over time, and rebuilding a written world."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from bracketry_base.errors import BracketryError
from bracketry_emulator.synth import World, world_from_dataset, world_from_scenario, write_trajectory
from bracketry_emulator.synth.scenario import (
    scenario_from_dict,
    sun_position,
)
from bracketry_emulator.synth.world import sun_differences


def _doc(**kw: object) -> dict:
    base: dict = {"preset": "forest-winter", "route": {"length_m": 60.0, "pace_kmh": 3.0}, "sun": {"hour": 11.0}}
    base.update(kw)
    return base


def test_world_from_dataset_rebuilds_the_exact_world(tmp_path: Path) -> None:
    sc = scenario_from_dict(_doc(preset="campus-summer", sun={"hour": 17.5},
                                 route={"length_m": 60, "start_fraction": 0.3},
                                 lighting_events=[{"kind": "clouds"}, {"kind": "canopy", "from": 0.5, "to": 0.7}]))
    for k, world in enumerate((world_from_scenario(sc, seed=5, resolution=(64, 40), detail=0.25),
                               World("forest-winter", seed=2, resolution=(64, 40)))):
        out = tmp_path / f"w{k}"
        write_trajectory(world, out, seconds=0.3)
        again = world_from_dataset(out)
        assert (again.scenario is None) == (world.scenario is None)
        for t in (0.0, 0.13):
            assert np.array_equal(world.render("right", t, 8000.0), again.render("right", t, 8000.0))
            assert np.array_equal(world.pose(t), again.pose(t))


def test_world_from_dataset_refuses_a_folder_that_is_not_synthetic(tmp_path: Path) -> None:
    with pytest.raises(BracketryError, match="not a synthetic dataset"):
        world_from_dataset(tmp_path)


@pytest.mark.parametrize(("doc", "message"), [
    ({"route": {"length_m": 60}}, "preset must be one of"),
    (_doc(route={"pace_kmh": 40}), r"route.pace_kmh must be in \(0, 20\]"),
    (_doc(sun={"hour": 11, "elevation_deg": 5}), "give both elevation_deg and azimuth_deg"),
    (_doc(weather={"fog": 1}), "weather: unknown key 'fog'"),
    (_doc(lighting_events=[{"kind": "lightning"}]), r"lighting_events\[0\] must be a mapping with kind"),
    (_doc(lighting_events=[{"kind": "canopy", "from": 0.2}]), "needs 'to'"),
    (_doc(lighting_events=[{"kind": "dimming", "times_s": [0, 5], "factors": [1]}]), "same non-zero length"),
    (_doc(brackets_ms=[1, 64]), "does not fit in the frame period"),
    (_doc(scenario=2), "format version 2 is not supported"),
])
def test_bad_scenarios_are_refused_in_one_line(doc: dict, message: str) -> None:
    with pytest.raises(BracketryError, match=message) as info:
        scenario_from_dict(doc)
    assert "\n" not in str(info.value)


def test_sun_position_follows_the_time_of_day() -> None:
    from bracketry_emulator.synth.scenario import Sun

    noon, _ = sun_position(Sun(hour=12.0, day_of_year=172, latitude_deg=46.8))
    assert noon == pytest.approx(90.0 - 46.8 + 23.44, abs=0.2)
    morning_e, morning_az = sun_position(Sun(hour=8.0, day_of_year=172, latitude_deg=46.8))
    evening_e, evening_az = sun_position(Sun(hour=16.0, day_of_year=172, latitude_deg=46.8))
    assert morning_e == pytest.approx(evening_e, abs=1e-6) and 0 < morning_e < noon
    # world azimuth from east towards north: the morning sun is east (cos > 0), the evening sun west
    assert np.cos(np.radians(morning_az)) > 0 > np.cos(np.radians(evening_az))
    dusk, _ = sun_position(Sun(hour=20.5, day_of_year=172, latitude_deg=46.8))
    assert dusk < 0


#: renders frames of a scenario with every kind of light (canopy, patches, clouds, dimming, glare, fresh snow) and
#: prints the digest of their radiance and codes
_SCENARIO_SCRIPT = """
import hashlib
import numpy as np
from bracketry_emulator.synth.scenario import scenario_from_dict
from bracketry_emulator.synth.world import world_from_scenario
doc = {"preset": "forest-winter", "sun": {"elevation_deg": 9.0, "azimuth_deg": 200.0}, "weather": {"glare": 2.0},
       "content": {"tree_density": 0.5, "treeline_scale": 0.4},
       "lighting_events": [{"kind": "canopy", "from": 0.0, "to": 0.3, "density": 0.98},
                           {"kind": "canopy_patches", "from": 0.3, "to": 0.8, "period_m": 7},
                           {"kind": "clouds", "speed_mps": 15, "size_m": 25},
                           {"kind": "dimming", "times_s": [0, 30], "factors": [1, 0.3]},
                           {"kind": "fresh_snow", "from": 0.5, "to": 0.9}]}
w = world_from_scenario(scenario_from_dict(doc), resolution=(160, 100), detail=0.25)
h = hashlib.sha256()
for t in (0.0, 5.3, 11.9, 17.2, 24.0):
    h.update(np.ascontiguousarray(w.radiance("left", t).radiance).tobytes())
    h.update(w.render("right", t, 8000.0).tobytes())
print(h.hexdigest())
"""


@pytest.mark.slow
def test_scenario_frames_are_the_same_under_every_openblas_kernel_and_numpy_dispatch() -> None:
    import os
    import platform
    import subprocess
    import sys

    if platform.machine() not in ("x86_64", "AMD64"):
        pytest.skip("the OpenBLAS kernels compared are x86-64 ones")
    flags: set[str] = set()
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.startswith("flags"):
                flags = set(line.split(":", 1)[1].split())
                break
    except OSError:
        pass
    settings: dict[str, dict[str, str]] = {"default": {}}
    settings.update({k: {"OPENBLAS_CORETYPE": k} for k, need in
                     {"Haswell": {"avx2", "fma"}, "Sandybridge": {"avx"}, "Prescott": {"sse3"}}.items()
                     if need <= flags})
    settings["numpy baseline"] = {"NPY_DISABLE_CPU_FEATURES": "X86_V3 X86_V4 AVX512_ICL AVX512_SPR"}
    settings["no C kernels"] = {"BRACKETRY_NO_CKERNEL": "1"}
    base = {k: v for k, v in os.environ.items() if k not in ("OPENBLAS_CORETYPE", "NPY_DISABLE_CPU_FEATURES")}
    procs = {name: subprocess.Popen([sys.executable, "-c", _SCENARIO_SCRIPT], env={**base, **extra},
                                    stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
             for name, extra in settings.items()}
    digests = {}
    for name, proc in procs.items():
        stdout, stderr = proc.communicate(timeout=300)
        assert proc.returncode == 0, (name, stderr[-2000:])
        digests[name] = stdout.strip()
    assert len(set(digests.values())) == 1, digests


def test_world_from_dataset_refuses_a_folder_rendered_with_another_sun(tmp_path: Path) -> None:
    # a folder whose camera_model.json records another solar disk (as code with a dimmer disk wrote it) would be
    # rebuilt with this code's disk: its truth renders would not match its images
    sc = scenario_from_dict(_doc(sun={"elevation_deg": 5.0, "azimuth_deg": 200.0}))
    out = tmp_path / "w"
    write_trajectory(world_from_scenario(sc, seed=1, resolution=(64, 40), detail=0.25), out, seconds=0.1)
    world_from_dataset(out)  # as written: rebuilt
    info_path = out / "camera_model.json"
    info = json.loads(info_path.read_text())
    disk = info["world"]["sun"]["disk_radiance"]
    info["world"]["sun"]["disk_radiance"] = disk / 10.8
    info_path.write_text(json.dumps(info))
    with pytest.raises(BracketryError, match=r"another sun than this code builds \(disk_radiance"):
        world_from_dataset(out)
    info["world"]["sun"] = [disk]  # not a mapping: refused in one line too
    info_path.write_text(json.dumps(info))
    with pytest.raises(BracketryError, match=r"world\.sun is not a mapping"):
        world_from_dataset(out)
    # the same check, on the parts: numbers within a relative 1e-9, other values equal, a missing entry differs
    assert sun_differences({"disk_radiance": disk * (1 + 1e-12), "elevation_deg": 5.0},
                           {"disk_radiance": disk, "elevation_deg": 5.0, "direction_world": [0.0, 1.0, 0.0]}) == []
    assert sun_differences({"direction_world": [0.0, 1.0, 0.0]}, {"direction_world": [0.0, 0.99, 0.0]})
    assert sun_differences({"note": "x"}, {"note": "y"}) and sun_differences({"disk_radiance": 1.0}, {})
