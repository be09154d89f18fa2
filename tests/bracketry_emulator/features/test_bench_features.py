"""Features: RGGB demosaicing, ORB-SLAM2-like ORB extractor, 20x20 grid coverage."""

from __future__ import annotations

import itertools

import cv2
import numpy as np
import pytest

from bracketry_emulator.features import OrbExtractor, OrbSettings, bayer12_to_gray8, grid_coverage, hamming_distance
from bracketry_emulator.features.orb import _ic_angle_deg


def test_bench_demosaic_rggb_red_is_red() -> None:
    raw = np.zeros((16, 16), np.uint16)
    raw[0::2, 0::2] = 4000  # red sites of an RGGB mosaic
    gray = bayer12_to_gray8(raw)
    assert gray.dtype == np.uint8 and gray.shape == raw.shape
    assert abs(int(gray[8, 8]) - round(0.299 * 4000 / 16)) <= 1  # BT.601 weight of red, 12 -> 8 bit
    raw[:] = 0
    raw[1::2, 1::2] = 4000  # blue sites
    assert abs(int(bayer12_to_gray8(raw)[8, 8]) - round(0.114 * 4000 / 16)) <= 1


def test_bench_orb_settings_levels() -> None:
    s = OrbSettings()
    per_level = s.features_per_level()
    assert (s.n_features, s.scale_factor, s.n_levels, s.ini_th_fast, s.min_th_fast) == (3000, 1.2, 13, 15, 5)
    assert len(per_level) == 13 and sum(per_level) == 3000
    assert all(a > b for a, b in itertools.pairwise(per_level))


def test_bench_orb_extractor_budget_and_spread() -> None:
    rng = np.random.default_rng(3)
    img = cv2.GaussianBlur(rng.integers(0, 256, (480, 640), dtype=np.uint8), (7, 7), 2.0)
    ex = OrbExtractor(OrbSettings(n_features=1000))
    f = ex.detect_and_compute(img)
    assert 700 <= len(f) <= 1000  # small top levels cannot fill their quotas (as in ORB-SLAM)
    assert f.descriptors.shape == (len(f), 32) and f.descriptors.dtype == np.uint8
    assert f.octave.max() >= 5  # the pyramid is used
    assert grid_coverage(f.xy_px, 640, 480, 20) > 0.65  # the 19 px edge margin empties part of the outer ring
    # same image -> same features (deterministic)
    g = ex.detect_and_compute(img)
    assert np.array_equal(f.xy_px, g.xy_px) and np.array_equal(f.descriptors, g.descriptors)
    assert np.all(hamming_distance(f.descriptors, g.descriptors) == 0)


def test_bench_orientation_matches_opencv() -> None:
    rng = np.random.default_rng(5)
    img = cv2.GaussianBlur(rng.integers(0, 256, (240, 320), dtype=np.uint8), (5, 5), 1.5)
    kps = cv2.ORB_create(200, nlevels=1).detect(img, None)
    x = np.array([round(k.pt[0]) for k in kps])
    y = np.array([round(k.pt[1]) for k in kps])
    diff = (_ic_angle_deg(img, x, y) - np.array([k.angle for k in kps]) + 180) % 360 - 180
    assert np.median(np.abs(diff)) < 0.5


def test_bench_grid_coverage() -> None:
    assert grid_coverage(np.zeros((0, 2)), 100, 100) == 0.0
    xy = np.array([[2.0, 2.0], [3.0, 3.0], [99.0, 99.0]])
    assert grid_coverage(xy, 100, 100, 20) == pytest.approx(2 / 400)
    centres = (np.stack(np.meshgrid(np.arange(20), np.arange(20)), -1).reshape(-1, 2) + 0.5) * 5
    assert grid_coverage(centres, 100, 100, 20) == 1.0


@pytest.mark.realdata
def test_bench_orb_on_real_sample(borealhdr_sequence) -> None:
    png = sorted((borealhdr_sequence / "camera_left" / "4.0").glob("*.png"))[0]
    raw = cv2.imread(str(png), cv2.IMREAD_UNCHANGED)
    gray = bayer12_to_gray8(raw)
    f = OrbExtractor().detect_and_compute(gray)
    assert len(f) >= 2900  # the 3000 budget is met on a textured forest image
    assert grid_coverage(f.xy_px, gray.shape[1], gray.shape[0]) > 0.9


