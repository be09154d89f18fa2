"""The upstream methods' fast paths (Zhang's compiled kernel and numpy fallback, Kim's per-value tables) give exactly
the values of the authors' formulas as written."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from scipy import signal

from bracketry_emulator.ae import upstream as U
from bracketry_emulator.ae.base import bayer_gray
from bracketry_emulator.dataset import open_dataset
from bracketry_emulator.emulation import Emulator, EmulatorConfig


def reference_next_ms(gray: np.ndarray, t_ms: float, spline: object) -> float:
    """The authors' formula as written (scipy convolve2d, long double, np.sort), for the gradient branch."""
    kx = np.array([[3, 0, -3], [10, 0, -10], [3, 0, -3]], dtype=np.float32)
    ky = np.array([[3, 10, 3], [0, 0, 0], [-3, -10, -3]], dtype=np.float32)

    def grad(img: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        gx = signal.convolve2d(img, kx, boundary="symm", mode="same")
        gy = signal.convolve2d(img, ky, boundary="symm", mode="same")
        return np.asarray(gx, dtype=np.longdouble), np.asarray(gy, dtype=np.longdouble)

    ix, iy = grad(gray)
    jx, jy = grad(1.0 / (spline(gray) * t_ms))  # type: ignore[operator]
    terms = np.sort((2 * ((ix * jx) + (iy * jy))).ravel())
    return float(t_ms + 1e-6 * np.sum(U.upstream_zhang_weights(terms.size) * terms))


def test_scharr_symm_is_convolve2d_bit_for_bit() -> None:
    rng = np.random.default_rng(3)
    img = 1.0 / (rng.random((37, 53)) * 7 + 0.01)
    for k in (U.UpstreamZhangAE._SCHARR_X, U.UpstreamZhangAE._SCHARR_Y):
        ref = signal.convolve2d(img, k.astype(np.float32), boundary="symm", mode="same")
        assert np.array_equal(U.scharr_symm(img, k), ref)
    codes = rng.integers(0, 4096, (29, 31)).astype(np.uint16)
    gx, gy = U.scharr_integer(codes)
    assert np.array_equal(gx, signal.convolve2d(codes, U.UpstreamZhangAE._SCHARR_X, boundary="symm", mode="same"))
    assert np.array_equal(gy, signal.convolve2d(codes, U.UpstreamZhangAE._SCHARR_Y, boundary="symm", mode="same"))


def test_sort_longdouble_equals_np_sort_with_ties_below_float64() -> None:
    rng = np.random.default_rng(5)
    base = rng.normal(size=2000).astype(np.longdouble)
    eps = np.finfo(np.float64).eps
    # long doubles that round to the same float64 but differ, in shuffled order
    vals = np.concatenate([base, base * (1 + np.longdouble(eps) / 8), base * (1 - np.longdouble(eps) / 8), base])
    rng.shuffle(vals)
    got = U.sort_longdouble(vals)
    assert np.array_equal(got, np.sort(vals))
    hi = got.astype(np.float64)
    assert np.count_nonzero((hi[1:] == hi[:-1]) & (got[1:] != got[:-1])) > 1000  # the ties were there to sort


def test_compiled_kernel_is_built_and_equals_numpy() -> None:
    assert U._zhang_kernel() is not None, "the _zhang_terms extension was not built (setup.sh builds it)"
    z = U.UpstreamZhangAE()
    meta = {"response": None}
    rng = np.random.default_rng(7)
    for shape in [(1, 1), (1, 6), (2, 2), (5, 3), (33, 47)]:
        gray = rng.integers(0, 4096, shape).astype(np.uint16)
        for t_ms in (0.5, 8.0):
            c = z.sorted_terms(gray, t_ms, meta)
            ref = np.sort(z._terms(gray, t_ms, meta))
            assert np.array_equal(c, ref), (shape, t_ms)


@pytest.mark.realdata
def test_zhang_equals_the_formula_as_written_on_the_sample(borealhdr_sample: Path, borealhdr_sequence: Path) -> None:
    pcalib = borealhdr_sample / "calibration" / "pcalib_inside1.txt"
    emu = Emulator(EmulatorConfig(selection="upstream", parity="upstream", crf=str(pcalib)))
    img = emu.emulate(open_dataset(borealhdr_sequence).sequences()[0].load("left"), 8000.0).image
    gray = bayer_gray(img)
    meta = {"response": emu.response}
    z = U.UpstreamZhangAE()
    mean = float(np.mean(gray))
    assert (70 / 256) * 4096 < mean < (190 / 256) * 4096  # the gradient branch
    want = reference_next_ms(gray, 8.0, z._icrf_slope(meta)) * 1000.0
    assert z.next_exposure_us(img, 8000.0, meta) == want


@pytest.mark.realdata
def test_kim_metric_tables_equal_the_per_pixel_formula(borealhdr_sample: Path, borealhdr_sequence: Path) -> None:
    pcalib = borealhdr_sample / "calibration" / "pcalib_inside1.txt"
    emu = Emulator(EmulatorConfig(selection="upstream", parity="upstream", crf=str(pcalib)))
    brackets = open_dataset(borealhdr_sequence).sequences()[0].load("left")
    for t_us in (1500.0, 8000.0, 30000.0):
        gray = bayer_gray(emu.emulate(brackets, t_us).image)
        assert U.upstream_kim_metric(gray) == U._upstream_kim_metric_direct(gray, 16.0, 4.0, 0.6), t_us
    rng = np.random.default_rng(1)
    for high in (2, 300, 4096):  # 2: one 8-bit value, a constant entropy: NaN (0/0) in both
        gray = rng.integers(0, high, (37, 51)).astype(np.uint16)
        fast, direct = U.upstream_kim_metric(gray), U._upstream_kim_metric_direct(gray, 16.0, 4.0, 0.6)
        assert fast == direct or (high == 2 and np.isnan(fast) and np.isnan(direct)), high
