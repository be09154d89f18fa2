"""The compiled loops of the synthetic world (``synth/_kernels.c``) give exactly the numpy paths' values: the ray
caster's radiance and range (trunk hits and their shading) and the codes of a noisy exposure from pre-drawn normals."""

from __future__ import annotations

import numpy as np
import pytest

from bracketry.sim.frames import noise_bank, world_frame
from bracketry_emulator.extensions import extensions_disabled
from bracketry_emulator.synth import World
from bracketry_emulator.synth.kernels import synth_kernels


@pytest.fixture
def both_paths() -> None:
    assert synth_kernels() is not None, "the synth _kernels extension was not built (setup.sh builds it)"


def _render(world: World, side: str, t_s: float, compiled: bool) -> tuple[np.ndarray, np.ndarray]:
    R, p = world.world_pose(t_s, side)
    if compiled:
        res = world._renderer(side).render(R, p)
    else:
        with extensions_disabled():
            assert synth_kernels() is None  # the numpy path runs
            res = world._renderer(side).render(R, p)
    return res.radiance, res.range_m


@pytest.mark.usefixtures("both_paths")
@pytest.mark.parametrize("preset", ["forest-winter", "campus-summer"])
def test_compiled_ray_caster_equals_numpy(preset: str) -> None:
    world = World(preset, seed=3, resolution=(320, 200))
    trunk_pixels = 0
    for side in ("left", "right"):
        for t_s in (0.0, 4.1, 17.3, 38.9, 61.7):
            rad_np, rng_np = _render(world, side, t_s, compiled=False)
            rad_c, rng_c = _render(world, side, t_s, compiled=True)
            assert np.array_equal(rad_np, rad_c), (side, t_s)
            assert np.array_equal(rng_np, rng_c), (side, t_s)
            trunk_pixels += int(np.count_nonzero(np.isfinite(rng_c) & (rng_c < 30)))
    assert trunk_pixels > 1000  # near objects were in view: the compared paths did cast rays at them


@pytest.mark.usefixtures("both_paths")
def test_compiled_exposure_equals_numpy() -> None:
    world = World("forest-winter", seed=1, resolution=(160, 100))
    bank = noise_bank(world, 0)
    codes = set()
    for t_s in (0.0, 9.5):
        for exposure_us in (20.0, 1000.0, 8000.0, 64000.0, 2e6):  # dark to fully saturated
            with extensions_disabled():
                assert synth_kernels() is None  # the numpy path runs
                ref = world_frame(world, bank, "left", t_s, exposure_us)
            got = world_frame(world, bank, "left", t_s, exposure_us)
            assert got.dtype == ref.dtype == np.uint16
            assert np.array_equal(got, ref), (t_s, exposure_us)
            codes.update(np.unique(got).tolist())
    assert 0 in codes and 4094 in codes and len(codes) > 1000  # clipped at both ends and a wide range between
