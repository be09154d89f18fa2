"""Gain emulation: a target beyond the longest bracket is that bracket's exposure plus analog gain, with the noise
model's noise, and the steps record the exposure and gain the image stands for."""

from __future__ import annotations

import csv
from pathlib import Path

import numpy as np
import pytest

from bracketry_emulator.emulation import Emulator, EmulatorConfig, NoiseModel
from emu_synthetic import BRACKETS_US, SRGB, radiance_map, render, write_tree


def _brackets(irr: np.ndarray, seed: int = 0) -> dict[int, np.ndarray]:
    rng = np.random.default_rng(seed)
    return {e: render(irr, e, rng) for e in BRACKETS_US}


def test_beyond_the_longest_bracket_is_its_exposure_plus_gain() -> None:
    imgs = _brackets(radiance_map(seed=1) * 0.01)
    gained = Emulator(EmulatorConfig()).emulate(imgs, 64_000.0)
    plain = Emulator(EmulatorConfig(beyond="extrapolate")).emulate(imgs, 64_000.0)
    assert gained.camera_exposure_us == 32_000.0 and gained.gain_db == pytest.approx(20 * np.log10(2.0))
    assert plain.camera_exposure_us == 64_000.0 and plain.gain_db == 0.0
    # the scaled longest bracket already carries the noise of 32 ms at 2x gain: the same image
    np.testing.assert_array_equal(gained.image, plain.image)
    inside = Emulator(EmulatorConfig()).emulate(imgs, 6_000.0)
    assert inside.camera_exposure_us == 6_000.0 and inside.gain_db == 0.0


def test_a_gain_a_method_asks_for_is_its_exposure_amplified() -> None:
    """4 ms at 12 dB (the target 16 ms, inside the brackets): the 4 ms bracket is the source (the camera's exposure),
    amplified 4x with the noise model's gain noise; the mean level is the 16 ms frame's, the noise larger. With the
    gain request beyond the longest bracket the rest is gain too. Fusion takes the request the same way."""
    level_16 = 400.0
    irr = np.full((200, 200), level_16 / 16_000.0)
    imgs = _brackets(irr, seed=3)
    model = NoiseModel(read_dn=1.0, dn_per_e=0.4)
    emu = Emulator(EmulatorConfig(noise=model))
    asked = emu.emulate(imgs, 16_000.0, gain_db=20 * np.log10(4.0))
    assert asked.source_exposure_us == 4000 and asked.camera_exposure_us == pytest.approx(4000.0)
    assert asked.gain_db == pytest.approx(20 * np.log10(4.0))
    exposed = emu.emulate(imgs, 16_000.0)
    assert exposed.source_exposure_us == 16_000 and exposed.gain_db == 0.0
    a, b = (SRGB.icrf[x.image].astype(np.float64) for x in (asked, exposed))
    assert a.mean() == pytest.approx(b.mean(), rel=0.03)
    assert a.var() == pytest.approx(16 * (1.0 + 0.4 * level_16 / 4), rel=0.10)  # a 4 ms frame read out at 4x
    assert a.var() > 2.5 * b.var()
    far = emu.emulate(imgs, 256_000.0, gain_db=6.0)  # 128 ms asked: the longest bracket, the rest as gain
    assert far.camera_exposure_us == 32_000.0 and far.gain_db == pytest.approx(20 * np.log10(8.0))
    fused = Emulator(EmulatorConfig(selection="fusion", noise=model)).emulate(imgs, 16_000.0, gain_db=20 * np.log10(4))
    assert fused.camera_exposure_us == pytest.approx(4000.0) and fused.source_exposure_us == 4000
    assert SRGB.icrf[fused.image].astype(np.float64).var() == pytest.approx(a.var(), rel=0.15)


def test_fused_gain_has_the_noise_models_noise() -> None:
    """A flat field fused from every bracket is nearly noise-free; at 4x gain beyond 32 ms the emulated image has
    the variance G^2 (read^2 + k S) of a 32 ms frame read out with gain 4 (within 10 %)."""
    level_32 = 150.0
    irr = np.full((200, 200), level_32 / 32_000.0)
    imgs = _brackets(irr, seed=2)
    model = NoiseModel(read_dn=1.0, dn_per_e=0.4)  # the noise emu_synthetic renders with
    out = Emulator(EmulatorConfig(selection="fusion", fusion_brackets="all", noise=model)).emulate(imgs, 128_000.0)
    assert out.camera_exposure_us == 32_000.0 and out.gain_db == pytest.approx(20 * np.log10(4.0))
    lin = SRGB.icrf[out.image].astype(np.float64)
    assert lin.mean() == pytest.approx(4 * level_32, rel=0.02)
    expected_var = 16 * (1.0 + 0.4 * level_32)
    assert lin.var() == pytest.approx(expected_var, rel=0.10)
    # without gain (extrapolated), the fused image keeps its small variance: the gain noise is the model's
    flat = Emulator(EmulatorConfig(selection="fusion", fusion_brackets="all", noise=model, beyond="extrapolate"))
    assert SRGB.icrf[flat.emulate(imgs, 128_000.0).image].var() < 0.6 * expected_var


def test_steps_record_exposure_and_gain(tmp_path: Path) -> None:
    from bracketry_emulator.ae import LoopConfig, resolve_methods, run_methods

    data = write_tree(tmp_path / "ds", radiance_map(seed=3) * 0.02, n_sequences=2)
    cfg = LoopConfig(write_images=False, max_exposure_us=200_000.0)
    run_methods(data, resolve_methods(["constant-128", "constant-8"]), tmp_path / "out", workers=1, config=cfg,
                progress=False)
    for name, exp_ms, gain_db in (("constant-128", 32.0, 20 * np.log10(4.0)), ("constant-8", 8.0, 0.0)):
        steps = list(csv.DictReader((tmp_path / "out" / name / "steps.csv").open()))
        assert [float(r["exposure_ms"]) for r in steps] == [exp_ms, exp_ms]
        assert [float(r["gain_db"]) for r in steps] == pytest.approx([gain_db, gain_db], abs=1e-4)
        ae = list(csv.DictReader((tmp_path / "out" / name / "ae.csv").open()))
        assert [float(r["gain_db"]) for r in ae] == pytest.approx([gain_db, gain_db], abs=1e-4)
