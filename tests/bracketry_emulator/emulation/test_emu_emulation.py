"""Emulation: upstream parity (bit-exact), default rounding, selection rules, fusion, gain, RunWriter layout."""

from __future__ import annotations

import csv
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from bracketry_base.errors import BracketryError
from bracketry_emulator.crf import load_pcalib, srgb_eotf
from bracketry_emulator.dataset import open_dataset, read_png12
from bracketry_emulator.emulation import (
    Emulator,
    EmulatorConfig,
    RunWriter,
    apply_lut,
    kernel,
    select_highernosat,
    select_upstream,
)
from bracketry_emulator.emulation.reference import UpstreamFormula, closer_least_sat, upstream_saturation
from bracketry_emulator.extensions import extensions_disabled
from emu_synthetic import BRACKETS_US, SRGB, radiance_map, render, write_tree


@pytest.mark.realdata
def test_emu_parity_upstream_bit_exact_on_sample(borealhdr_sample: Path) -> None:
    pcalib_path = borealhdr_sample / "calibration" / "pcalib_inside1.txt"
    ref = UpstreamFormula(load_pcalib(pcalib_path))
    ds = open_dataset(borealhdr_sample)
    imgs = ds.sequences()[0].load("left")
    emu = Emulator(EmulatorConfig(selection="upstream", crf=pcalib_path, parity="upstream"))
    crop = {e: i[:300, :400] for e, i in imgs.items()}
    sats = [upstream_saturation(crop[e]) for e in sorted(crop)]
    for target_ms in (0.5, 1.0, 3.0, 6.0, 8.0, 12.5, 20.0, 32.0, 45.0):
        out = emu.emulate(crop, target_ms * 1000)
        src_ms = closer_least_sat([e / 1000 for e in sorted(crop)], sats, target_ms)
        assert out.source_exposure_us == round(src_ms * 1000)
        expected = ref.radiance_emulation(crop[out.source_exposure_us], target_ms, src_ms)
        np.testing.assert_array_equal(out.image, expected)
    # the whole code range, including the f = 1 round-trip quirk (45 codes come out 1 DN lower)
    codes = np.arange(4096, dtype=np.uint16).reshape(64, 64)
    same = emu.emulate({8000: codes}, 8000.0).image
    np.testing.assert_array_equal(same, ref.radiance_emulation(codes, 8.0, 8.0))
    assert int(np.count_nonzero(same != codes)) == 45


def test_emu_default_rounds_and_keeps_code_set() -> None:
    codes = SRGB.used_codes.astype(np.uint16)[None, :]
    emu = Emulator(EmulatorConfig())
    out = emu.emulate({4000: codes}, 4000.0).image
    np.testing.assert_array_equal(out, codes)  # f = 1 is the identity on the camera's codes
    half = emu.emulate({4000: codes}, 2000.0).image
    assert set(np.unique(half)) <= set(SRGB.used_codes.tolist())
    assert int(half.max()) <= 4094
    # the mean linear level is preserved by rounding (no truncation bias)
    assert abs(SRGB.icrf[half].mean() - 0.5 * SRGB.icrf[codes].mean()) < 0.05


def test_emu_apply_lut_matches_fancy_indexing() -> None:
    rng = np.random.default_rng(1)
    img = rng.integers(0, 4096, size=(1200, 1920), dtype=np.uint16)
    lut = rng.integers(0, 4096, size=4096, dtype=np.uint16)
    np.testing.assert_array_equal(apply_lut(lut, img), lut[img])
    np.testing.assert_array_equal(apply_lut(lut, img[:5, :7], threads=False), lut[img[:5, :7]])
    # the gather extension is built with the package (setup.sh's install), not compiled at run time
    gather = kernel.c_kernel()
    assert gather is not None and gather.__module__ == "bracketry_emulator.emulation._lut12"
    out = np.zeros_like(img)
    gather(lut, img, out)
    np.testing.assert_array_equal(out, lut[img])
    with pytest.raises(ValueError, match="4096"):
        gather(lut[:100], img, out)
    with pytest.raises(ValueError, match="same size"):
        gather(lut, img, out[:10])
    with extensions_disabled():  # the numpy fallback gives the same result
        assert kernel.c_kernel() is None
        np.testing.assert_array_equal(apply_lut(lut, img), lut[img])
        np.testing.assert_array_equal(apply_lut(lut, img[::3, ::2]), lut[img[::3, ::2]])
    assert kernel.c_kernel() is gather


