"""The ground's texture statistics: the forest snow's 1/f texture has the RMS contrast the scene module states
(the real sample's local ground contrast, emulator/DATASET.md), and its litter is no high-contrast pattern."""

from __future__ import annotations

import numpy as np

from bracketry_emulator.synth.noise import ValueNoise, smoothstep
from bracketry_emulator.synth.scene import (
    _FINE_RMS,
    GROUND_RMS_CONTRAST,
    SNOW_ALBEDO,
    SPECK_ALBEDO,
    _base_albedo,
)


def _noises(seed: int) -> dict[str, ValueNoise]:
    rng = np.random.default_rng(seed)
    return {"fine": ValueNoise(rng, 0.6, octaves=5), "mid": ValueNoise(rng, 0.25, octaves=3),
            "big": ValueNoise(rng, 9.0, octaves=4), "speck": ValueNoise(rng, 0.16, octaves=2)}


def test_the_fine_noise_has_the_rms_the_texture_formula_divides_by() -> None:
    n = 1024
    field = _noises(1)["fine"].grid(-40.0, -40.0, 80.0 / n, n)
    assert abs(float(np.sqrt(np.mean(field ** 2))) / _FINE_RMS - 1.0) < 0.1


def test_forest_snow_has_the_stated_rms_contrast_and_low_contrast_litter() -> None:
    n, half_m = 1024, 40.0
    texel_m = 2 * half_m / n
    noises = _noises(2)
    far_from_trail = np.full((n, n), 10.0, np.float32)
    green = _base_albedo("forest-winter", noises, far_from_trail, half_m, texel_m)[0]
    specks = smoothstep(0.42, 0.5, noises["speck"].grid(-half_m, -half_m, texel_m, n))
    bare = smoothstep(0.32, 0.40, noises["big"].grid(-half_m, -half_m, texel_m, n))
    snow = green[(specks == 0) & (bare == 0)]
    assert snow.size > 0.3 * n * n
    # the formula: albedo = SNOW_ALBEDO * (1 + GROUND_RMS_CONTRAST * fine / RMS(fine))
    assert abs(float(snow.mean()) / SNOW_ALBEDO - 1.0) < 0.03
    assert abs(float(snow.std() / snow.mean()) / GROUND_RMS_CONTRAST - 1.0) < 0.15
    assert float(snow.min()) > 0.0
    # litter where the specks cover a texel fully: a Michelson contrast against the snow well below a dark twig's
    litter = green[(specks == 1) & (bare == 0)]
    michelson = (SNOW_ALBEDO - float(litter.mean())) / (SNOW_ALBEDO + float(litter.mean()))
    assert abs(float(litter.mean()) - SPECK_ALBEDO) < 0.02 and michelson < 0.4