def test_bench_orb_detect_xy_is_detect_and_compute_without_descriptors(borealhdr_sequence) -> None:
    """SLAM's coverage and keypoint counts use detect_xy: the same keypoints, in the same order, as the full
    extractor (textured, blank-bordered, masked and tiny images; the real sample)."""
    rng = np.random.default_rng(11)
    images = [cv2.GaussianBlur(rng.integers(0, 256, (400, 640), dtype=np.uint8), (5, 5), s) for s in (0.8, 2.0)]
    edge = images[0].copy()
    edge[:, :40] = 0  # keypoints hug the edge of a blank band
    images += [edge, images[1][:90, :120].copy(), np.zeros((200, 320), np.uint8)]
    png = sorted((borealhdr_sequence / "camera_left" / "4.0").glob("*.png"))[0]
    images.append(bayer12_to_gray8(cv2.imread(str(png), cv2.IMREAD_UNCHANGED)))
    ex = OrbExtractor()
    for k, img in enumerate(images):
        mask = np.zeros(img.shape, np.uint8)
        mask[10:-10, 25:-30] = 1
        for m in (None, mask):
            assert np.array_equal(ex.detect_xy(img, m), ex.detect_and_compute(img, m).xy_px), (k, m is None)
    small_edge = OrbExtractor(OrbSettings(edge_px=15))  # below the descriptor border: falls back to the full path
    assert np.array_equal(small_edge.detect_xy(images[0]), small_edge.detect_and_compute(images[0]).xy_px)


def test_bench_gray16_to_gray8_is_the_rounding_formula_for_every_code() -> None:
    from bracketry_emulator.features.demosaic import gray16_to_gray8

    codes = np.arange(65536, dtype=np.uint16).reshape(256, 256)
    want = np.clip(np.rint(codes.astype(np.float32) / 16.0), 0, 255).astype(np.uint8)  # half to even
    got = gray16_to_gray8(codes)
    assert got.dtype == np.uint8 and np.array_equal(got, want)
    assert np.array_equal(gray16_to_gray8(codes[:, ::3]), want[:, ::3])  # a strided view too


def _level_reference(ex: OrbExtractor, image: np.ndarray, wanted: int) -> tuple[np.ndarray, np.ndarray]:
    """The extractor's level detection written plainly (per-keypoint Python, ufunc.at): the fast path must match."""
    from bracketry_emulator.features.orb import _spread

    s = ex.settings
    h, w = image.shape
    kps = ex._fast.detect(image, None)
    xy = np.array([k.pt for k in kps], np.float32).reshape(-1, 2)
    resp = np.array([k.response for k in kps], np.float32)
    e = s.edge_px
    inside = (xy[:, 0] >= e) & (xy[:, 0] < w - e) & (xy[:, 1] >= e) & (xy[:, 1] < h - e)
    xy, resp = xy[inside], resp[inside]
    cell = (xy[:, 1] // s.cell_px).astype(np.int64) * int(np.ceil(w / s.cell_px)) \
        + (xy[:, 0] // s.cell_px).astype(np.int64)
    cell_max = np.zeros(int(cell.max()) + 1, np.float32)
    np.maximum.at(cell_max, cell, resp)
    keep = (resp >= s.ini_th_fast) | (cell_max[cell] < s.ini_th_fast)
    pick = _spread(xy[keep], resp[keep], w, h, wanted)
    return xy[keep][pick], resp[keep][pick]


def test_bench_orb_levels_match_the_plain_reference() -> None:
    rng = np.random.default_rng(11)
    img = cv2.GaussianBlur(rng.integers(0, 256, (400, 640), dtype=np.uint8), (5, 5), 1.2)
    img[100:200, 200:400] //= 8  # a dark patch: cells without any corner at iniThFAST fall back to minThFAST
    ex = OrbExtractor()
    wanted = ex.settings.features_per_level()
    for level, image in enumerate(ex.pyramid(img)):
        xy, resp = ex._detect_level(image, wanted[level])
        ref_xy, ref_resp = _level_reference(ex, image, wanted[level])
        assert xy.dtype == np.float32 and np.array_equal(xy, ref_xy) and np.array_equal(resp, ref_resp), level