def test_emu_saturation_fraction_compiled_counts_equal_numpy() -> None:
    """The compiled one-pass counts (pixels at or above the code, pixels at 0; blocks of 32768) give numpy's
    fractions, for both counts, sizes around the blocks, any code; other dtypes and views take numpy's path."""
    from bracketry_emulator.emulation import saturation_fraction

    counts = kernel.code_counts()
    assert counts is not None
    rng = np.random.default_rng(21)
    for n in (1, 7, 32767, 32768, 32769, 70001, 1200 * 1920):
        img = rng.integers(0, 4096, n).astype(np.uint16)
        img[::5], img[::13] = 0, 4094
        for code in (0, 1, 4094, 4095):
            want_at, want_zero = np.count_nonzero(img >= code), np.count_nonzero(img == 0)
            assert counts(img, code) == (want_at, want_zero), (n, code)
            assert saturation_fraction(img, code) == want_at / n
            assert saturation_fraction(img, code, "both") == (want_at + want_zero) / n
    img = rng.integers(0, 4096, (120, 160)).astype(np.uint16)
    img[:10] = 4095
    want = saturation_fraction(img, 4094, "both")
    with extensions_disabled():
        assert kernel.code_counts() is None and saturation_fraction(img, 4094, "both") == want
    assert saturation_fraction(img[:, ::2], 4094, "both") == saturation_fraction(img[:, ::2].copy(), 4094, "both")
    assert saturation_fraction(img.astype(np.int32), 4094) == saturation_fraction(img, 4094)


def test_emu_gather_needs_no_compiler_and_writes_no_cache(tmp_path: Path) -> None:
    """A fresh process with no compiler on PATH and an empty cache folder uses the built gather, writing nothing."""
    cache = tmp_path / "cache"
    cache.mkdir()
    code = ("import numpy as np; from bracketry_emulator.emulation import kernel, apply_lut; "
            "lut = np.arange(4096, dtype=np.uint16)[::-1].copy(); img = np.arange(4096, dtype=np.uint16); "
            "assert kernel.c_kernel() is not None; assert (apply_lut(lut, img) == lut[img]).all()")
    env = {"PATH": str(tmp_path), "HOME": str(tmp_path), "XDG_CACHE_HOME": str(cache), "CC": "/nonexistent/cc",
           "PYTHONPATH": os.pathsep.join(sys.path)}
    done = subprocess.run([sys.executable, "-c", code], env=env, capture_output=True, text=True, timeout=120)
    assert done.returncode == 0, done.stderr
    assert list(cache.iterdir()) == []


def test_emu_highernosat_rule() -> None:
    exps = list(BRACKETS_US)
    sat = dict.fromkeys(exps, 0.0)
    assert select_highernosat(exps, 6000, sat) == 8000  # higher bracket, scaled down
    assert select_highernosat(exps, 8000, sat) == 8000  # exact
    assert select_highernosat(exps, 500, sat) == 1000  # below the range: nearest
    assert select_highernosat(exps, 50000, sat) == 32000  # above the range: nearest
    sat[32000] = 0.02
    assert select_highernosat(exps, 20000, sat) == 16000  # higher is over-saturated beyond alpha
    assert select_highernosat(exps, 20000, sat, alpha=0.05) == 32000
    both = {1000: 0.08, 2000: 0.04, 4000: 0.02, 8000: 0.01, 16000: 0.005, 32000: 0.03}
    assert select_upstream(exps, 20000, both) == 16000
    assert select_upstream(exps, 3000, both) == 4000
    assert select_upstream(exps, 64000, both) == 32000


def test_emu_fusion_beats_single_bracket_on_static_stack() -> None:
    irr = radiance_map(96, 128, seed=3)
    rng = np.random.default_rng(7)
    imgs = {e: render(irr, e, rng) for e in BRACKETS_US}
    errs: dict[str, list[float]] = {"highernosat": [], "fusion": []}
    for target in (1500.0, 3000.0, 6000.0, 12000.0, 24000.0):
        truth = render(irr, target).astype(float)
        for sel in errs:
            out = Emulator(EmulatorConfig(selection=sel)).emulate(imgs, target)
            errs[sel].append(float(np.sqrt(np.mean((out.image - truth) ** 2))))
    assert all(f <= h + 1e-9 for f, h in zip(errs["fusion"], errs["highernosat"], strict=True))
    assert np.median(errs["fusion"]) < 0.8 * np.median(errs["highernosat"])


