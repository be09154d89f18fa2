"""Truth images with one effect switched off (``camera_model.json`` ``truth_effects``), for the cause analysis."""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import numpy as np
import pytest

from bracketry_base.errors import BracketryError
from bracketry_emulator.ae.truth import TRUTH_EFFECTS, TruthCache, truth_effects
from bracketry_emulator.emulation import EmulatorConfig

LONGEST_US = 8000
SOURCE_US = 2000


@pytest.fixture(scope="module")
def walk(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """One bracket cycle (1/2/4/8 ms) of a synthetic walk at 5 km/h, 160x100."""
    from bracketry_emulator.synth import LoopTrajectory, World, write_trajectory

    out = tmp_path_factory.mktemp("walk") / "ds"
    write_trajectory(World("forest-winter", 4, (160, 100), trajectory=LoopTrajectory(speed_kmh=5.0)), out,
                     seconds=0.15, brackets_ms=(1.0, 2.0, 4.0, 8.0), sides=("left",))
    return out


def _variant(walk: Path, tmp: Path, effects: dict[str, bool]) -> Path:
    tmp.mkdir(parents=True, exist_ok=True)
    dst = tmp / f"v{len(list(tmp.iterdir()))}"
    shutil.copytree(walk, dst)
    info = json.loads((dst / "camera_model.json").read_text())
    info["truth_effects"] = effects
    (dst / "camera_model.json").write_text(json.dumps(info))
    return dst


def _image(ds: Path, target_us: float, stamp_ns: int, beyond: str = "extrapolate"
           ) -> tuple[np.ndarray, TruthCache]:
    """The truth image; by default a camera that exposes beyond the longest bracket (``beyond="extrapolate"``), so
    that the ``exposure`` effect is there to switch off."""
    cache = TruthCache(EmulatorConfig(beyond=beyond), ds)  # type: ignore[arg-type]
    images = {e: np.zeros((100, 160), np.uint16) for e in (1000, 2000, 4000, LONGEST_US)}
    out = cache.emulate(0, "left", images, target_us, source_us=SOURCE_US, times_ns={SOURCE_US: stamp_ns})
    return out.image, cache


def test_each_effect_switched_off_is_what_the_emulator_gives_instead(walk: Path, tmp_path: Path) -> None:
    stamp = json.loads((walk / "camera_model.json").read_text())["recording"]["t0_ns"] + 60_000_000
    full, cache = _image(_variant(walk, tmp_path, {}), 16_000.0, stamp)
    assert cache.effects == dict.fromkeys(TRUTH_EFFECTS, True)
    world = cache.world
    t = cache.trigger_s(stamp, SOURCE_US)
    assert np.array_equal(full, world.render("left", t, 16_000.0))

    quiet, _ = _image(_variant(walk, tmp_path, {"noise": False}), 16_000.0, stamp)
    assert np.array_equal(quiet, world.render("left", t, 16_000.0, noise=False))
    assert not np.array_equal(quiet, full)

    # no motion blur: the render at mid-exposure, sharper than the blurred frame
    sharp, c_blur = _image(_variant(walk, tmp_path, {"blur": False, "noise": False}), 16_000.0, stamp)
    assert c_blur.world.motion_blur is False
    assert np.array_equal(sharp, c_blur.world.render("left", t, 16_000.0, noise=False))

    def grad(img: np.ndarray) -> float:
        return float(np.abs(np.diff(img.astype(np.float64), axis=1)).mean())
    assert grad(sharp) > 1.02 * grad(quiet)

    # the frame centred on the source's stamp: triggered (16 - 2) / 2 ms earlier than from the source's trigger
    early, c_inst = _image(_variant(walk, tmp_path, {"instant": False}), 16_000.0, stamp)
    t_early = c_inst.trigger_s(stamp, 16_000.0)
    assert t_early == pytest.approx(t - 0.007)
    assert np.array_equal(early, world.render("left", t_early, 16_000.0))

    # beyond the longest bracket as gain: the 8 ms frame's noise amplified 4x, the same level on average
    target = 4.0 * LONGEST_US
    true_long, _ = _image(_variant(walk, tmp_path, {"noise": False, "exposure": True}), target, stamp)
    noisy_long, _ = _image(_variant(walk, tmp_path, {}), target, stamp)
    gained, c_gain = _image(_variant(walk, tmp_path, {"exposure": False}), target, stamp)
    icrf = c_gain.emulator.response.icrf
    ok = (true_long > 200) & (true_long < 3500)

    def rmse(a: np.ndarray) -> float:
        return float(np.sqrt(np.mean((a[ok].astype(np.float64) - true_long[ok]) ** 2)))
    assert rmse(gained) > 1.3 * rmse(noisy_long)
    # the same linear level on average (an 8 ms frame centred 12 ms before the 32 ms one: not the same pixels)
    assert abs(float(icrf[gained][ok].mean()) / float(icrf[true_long][ok].mean()) - 1) < 0.05


def test_the_truth_takes_gain_beyond_the_longest_bracket_as_the_emulated_camera(walk: Path, tmp_path: Path) -> None:
    """With the benchmark's camera policy (beyond="gain"), a target beyond the longest bracket is that bracket's
    exposure plus gain in the truth too, recorded as the emulator records it; within the brackets, the full
    exposure."""
    stamp = json.loads((walk / "camera_model.json").read_text())["recording"]["t0_ns"] + 60_000_000
    target = 4.0 * LONGEST_US
    ds = _variant(walk, tmp_path, {})
    gain_truth, cache = _image(ds, target, stamp, beyond="gain")
    as_variant, _ = _image(_variant(walk, tmp_path, {"exposure": False}), target, stamp)
    assert np.array_equal(gain_truth, as_variant)
    images = {e: np.zeros((100, 160), np.uint16) for e in (1000, 2000, 4000, LONGEST_US)}
    rec = cache.emulate(0, "left", images, target, source_us=SOURCE_US, times_ns={SOURCE_US: stamp})
    assert cache.emulator.exposure_and_gain(images, target) == (LONGEST_US, 4.0)
    assert rec.exposure_us == LONGEST_US and rec.gain_db == pytest.approx(20 * np.log10(4.0))
    within, _ = _image(ds, 4000.0, stamp, beyond="gain")
    t = cache.trigger_s(stamp, SOURCE_US)
    assert np.array_equal(within, cache.world.render("left", t, 4000.0))


def test_the_truth_of_a_method_that_sets_the_gain_is_its_exposure_amplified(walk: Path, tmp_path: Path) -> None:
    """A method that asked for 2 ms at 12 dB (4x: the target 8 ms, the longest bracket): the world's 2 ms frame (its
    blur, its noise) amplified 4x, recorded as 2 ms and 12 dB; the same target without a gain request is the full
    8 ms frame."""
    stamp = json.loads((walk / "camera_model.json").read_text())["recording"]["t0_ns"] + 60_000_000
    cache = TruthCache(EmulatorConfig(beyond="gain"), _variant(walk, tmp_path, {}))
    images = {e: np.zeros((100, 160), np.uint16) for e in (1000, 2000, 4000, LONGEST_US)}
    gain_db = 20 * np.log10(4.0)
    target = float(LONGEST_US)
    rec = cache.emulate(0, "left", images, target, source_us=SOURCE_US, times_ns={SOURCE_US: stamp},
                        gain_db=gain_db)
    assert rec.exposure_us == pytest.approx(2000.0) and rec.gain_db == pytest.approx(gain_db)
    t = cache.trigger_s(stamp, SOURCE_US)
    world, response = cache.world, cache.emulator.response
    raw = world.render("left", t, 2000.0, rng=world.frame_rng("left", t, target))
    expected = response.encode(response.icrf[raw].astype(np.float64) * 4.0, cache.emulator.rounding)
    assert np.array_equal(rec.image, expected)
    full = cache.emulate(0, "left", images, target, source_us=SOURCE_US, times_ns={SOURCE_US: stamp})
    assert full.exposure_us == target and full.gain_db == 0.0
    assert np.array_equal(full.image, world.render("left", t, target))
    assert not np.array_equal(full.image, rec.image)


def test_bad_truth_effects_are_one_line_errors(walk: Path, tmp_path: Path) -> None:
    for bad in ({"motion": False}, {"noise": "no"}):
        with pytest.raises(BracketryError, match="truth_effects"):
            truth_effects(_variant(walk, tmp_path, bad))


def test_the_command_names_the_same_effects() -> None:
    from bracketry_emulator.cli.accuracy import TRUTH_EFFECT_NAMES

    assert TRUTH_EFFECT_NAMES == TRUTH_EFFECTS
