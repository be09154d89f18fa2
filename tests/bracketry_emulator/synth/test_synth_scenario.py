"""Scenarios: parsing (one-line errors), the light they put in the world over time, and rebuilding a written world."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from bracketry.errors import BracketryError
from bracketry_emulator.synth import World, world_from_dataset, world_from_scenario, write_trajectory
from bracketry_emulator.synth.scenario import (
    scenario_from_dict,
    sun_position,
)


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