def test_emu_gain_emulation_matches_noise_model() -> None:
    irr = np.full((200, 200), 0.25)  # 1000 DN at 4 ms
    rng = np.random.default_rng(2)
    imgs = {e: render(irr, e, rng) for e in BRACKETS_US}
    emu = Emulator(EmulatorConfig(gain_db=6.0, seed=5))
    out = emu.emulate(imgs, 2000.0)  # 2 ms at +6 dB ~ same mean as 4 ms at 0 dB
    lin = SRGB.icrf[out.image]
    assert abs(lin.mean() - 0.25 * 2000 * 10 ** (6 / 20)) < 15
    expected_std = 10 ** (6 / 20) * np.sqrt(1.0 + 0.4 * 500)
    assert abs(lin.std() - expected_std) / expected_std < 0.15
    again = emu.emulate(imgs, 2000.0)
    np.testing.assert_array_equal(out.image, again.image)  # deterministic


def test_emu_config_errors() -> None:
    with pytest.raises(BracketryError, match="unknown selection"):
        Emulator(EmulatorConfig(selection="closest"))  # type: ignore[arg-type]
    with pytest.raises(BracketryError, match="positive"):
        Emulator().emulate({1000: np.zeros((2, 2), np.uint16)}, -1.0)
    with pytest.raises(BracketryError, match="pcalib file not found"):
        Emulator(EmulatorConfig(crf="/nonexistent/pcalib.txt"))


def test_emu_run_writer_layout(tmp_path: Path) -> None:
    root = write_tree(tmp_path / "rec", 0.05 * radiance_map(16, 24), n_sequences=2)
    ds = open_dataset(root)
    emu = Emulator(EmulatorConfig(selection="fusion"))
    out = tmp_path / "out"
    with RunWriter(out, "constant-6", ds.sides) as writer:
        for step, seq in enumerate(ds.sequences()):
            writer.write_step(step, seq, emu.emulate_sequence(seq, 6000.0), 6000.0)
    run = out / "constant-6"
    lines = (run / "times_images_left.txt").read_text().splitlines()
    assert len(lines) == 2
    name, ts, target_ms = lines[0].split()
    assert name == ts and float(target_ms) == 6.0
    assert int(ts) == ds.sequences()[0].timestamps_ns["left"][8000]  # the reference (HigherNoSat) bracket
    img = read_png12(run / "images_right" / f"{ts}.png")
    assert img.shape == (16, 24)
    rows = list(csv.DictReader((run / "steps.csv").open()))
    assert [r["step"] for r in rows] == ["0", "1"]
    assert rows[0]["selection"] == "fusion" and float(rows[0]["source_exposure_ms"]) == 8.0
    assert float(rows[0]["factor"]) == pytest.approx(0.75)
    with pytest.raises(BracketryError, match="already holds a run"):
        RunWriter(out, "constant-6", ds.sides)


def test_emu_noise_model_calibration_and_loading(tmp_path: Path) -> None:
    from bracketry_emulator.emulation import NoiseModel, calibrate_noise

    irr = radiance_map(80, 120, seed=5) * 0.2
    rng = np.random.default_rng(3)
    repeats = {e: [render(irr, e, rng, read_dn=1.5, dn_per_e=0.2) for _ in range(8)] for e in (2000, 8000)}
    model = calibrate_noise(repeats, SRGB)
    assert model.read_dn == pytest.approx(1.5, abs=0.3)
    assert model.dn_per_e == pytest.approx(0.2, rel=0.15)
    cam = tmp_path / "camera_model.json"
    cam.write_text('{"read_noise_e": 7.0, "gain_e_per_dn": 7.0}')
    assert NoiseModel.from_json(cam) == NoiseModel(read_dn=1.0, dn_per_e=1 / 7.0)


