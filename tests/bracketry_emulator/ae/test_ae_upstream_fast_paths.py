"""The upstream methods' fast paths (Zhang's compiled kernel and numpy fallback, Kim's per-value tables and code sums,
Shim's per-code tables and compiled gradients, the GP's direct LAPACK / L-BFGS-B calls) give the values of the
authors' formulas as written: bit for bit, Kim's code sums to float64 rounding."""

from __future__ import annotations

from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

import cv2
import numpy as np
import pytest
from scipy import signal
from upstream_formulas import fit_formula, neg_lml_formula, shim_scores_formula, zhang_weights_formula

from bracketry_emulator.ae import gp as GP
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
    return float(t_ms + 1e-6 * np.sum(zhang_weights_formula(terms.size) * terms))


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


def test_zhang_weights_equal_the_formula_bit_for_bit() -> None:
    for n in (2, 3, 7, 8, 100, 32768 * 5, 32768 * 5 + 1, 65536 * 3 + 17, 1920 * 1080, 1920 * 1200):
        got, want = U.upstream_zhang_weights(n), zhang_weights_formula(n)
        assert got.dtype == want.dtype == np.float32 and got.tobytes() == want.tobytes(), n
    with pytest.raises(ZeroDivisionError):  # one pixel: no ranks below the percentile, as the formula
        U.upstream_zhang_weights(1)


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


