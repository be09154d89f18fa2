"""The monitor's pure core and the bracket advisor on constructed scenes with known dynamic range."""

from __future__ import annotations

import numpy as np
import pytest

from bracketry_rig.monitor.advisor import advise, coverage, dynamic_range_stops, radiance_map, suggest_brackets
from bracketry_rig.monitor.core import (
    OVER_RGB,
    UNDER_RGB,
    disk_time_left_s,
    exposure_limits_dn,
    exposure_shares,
    histogram,
    luminance,
    preview_rgb,
)

WHITE = 4095
MIN_US, MAX_US = 10.0, 45_000.0


def scene(stops: float, shape: tuple[int, int] = (120, 160), r0: float = 0.01, seed: int = 0) -> np.ndarray:
    """Radiance (DN/us) log-uniform over ``stops`` stops from ``r0``, shuffled."""
    rng = np.random.default_rng(seed)
    return r0 * 2.0 ** rng.uniform(0.0, stops, size=shape)


def render(radiance: np.ndarray, exposure_us: float) -> np.ndarray:
    """Noise-free 12-bit luminance of the scene at one exposure (quantised, clipped)."""
    return np.clip(np.round(radiance * exposure_us), 0, WHITE).astype(np.float32)


def test_preview_marks_over_blue_and_under_red_and_demosaics() -> None:
    raw = np.full((40, 60), 2000, np.uint16)
    raw[0:10, 0:20] = 4095  # saturated cells
    raw[20:30, 0:20] = 10  # dark cells
    raw[30:40, 30:60:2] = 0  # R and G2 columns of the mosaic... makes the bottom-right cells cyan-ish, not marked
    rgb = preview_rgb(raw, bayer=True, white_dn=WHITE, max_width=30)
    assert rgb.shape == (20, 30, 3) and rgb.dtype == np.uint8
    assert tuple(rgb[2, 5]) == OVER_RGB
    assert tuple(rgb[12, 5]) == UNDER_RGB
    mid = rgb[7, 20]
    assert mid[0] == mid[1] == mid[2] and 150 < mid[0] < 255  # grey 2000/4095 with gamma 1/2.2
    cyan = rgb[17, 20]  # R = 0 (row 30, even col), G = (G1 + 0)/2, B = 2000
    assert cyan[0] == 0 and cyan[2] > cyan[1] > 0
    small = preview_rgb(np.zeros((400, 640), np.uint16), bayer=True, max_width=100)
    assert small.shape[1] <= 100 and tuple(small[0, 0]) == UNDER_RGB
    mono = preview_rgb(np.full((10, 10), 3000, np.uint16), bayer=False)
    assert mono.shape == (10, 10, 3)


def test_histogram_and_shares() -> None:
    lum = np.array([0, 50, 2000, 4000, 4095, 4095], np.float32)
    h = histogram(lum, white_dn=WHITE, bins=4)
    assert h.tolist() == [2, 1, 0, 3] and h.dtype == np.int64
    over, under = exposure_shares(lum, white_dn=WHITE)
    assert over == pytest.approx(3 / 6) and under == pytest.approx(2 / 6)
    low, high = exposure_limits_dn(WHITE)
    assert low == pytest.approx(81.9) and high == pytest.approx(3890.25)


def test_luminance_takes_the_brightest_colour_of_each_cell() -> None:
    raw = np.zeros((4, 4), np.uint16)
    raw[0, 0], raw[0, 1], raw[1, 0], raw[1, 1] = 100, 300, 100, 50
    lum = luminance(raw, bayer=True)
    assert lum.shape == (2, 2) and lum[0, 0] == pytest.approx(200.0)  # (300 + 100) / 2 > R, B


def test_disk_time_left() -> None:
    assert disk_time_left_s([(0.0, 1000.0)], 1000.0) is None
    assert disk_time_left_s([(0.0, 1000.0), (10.0, 1000.0)], 1000.0) is None  # not writing
    assert disk_time_left_s([(0.0, 1000.0), (10.0, 900.0)], 900.0, floor_mb=100.0) == pytest.approx(80.0)


@pytest.mark.parametrize("stops", [6.0, 10.0, 14.0])
def test_dynamic_range_of_a_covered_scene_is_measured(stops: float) -> None:
    rad = scene(stops)
    brackets = [1.0 * 2**i for i in range(16)]  # 1 us .. 32 ms: covers everything
    rad_est, state = radiance_map(brackets, [render(rad, e) for e in brackets], white_dn=WHITE)
    assert np.mean(state != 0) < 0.001
    true_dr = float(np.log2(np.percentile(rad, 99.5) / np.percentile(rad, 0.5)))
    assert dynamic_range_stops(rad_est) == pytest.approx(true_dr, abs=0.15)
    assert abs(true_dr - stops * 0.99) < 0.1


@pytest.mark.parametrize(("stops", "n"), [(6.0, 3), (10.0, 4), (14.0, 6), (3.0, 6)])
def test_suggested_table_covers_the_scene(stops: float, n: int) -> None:
    """From a table that sees the whole scene, the suggested table (n brackets) exposes >= 99 % of it well."""
    rad = scene(stops, r0=0.02)
    seen = [1.0 * 4**i for i in range(8)]
    rad_est, state = radiance_map(seen, [render(rad, e) for e in seen], white_dn=WHITE)
    table = suggest_brackets(rad_est, state, n, min_us=MIN_US, max_us=MAX_US, white_dn=WHITE)
    assert len(table) == n and list(table) == sorted(table) and len(set(table)) == n
    assert all(MIN_US <= e <= MAX_US for e in table)
    assert coverage([render(rad, e) for e in table], white_dn=WHITE) >= 0.99


def test_rounds_of_advice_reach_a_scene_far_from_the_table() -> None:
    """A bright 10-stop scene seen through a table far too long: a few suggest-apply rounds cover it."""
    rad = scene(10.0, r0=0.3)  # 0.3 .. 307 DN/us: 1 ms saturates most of it
    table: tuple[float, ...] = (1000.0, 2000.0, 4000.0, 8000.0, 16000.0, 32000.0)
    first = coverage([render(rad, e) for e in table], white_dn=WHITE)
    for _ in range(4):
        advice = advise(table, [render(rad, e) for e in table], min_us=MIN_US, max_us=MAX_US, white_dn=WHITE)
        table = tuple(float(e) for e in advice.suggested_us)
    final = coverage([render(rad, e) for e in table], white_dn=WHITE)
    assert first < 0.5 and final >= 0.99, (first, final, table)


def test_a_scene_beyond_the_hardware_limits_gets_the_widest_table() -> None:
    rad = scene(24.0, r0=1e-4)
    seen = [0.01 * 4**i for i in range(14)]
    rad_est, state = radiance_map(seen, [render(rad, e) for e in seen], white_dn=WHITE)
    table = suggest_brackets(rad_est, state, 6, min_us=MIN_US, max_us=MAX_US, white_dn=WHITE)
    assert table[0] == MIN_US and table[-1] == MAX_US


def test_advice_reports_current_coverage_and_clipping() -> None:
    rad = scene(10.0, r0=0.05)
    table = (100.0, 200.0, 400.0)  # covers roughly the bright half only
    advice = advise(table, [render(rad, e) for e in table], min_us=MIN_US, max_us=MAX_US, white_dn=WHITE)
    assert 0.2 < advice.coverage < 0.9
    assert advice.clipped_share == pytest.approx(1.0 - advice.coverage, abs=0.01)
    assert advice.suggested_coverage >= advice.coverage