def test_emu_motion_estimate_and_warp_conventions() -> None:
    from bracketry_emulator.emulation import estimate_motion, warp_mosaic

    rng = np.random.default_rng(4)
    base = cv2_blur(rng.random((240, 320)) * 100 + 5)
    ref = base[20:220, 20:300]
    moving = base[24:224, 26:306]  # the scene moved by (-6, -4): ref (x, y) is at moving (x - 6, y - 4)
    h = estimate_motion(moving, ref, "translation")
    assert h[0, 2] == pytest.approx(-6, abs=0.3) and h[1, 2] == pytest.approx(-4, abs=0.3)
    inner = (slice(12, -12), slice(12, -12))
    assert np.nanmax(np.abs(warp_mosaic(moving, h)[inner] - ref[inner])) < 3.0
    hh = estimate_motion(moving, ref, "homography")
    unaligned = np.mean(np.abs(moving[inner] - ref[inner]))
    assert np.nanmean(np.abs(warp_mosaic(moving, hh)[inner] - ref[inner])) < 0.2 * unaligned


def cv2_blur(x: np.ndarray) -> np.ndarray:
    import cv2

    return cv2.GaussianBlur(x.astype(np.float32), (0, 0), 2.0)


def test_emu_fusion_motion_compensation_removes_ghosting() -> None:
    irr_big = 0.02 * radiance_map(220, 300, seed=8)
    irr_big = cv2_blur(irr_big).astype(np.float64) + 0.01
    ref_view = irr_big[10:210, 10:290]
    shifted = irr_big[14:214, 18:298]  # the 4 ms bracket sees the scene moved by 8 px in x, 4 px in y
    imgs = {2000: render(ref_view, 2000), 4000: render(shifted, 4000)}
    truth = render(ref_view, 3000).astype(float)
    errs = {}
    for motion in ("none", "translation", "homography"):
        emu = Emulator(EmulatorConfig(selection="fusion", motion=motion, alpha=1.0))
        out = emu.emulate(imgs, 3000.0)
        assert out.source_exposure_us == 4000  # HigherNoSat reference: the fused image has its geometry
        errs[motion] = float(np.sqrt(np.mean((out.image.astype(float) - render(shifted, 3000)) ** 2)))
    assert errs["translation"] < 0.5 * errs["none"]
    assert errs["homography"] < 0.5 * errs["none"]
    assert truth.shape == out.image.shape


def test_emu_fusion_unbiased_near_black() -> None:
    # a flat dark field: 1.5 linear levels at 1 ms (codes 0, 12, 25, 38 ...), 3 at 2 ms
    irr = np.full((300, 300), 0.0015)
    rng = np.random.default_rng(11)
    imgs = {e: render(irr, e, rng) for e in BRACKETS_US}
    for target in (1500.0, 3000.0, 12000.0):
        for brackets in ("bounding", "longer"):
            emu = Emulator(EmulatorConfig(selection="fusion", fusion_brackets=brackets))
            out = emu.emulate(imgs, target)
            fused = emu._fusion_cache[-1][2].irradiance
            assert fused.mean() * target == pytest.approx(0.0015 * target, rel=0.03, abs=0.05)
            if brackets == "bounding":  # noisy enough to dither the coarse dark codes: their mean is unbiased too
                assert SRGB.icrf[out.image].mean() == pytest.approx(0.0015 * target, rel=0.03, abs=0.05)
            else:  # little noise left to dither the codes: the image mean is off by the rounding, < 0.5 level
                assert abs(SRGB.icrf[out.image].mean() - 0.0015 * target) < 0.5
    # the continuous sRGB inverse reads every dark code ~0.05 level low (floor encoding): the bin means do not
    cont = 4095 * srgb_eotf(imgs[2000] / 4095.0)
    assert SRGB.icrf[imgs[2000]].mean() - cont.mean() > 0.04


def test_emu_fusion_deghost_keeps_reference_where_brackets_disagree() -> None:
    irr = np.full((40, 40), 0.05)
    imgs = {2000: render(irr, 2000), 4000: render(irr, 4000)}
    moved = imgs[2000].copy()
    moved[:, :20] = render(irr * 3, 2000)[:, :20]  # an object moved into the left half of the 2 ms bracket only
    imgs[2000] = moved
    plain = Emulator(EmulatorConfig(selection="fusion")).emulate(imgs, 3000.0)
    dg = Emulator(EmulatorConfig(selection="fusion", deghost_sigma=4.0)).emulate(imgs, 3000.0)
    truth = render(irr, 3000)  # the reference (HigherNoSat: 4 ms) view
    assert plain.source_exposure_us == 4000
    assert np.array_equal(dg.image, truth)
    assert not np.array_equal(plain.image[:, :20], truth[:, :20])