def test_compiled_weighted_sum_equals_numpys_sum_of_the_sorted_terms() -> None:
    z = U.UpstreamZhangAE()
    meta = {"response": None}
    rng = np.random.default_rng(11)
    for shape in [(1, 2), (2, 3), (3, 5), (9, 17), (33, 47), (120, 90)]:
        gray = rng.integers(0, 4096, shape).astype(np.uint16)
        gray[: shape[0] // 2] = gray[0, 0]  # flat rows: many equal terms
        for t_ms in (0.5, 8.0):
            got = z.weighted_sum(gray, t_ms, meta)
            want = np.sum(U.upstream_zhang_weights(gray.size) * np.sort(z._terms(gray, t_ms, meta)))
            assert isinstance(got, np.longdouble) and got == want, (shape, t_ms)


def _terms_of_jlut(gray: np.ndarray, jlut: np.ndarray) -> np.ndarray:
    """The numpy path's terms 2 (Ix Jx + Iy Jy) (long double, flat, unsorted) for J = jlut[gray]."""
    ix, iy = U.scharr_integer(gray)
    j = jlut[gray]
    jx = U.scharr_symm(j, U.UpstreamZhangAE._SCHARR_X)
    jy = U.scharr_symm(j, U.UpstreamZhangAE._SCHARR_Y)
    with np.errstate(invalid="ignore", over="ignore"):
        prod = np.multiply(ix, jx, dtype=np.longdouble)
        prod += np.multiply(iy, jy, dtype=np.longdouble)
        prod *= 2
    return prod.ravel()


def _same(a: np.ndarray, b: np.ndarray) -> bool:
    """Equal values (a zero's sign aside, as ``==``: the kernel's -0 terms are +0, which no sum can tell apart from
    -0 unless it is zero itself), NaN where NaN."""
    return bool(np.array_equal(a, b, equal_nan=True))


def test_compiled_bucket_sort_equals_numpy_on_large_and_degenerate_images() -> None:
    """Images large enough for the kernel's radix buckets and their splits (a smooth scene with noise, noise of a
    few codes, flat, steps), one after the other through its kept scratch memory (sizes up and down), and J tables
    with infinities and NaN: the sorted terms and the weighted sum are numpy's."""
    kernel = U._zhang_kernel()
    assert kernel is not None, "the _zhang_terms extension was not built (setup.sh builds it)"
    rng = np.random.default_rng(12)
    yy, xx = np.mgrid[0:300, 0:420]
    scene = 2000 + 1500 * np.sin(xx / 37.0) * np.cos(yy / 23.0) + rng.normal(0, 30, xx.shape)
    steps = np.where(xx < 210, 1000, 3000) + np.where(yy < 150, 0, 77)
    cases = [np.clip(scene, 0, 4095), rng.integers(1000, 1004, (64, 512)), np.full((50, 60), 7), steps,
             np.clip(scene[:90, :70], 0, 4095), rng.integers(0, 4096, (250, 333))]
    slope = 0.5 + np.abs(np.sin(np.arange(65536) / 300.0))
    for i, img in enumerate(cases):
        gray = np.ascontiguousarray(img, dtype=np.uint16)
        for t_ms in (0.7, 9.0):
            jlut = 1.0 / (slope * t_ms)
            if i == 3:
                jlut = jlut.copy()
                jlut[1000], jlut[3077] = np.inf, np.nan  # infinite / NaN terms: numpy sorts NaN last
            want = np.sort(_terms_of_jlut(gray, jlut))
            got = np.empty(gray.size, dtype=np.longdouble)
            kernel.sorted_terms(gray, jlut, gray.shape[0], gray.shape[1], got)
            assert _same(got, want), (i, t_ms)
            w = U.upstream_zhang_weights(gray.size)
            total = np.empty(1, dtype=np.longdouble)
            kernel.weighted_sum(gray, jlut, gray.shape[0], gray.shape[1], w, total)
            with np.errstate(invalid="ignore"):
                assert _same(total, np.array([np.sum(w * want)])), (i, t_ms)


def test_compiled_weighted_sum_from_two_threads_at_once() -> None:
    """Two threads in the kernel at the same time (it releases the GIL; one of them takes the kept scratch memory,
    the other its own): each result is the one computed alone."""
    z = U.UpstreamZhangAE()
    meta = {"response": None}
    rng = np.random.default_rng(13)
    grays = [rng.integers(0, 4096, (240, 320)).astype(np.uint16) for _ in range(4)]
    alone = [z.weighted_sum(g, 4.0, meta) for g in grays]
    with ThreadPoolExecutor(2) as pool:
        for _ in range(3):
            together = list(pool.map(lambda g: z.weighted_sum(g, 4.0, meta), grays))
            assert together == alone


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


def _sample_grays(borealhdr_sample: Path, borealhdr_sequence: Path, exposures_us: tuple[float, ...]
                  ) -> list[np.ndarray]:
    pcalib = borealhdr_sample / "calibration" / "pcalib_inside1.txt"
    emu = Emulator(EmulatorConfig(selection="upstream", parity="upstream", crf=str(pcalib)))
    brackets = open_dataset(borealhdr_sequence).sequences()[0].load("left")
    return [bayer_gray(emu.emulate(brackets, t_us).image) for t_us in exposures_us]


@pytest.mark.realdata
def test_kim_metric_tables_and_code_sums_equal_the_per_pixel_formula(borealhdr_sample: Path,
                                                                      borealhdr_sequence: Path) -> None:
    grays = _sample_grays(borealhdr_sample, borealhdr_sequence, (1500.0, 8000.0, 30000.0))
    rng = np.random.default_rng(1)
    grays += [rng.integers(0, high, (37, 51)).astype(np.uint16) for high in (2, 300, 4096)]
    for i, gray in enumerate(grays):
        direct = U._upstream_kim_metric_direct(gray, 16.0, 4.0, 0.6)
        exact, fast = U.upstream_kim_metric_exact(gray), U.upstream_kim_metric(gray)
        if i == 3:  # one 8-bit value, a constant entropy: NaN (0/0) in all three
            assert np.isnan(direct) and np.isnan(exact) and np.isnan(fast)
            continue
        assert exact == direct, i  # per-value tables: bit for bit
        assert fast == pytest.approx(direct, rel=1e-12, abs=0), i  # per-value sums: float64 rounding


def test_kim_code_sums_kernel_equals_opencv() -> None:
    kernels = U._upstream_kernels()
    assert kernels is not None, "the _upstream_kernels extension was not built (setup.sh builds it)"
    rng = np.random.default_rng(2)
    for shape in [(2, 2), (3, 7), (40, 33)]:
        gray = rng.integers(0, 4096, shape).astype(np.uint16)
        img = (gray >> 4).astype(np.uint8)
        gx = cv2.Sobel(img, ddepth=cv2.CV_16U, dx=1, dy=0, ksize=3).ravel()
        gy = cv2.Sobel(img, ddepth=cv2.CV_16U, dx=0, dy=1, ksize=3).ravel()
        g = gx**2 + gy**2  # uint16: wraps
        counts, sums = np.empty(256, np.int64), np.empty(256, np.int64)
        assert kernels.kim_code_sums(gray, shape[0], shape[1], counts, sums) == 0
        assert np.array_equal(counts, np.bincount(img.ravel(), minlength=256))
        assert np.array_equal(sums, np.bincount(img.ravel(), weights=g, minlength=256).astype(np.int64))
    over = np.full((3, 3), 4096, np.uint16)
    assert kernels.kim_code_sums(over, 3, 3, counts, sums) == -1  # not 12-bit: the caller uses the formula


@pytest.mark.realdata
def test_shim_scores_equal_the_per_pixel_formula(borealhdr_sample: Path, borealhdr_sequence: Path) -> None:
    grays = _sample_grays(borealhdr_sample, borealhdr_sequence, (1500.0, 8000.0, 30000.0))
    rng = np.random.default_rng(4)
    grays += [rng.integers(0, 4096, (2, 2)).astype(np.uint16), rng.integers(100, 104, (31, 17)).astype(np.uint16),
              np.minimum(rng.integers(0, 4096, (64, 80)), 4095).astype(np.uint16)]
    for i, gray in enumerate(grays):
        got, want = U.upstream_shim_scores(gray), shim_scores_formula(gray)
        assert [type(v) for v in got] == [type(v) for v in want]
        assert [v.tobytes() for v in got] == [v.tobytes() for v in want], i
    flat = np.full((5, 6), 700, np.uint16)  # hi == lo: the formula (NaN image, zero scores)
    with np.errstate(divide="ignore", invalid="ignore"):
        assert [v.tobytes() for v in U.upstream_shim_scores(flat)] == [v.tobytes() for v in shim_scores_formula(flat)]


def test_shim_gradient_kernel_rounds_as_opencv() -> None:
    """CV_16U Sobel of a float64 image: the kernel's gradients equal cv2.Sobel's on values where the order of the
    float64 operations and the rounding of halves decide (dyadic values, values a few ulps off halves)."""
    kernels = U._upstream_kernels()
    assert kernels is not None
    rng = np.random.default_rng(6)
    for trial in range(40):
        n_codes = 64
        if trial % 2:
            table = rng.integers(0, 17, n_codes) / 16.0
        else:
            table = np.clip(rng.integers(0, 9, n_codes) / 8.0 + rng.choice([0, 1e-16, -1e-16, 2.2e-16], n_codes), 0, 1)
        h, w = (int(v) for v in rng.integers(2, 30, 2))
        gray = rng.integers(0, n_codes, (h, w)).astype(np.uint16)
        img = table[gray]
        gx = cv2.Sobel(img, ddepth=cv2.CV_16U, dx=1, dy=0, ksize=3)
        gy = cv2.Sobel(img, ddepth=cv2.CV_16U, dx=0, dy=1, ksize=3)
        out = np.empty((h, w), np.uint8)
        status, m2_min, m2_max = kernels.shim_buckets(gray, table, h, w, out)
        assert status == 0
        assert np.array_equal(out // 6, gx) and np.array_equal(out % 6, gy), trial
        m2 = gx.astype(int) ** 2 + gy.astype(int) ** 2
        assert (m2_min, m2_max) == (m2.min(), m2.max())
    gray = np.array([[0, 0, 1], [0, 0, 1], [0, 0, 1]], np.uint16)
    assert kernels.shim_buckets(gray, np.array([0.0, 2.0]), 3, 3, np.empty((3, 3), np.uint8))[0] == 1  # above 4
    assert kernels.shim_buckets(gray, np.array([0.0]), 3, 3, np.empty((3, 3), np.uint8))[0] == -1  # not in table


def test_shim_sparse_path_equals_every_pixel() -> None:
    """The candidates (pixels whose gradients can round above 0 for some table) and the gradients computed there
    only: the same buckets and (min, max) as every pixel computed, for gammas and for tables that are not monotone;
    edges of just over 1/8 of the range (gradient 4 x 0.14 > 0.5) must be candidates."""
    kernels = U._upstream_kernels()
    assert kernels is not None
    rng = np.random.default_rng(14)
    yy, xx = np.mgrid[0:61, 0:83]
    images = [np.where(xx < 40, 1000, 1000 + 0.14 * 3000) + 0 * yy,  # a vertical step just over 1/8
              np.where(yy < 30, 1000, 1000 + 0.14 * 3000) + 0 * xx,  # a horizontal one
              2000 + 900 * np.sin(xx / 9.0) * np.cos(yy / 7.0) + rng.normal(0, 25, xx.shape),
              rng.integers(0, 4096, (2, 3)), np.where(rng.random((40, 50)) < 0.02, 4000, 100),
              np.where(xx < 40, 1000, 1005) + 0 * yy]  # a step of 5 codes: large only where the table jumps
    for i, img in enumerate(images):
        gray = np.clip(img, 0, 4095).astype(np.uint16)
        gray[0, 0], gray[-1, -1] = 1000, 4000  # one range for all
        lo, hi = int(gray.min()), int(gray.max())
        t01 = (np.maximum(np.arange(hi + 1), lo) - lo) / (hi - lo)
        tables = [np.ascontiguousarray(t01**g) for g in U.SHIM_GAMMAS_UPSTREAM]
        wobbly = np.clip(t01 + rng.choice([0.0, 0.01, -0.01], t01.size), 0, 1)
        wobbly[1005] = 0.9  # not monotone: bounded by the running maximum
        tables.append(np.ascontiguousarray(wobbly))
        idx = np.empty(gray.size, np.int32)
        count = kernels.shim_candidates(gray, U._shim_partner_codes(tables), *gray.shape, idx)
        assert 0 < count <= gray.size, i
        for k, table in enumerate(tables):
            full, sparse = np.empty(gray.shape, np.uint8), np.zeros(gray.shape, np.uint8)
            want = kernels.shim_buckets(gray, table, *gray.shape, full)
            assert kernels.shim_sparse(gray, table, *gray.shape, idx, count, sparse) == want, (i, k)
            assert np.array_equal(sparse, full), (i, k)
            if i < 2 and k == 3:  # gamma 1: the steps give gradients on both sides of the edge
                edge = full[1:-1, 39:41] if i == 0 else full[29:31, 1:-1]
                assert np.all(edge > 0), i
            if i == 5 and k == len(tables) - 1:
                assert np.all(full[1:-1, 39:41] > 0)
    assert kernels.shim_candidates(np.full((3, 3), 9, np.uint16), np.zeros(5, np.int32), 3, 3, idx[:9]) == -1


def test_shim_sum_is_numpys_pairwise_sum() -> None:
    kernels = U._upstream_kernels()
    assert kernels is not None
    rng = np.random.default_rng(8)
    for n in (1, 7, 8, 9, 127, 128, 129, 1000, 4099, 100_003, 2_304_000):
        values = (rng.random(256) * rng.choice([1.0, 1e3, 1e-3], 256)).astype(np.float32)
        for zeros in (False, True):
            if zeros:
                values[0] = 0.0
                codes = np.where(rng.random(n) < 0.97, 0, rng.integers(1, 36, n)).astype(np.uint8)
            else:
                codes = rng.integers(0, 256, n).astype(np.uint8)
            got = np.float32(kernels.shim_sum(codes, values))
            assert got.tobytes() == np.sum(values[codes]).tobytes(), (n, zeros)


# --- Kim's GP: the fit as formulated with scipy.linalg and scipy.optimize.minimize --------------------------------


def _gp_problems() -> list[tuple[np.ndarray, np.ndarray]]:
    rng = np.random.default_rng(9)
    problems = [(np.array([4.0]), np.array([1200.0])),  # Kim's first step
                (np.array([4.0, 4.0, 6.2]), np.array([900.0, 905.0, 1500.0])),  # a repeated exposure
                (np.array([0.5, 35.0]), np.array([0.0, 0.0]))]  # zero targets
    for n in (2, 3, 4, 5, 5, 5):
        problems.append((rng.uniform(0.5, 35.0, n), rng.uniform(300.0, 15000.0, n)))
    return problems


def test_gp_objective_equals_the_formula_bit_for_bit() -> None:
    rng = np.random.default_rng(10)
    for x, y in _gp_problems():
        obj = GP._Objective(x, y, 0.2)
        for theta in [np.zeros(2), np.array(GP.LOG_BOUNDS), np.array(GP.LOG_BOUNDS[::-1]),
                      *rng.uniform(*GP.LOG_BOUNDS, (6, 2))]:
            f, g = obj(theta)
            f_ref, g_ref = neg_lml_formula(theta, x, y, 0.2)
            assert f == f_ref and np.array_equal(g, g_ref), (x, theta)


def test_gp_fit_equals_minimize_on_the_formula_bit_for_bit() -> None:
    GP._minimizer()
    assert GP._Minimizer._checked, "scipy's L-BFGS-B routine is not driven directly (another scipy?)"
    for i, (x, y) in enumerate(_gp_problems()):
        gp = GP.GaussianProcess1D(0.2, 10, np.random.default_rng(i)).fit(x, y)
        assert np.array_equal(gp.log_theta, fit_formula(x, y, 0.2, np.random.default_rng(i))), i
