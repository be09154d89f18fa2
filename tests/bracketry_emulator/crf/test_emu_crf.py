"""Camera response: pcalib loading (TUM and the authors' lifting), sRGB model vs the sample, ALS calibration with an
OpenCV Debevec cross-check, the calibrate-crf command."""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np
import pytest

from bracketry.cli import main
from bracketry_base.errors import BracketryError
from bracketry_emulator.crf import SrgbResponse, load_pcalib, load_response, save_pcalib
from bracketry_emulator.crf.calibrate import calibrate_response
from bracketry_emulator.dataset import open_dataset
from emu_synthetic import SRGB, radiance_map, render, write_tree


@pytest.mark.realdata
def test_emu_pcalib_upstream_lifting_knots(borealhdr_sample: Path) -> None:
    path = borealhdr_sample / "calibration" / "pcalib_inside1.txt"
    values = load_pcalib(path)
    assert values.shape == (256,) and values[0] == pytest.approx(0.17293, abs=1e-4) and values[-1] == 255.0
    up = load_response(path, lifting="upstream")
    # the notes' knots: DN -> irradiance
    for dn, irr in ((513.9, 41.9), (1027.8, 143.2), (2055.5, 586.9), (3083.3, 1430.7), (3854.1, 3073.0)):
        assert np.interp(dn, np.arange(4096), up.icrf) == pytest.approx(irr, abs=0.6)
    assert up.icrf[0] == 0.0 and up.icrf[4095] == 4095.0
    tum = load_response(path)
    assert tum.icrf[0] == 0.0 and tum.icrf[-1] == pytest.approx(4095.0)


@pytest.mark.realdata
def test_emu_srgb_code_set_matches_sample(borealhdr_sequence: Path) -> None:
    codes: set[int] = set()
    ds = open_dataset(borealhdr_sequence)
    for img in ds.sequences()[0].load("left").values():
        codes |= set(np.unique(img).tolist())
    used = set(SrgbResponse().used_codes.tolist())
    assert codes <= used  # every stored code is floor(4095 * OETF(k / 4095)) of some linear level k
    assert len(used) == 2920 and max(used) == 4094


def test_emu_pcalib_file_errors(tmp_path: Path) -> None:
    bad = tmp_path / "pcalib.txt"
    bad.write_text("1 2 3\n")
    with pytest.raises(BracketryError, match="256"):
        load_pcalib(bad)
    bad.write_text(" ".join(str(x) for x in np.linspace(255, 0, 256)))
    with pytest.raises(BracketryError, match="non-decreasing"):
        load_pcalib(bad)
    good = tmp_path / "good.txt"
    save_pcalib(good, SRGB.icrf)
    resp = load_response(good)
    np.testing.assert_allclose(resp.icrf, SRGB.icrf * 4095 / SRGB.icrf[-1], atol=1e-3)


def _stack(seed: int = 1) -> dict[int, list[np.ndarray]]:
    irr = radiance_map(120, 160, seed=seed)
    rng = np.random.default_rng(seed)
    return {e: [render(irr, e, rng)] for e in (250, 500, 1000, 2000, 4000, 8000, 16000, 32000)}


def test_emu_als_recovers_srgb_response() -> None:
    cal = calibrate_response(_stack())
    ref = SRGB.icrf * 4095 / SRGB.icrf[-1]
    used = SRGB.used_codes
    mask = cal.observed[used] & (ref[used] > 20)
    rel = np.abs(cal.icrf[used] - ref[used])[mask] / ref[used][mask]
    assert np.median(rel) < 0.03 and rel.max() < 0.08
    assert np.all(np.diff(cal.icrf) >= 0)
    assert cal.residual_rms[-1] < cal.residual_rms[0]


def test_emu_als_agrees_with_opencv_debevec_on_8bit() -> None:
    stack = _stack(seed=2)
    cal = calibrate_response(stack)
    exps = sorted(stack)
    imgs8 = [cv2.cvtColor((stack[e][0] >> 4).astype(np.uint8), cv2.COLOR_GRAY2BGR) for e in exps]
    times = np.array([e * 1e-6 for e in exps], dtype=np.float32)
    deb = cv2.createCalibrateDebevec(samples=200, lambda_=10.0, random=False).process(imgs8, times)[:, 0, 1]
    # compare the two inverse responses as shapes (both up to scale): normalise at 8-bit value 128
    codes8 = np.arange(40, 240)
    ours = np.interp(codes8 * 16 + 8, np.arange(4096), cal.icrf)
    ours /= np.interp(128 * 16 + 8, np.arange(4096), cal.icrf)
    theirs = deb[codes8] / deb[128]
    assert np.median(np.abs(ours - theirs) / theirs) < 0.10


def test_emu_calibrate_crf_command(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    irr = radiance_map(60, 80, seed=4)
    root = tmp_path / "stack"
    # a plain BorealHDR tree of a static scene with 3 frames per exposure (repeats)
    write_tree(root, irr, n_sequences=3, sides=("left",))
    out = tmp_path / "pcalib.txt"
    noise = tmp_path / "noise.json"
    assert main(["calibrate-crf", str(root), "--out", str(out), "--noise-out", str(noise)]) == 0
    assert load_pcalib(out).shape == (4096,)
    assert "read" in noise.read_text()
    assert main(["calibrate-crf", str(root), "--out", str(out)]) == 2  # exists, no --overwrite
    assert main(["calibrate-crf", str(root), "--out", str(tmp_path / "p256.txt"), "--levels", "256"]) == 0
    assert load_pcalib(tmp_path / "p256.txt").shape == (256,)
    assert main(["calibrate-crf", str(tmp_path / "nope"), "--out", str(tmp_path / "x.txt")]) == 2
    err = capsys.readouterr().err
    assert "exists" in err and "does not exist" in err and "Traceback" not in err


def test_emu_upstream_interpolation_equals_scipy_interp1d(borealhdr_sample: Path) -> None:
    """The authors' lifting is evaluated without scipy: the same values as their interp1d calls, bit for bit, and the
    same refusal of points outside the knots."""
    from scipy.interpolate import interp1d

    from bracketry_emulator.crf.response import LinearInterp

    pcalib = np.loadtxt(borealhdr_sample / "calibration" / "pcalib_inside1.txt").ravel()
    x = np.linspace(0, 4095, 256)
    y = 16.0 * pcalib
    y[0], y[-1] = 0.0, 4095.0
    rng = np.random.default_rng(0)
    unsorted = rng.permutation(256)
    for a, b in ((x, y), (y, x), (x[unsorted], y[unsorted])):
        ref, mine = interp1d(a, b, kind="linear", fill_value=(0, 4095)), LinearInterp(a, b)
        for q in (np.arange(4096), np.linspace(0, 4095, 4097), rng.uniform(0, 4095, (40, 30)).astype(np.float32),
                  np.array(17.5), np.array([4095.0, 0.0, np.nan])):
            got, want = mine(q), ref(q)
            assert got.dtype == want.dtype and got.shape == want.shape
            np.testing.assert_array_equal(got, want)
        for outside in (-0.5, 4095.5):
            with pytest.raises(ValueError):
                ref(np.array([outside]))
            with pytest.raises(ValueError):
                mine(np.array([outside]))
