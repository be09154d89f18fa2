"""Photometry of the synthetic camera: exposure response, noise model, code set, Bayer phase, dynamic range."""

from __future__ import annotations

import itertools
from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np
import pytest

from bracketry_emulator.synth import CameraModel, World, srgb_lut
from bracketry_emulator.synth.camera_model import pcalib_from_lut, pcalib_lut, srgb_oetf
from bracketry_emulator.synth.trajectory import LoopTrajectory

RES = (320, 200)


@dataclass
class _Held(LoopTrajectory):
    """The walk's pose at ``at_s``, held: an exposure sweep of one view (every exposure has its own mid-exposure
    instant, and the World blurs a moving camera)."""

    at_s: float = 3.0

    def pose(self, t_s: float) -> tuple[np.ndarray, np.ndarray]:
        return super().pose(self.at_s)


@pytest.fixture(scope="module")
def world() -> World:
    return World("forest-winter", seed=1, resolution=RES, trajectory=_Held())


def test_synth_srgb_lut_is_the_samples_encoding() -> None:
    lut = srgb_lut()
    k = np.arange(4096)
    assert np.array_equal(lut, np.minimum(np.floor(4095 * srgb_oetf(k / 4095)), 4094))
    codes = np.unique(lut)
    assert len(codes) == 2920 and codes.max() == 4094
    assert list(codes[:5]) == [0, 12, 25, 38, 51]
    assert np.all(np.diff(lut.astype(int)) >= 0)


def test_synth_mean_code_rises_with_exposure_until_saturation(world: World) -> None:
    exposures = np.geomspace(20.0, 50000.0, 30)
    means_clean = [world.render("left", 3.0, e, noise=False).mean() for e in exposures]
    means_noisy = [world.render("left", 3.0, e).mean() for e in exposures]
    assert np.all(np.diff(means_clean) >= 0)
    assert np.all(np.diff(means_noisy) > -2.0)
    assert means_clean[-1] > 5 * means_clean[0]
    long = world.render("left", 3.0, 50000.0)
    assert long.max() == 4094 and (long == 4094).mean() > 0.05 and (long == 4095).sum() == 0
    # a pixel saturated in the noise-free image stays at 4094 for all longer exposures
    sat_8 = world.render("left", 3.0, 8000.0, noise=False) == 4094
    assert np.all(world.render("left", 3.0, 16000.0, noise=False)[sat_8] == 4094)


def test_synth_noise_variance_follows_the_model() -> None:
    cam = CameraModel(response="linear", full_well_e=20000.0, read_noise_e=6.0)
    world = World("campus-summer", seed=2, resolution=(160, 100), camera=cam)
    t_s, exposure_us = 4.0, 4000.0
    rate = world.rate_e_per_us("left", t_s, exposure_us)  # the frame's own (mid-exposure, motion-blurred) rate
    frames = np.stack([world.render("left", t_s, exposure_us, rng=np.random.default_rng(k)) for k in range(25)])
    frames = frames.astype(np.float64)
    g = cam.gain_e_per_dn
    mean_e = np.minimum(rate.astype(np.float64) * exposure_us, cam.full_well_e)
    mean_dn = mean_e / g
    var_pred = (mean_e + cam.read_noise_e ** 2) / g ** 2 + 1.0 / 12.0
    usable = (mean_dn > 5 * np.sqrt(var_pred)) & (mean_dn + 5 * np.sqrt(var_pred) < 4094)
    assert usable.sum() > 3000
    var_meas = frames.var(axis=0, ddof=1)
    # unbiased: the 25-frame means scatter around the model with the standard error of the mean
    z = (frames.mean(axis=0)[usable] - mean_dn[usable]) / np.sqrt(var_pred[usable] / 25)
    assert abs(float(z.mean())) < 0.1 and 0.9 < float(z.std()) < 1.1
    # binned by level: the measured variance follows shot + read + quantization noise within 10 %
    edges = np.quantile(mean_dn[usable], np.linspace(0, 1, 6))
    for lo, hi in itertools.pairwise(edges):
        sel = usable & (mean_dn >= lo) & (mean_dn <= hi)
        ratio = var_meas[sel].mean() / var_pred[sel].mean()
        assert ratio == pytest.approx(1.0, abs=0.1), (lo, hi, ratio)


def test_synth_poisson_and_gaussian_shot_noise_agree() -> None:
    rate = np.full((100, 100), 0.5, np.float32)
    for poisson in (False, True):
        cam = CameraModel(response="linear", read_noise_e=0.0, poisson=poisson, full_well_e=4095.0)
        img = cam.expose(rate, 200.0, np.random.default_rng(0)).astype(float)
        assert img.mean() == pytest.approx(100.0, abs=0.5)
        assert img.var() == pytest.approx(100.0 + 1 / 12, rel=0.06)


def test_synth_bayer_phase_is_rggb() -> None:
    for qe, lit in (((1.0, 0.0, 0.0), [(0, 0)]), ((0.0, 1.0, 0.0), [(0, 1), (1, 0)]), ((0.0, 0.0, 1.0), [(1, 1)])):
        # blooming off: charge above the full well spills into the neighbours whatever their colour filter
        world = World("forest-winter", seed=1, resolution=RES, camera=CameraModel(qe_rgb=qe, blooming=0.0))
        img = world.render("left", 3.0, 8000.0, noise=False)
        for r in (0, 1):
            for c in (0, 1):
                sub = img[r::2, c::2]
                assert (sub.mean() > 100) == ((r, c) in lit), (qe, r, c)


def test_synth_colour_on_the_mosaic(world: World) -> None:
    img = world.render("left", 3.0, 4000.0, noise=False).astype(float)
    g1, g2 = img[0::2, 1::2].mean(), img[1::2, 0::2].mean()
    # the two greens are a row and a column apart: on this view (the backpack's gait held at 3 s) the content alone
    # makes them differ by 1.9 % (2.2 % with the veil and the blooming)
    assert g1 == pytest.approx(g2, rel=0.03)
    # the sky is blue: in sky pixels the blue sites (1, 1) outshine the red sites (0, 0)
    sky = ~np.isfinite(world.radiance("left", 3.0).range_m)
    rad = world.radiance("left", 3.0).radiance
    red = rad[0::2, 0::2][sky[0::2, 0::2]].mean()
    blue = rad[1::2, 1::2][sky[1::2, 1::2]].mean()
    assert blue > red


def test_synth_vignetting_darkens_corners() -> None:
    cam = CameraModel()
    v = cam.vignetting_map(320, 200, 159.5, 99.5)
    assert v[100, 160] == pytest.approx(1.0, abs=1e-3)
    assert 0.6 < v[0, 0] < 0.85


def test_synth_world_spans_over_100_db() -> None:
    # walking towards the low winter sun: the solar disk and the shade under the trees in one frame. The instants
    # whose view holds the sun (projected inside the image) are tried, the most sun-facing first: at one of them a
    # trunk may hide the disk, so the span is that of the best of a few.
    world = World("forest-winter", seed=1, resolution=RES)
    tr = world.trajectory
    sun = world.scene.lighting.sun_dir
    cam = world.calibration.left
    in_view = []
    for t in np.arange(0.0, tr.length_m / tr.speed_mps, 0.5):
        d = world.world_pose(float(t))[0].T @ sun
        if d[2] <= 0:
            continue
        u, v = cam.cx + cam.fx * d[0] / d[2], cam.cy + cam.fy * d[1] / d[2]
        if 5 <= u < RES[0] - 5 and 5 <= v < RES[1] - 5:
            in_view.append((float(d[2]), float(t)))
    assert in_view, "the walk never faces the sun"
    spans = []
    for _, t in sorted(in_view, reverse=True)[:6]:
        rad = world.radiance("left", t).radiance
        spans.append(20 * np.log10(rad.max() / rad[rad > 0].min()))
    assert max(spans) >= 100.0, spans


def test_synth_pcalib_roundtrip(tmp_path: Path) -> None:
    values = pcalib_from_lut(srgb_lut())
    assert len(values) == 256 and values[0] == 0 and values[-1] == pytest.approx(255.0)
    path = tmp_path / "pcalib.txt"
    CameraModel().write_pcalib(path)
    cam = CameraModel.with_pcalib_file(path)
    # the lifted pcalib is a piecewise-linear approximation of the sRGB encoding
    assert np.abs(cam.lut.astype(int) - srgb_lut().astype(int))[16:].max() < 40
    assert np.array_equal(cam.lut, pcalib_lut(np.loadtxt(path)))


@pytest.mark.realdata
def test_synth_default_code_set_matches_real_sample(world: World, borealhdr_sequence: Path) -> None:
    sample: set[int] = set()
    for folder in sorted((borealhdr_sequence / "camera_left").iterdir()):
        img = cv2.imread(str(sorted(folder.glob("*.png"))[0]), cv2.IMREAD_UNCHANGED)
        sample |= set(np.unique(img).tolist())
    assert sample == set(np.unique(srgb_lut()).tolist())
    rendered: set[int] = set()
    for e in np.geomspace(20.0, 50000.0, 40):
        rendered |= set(np.unique(world.render("left", 3.0, e)).tolist())
    assert rendered == sample


def test_a_12bit_calibrate_crf_curve_drives_the_synthetic_camera(tmp_path: Path) -> None:
    """``calibrate-crf`` writes 4096 values (inverse response per 12-bit code); synth --response accepts them."""
    from bracketry_emulator.crf import load_response
    from bracketry_emulator.crf.pcalib import save_pcalib

    path = tmp_path / "pcalib4096.txt"
    save_pcalib(path, load_response("srgb").icrf)
    model = CameraModel.with_pcalib_file(path)
    diff = model.lut.astype(int) - srgb_lut().astype(int)
    assert np.abs(diff).max() <= 1  # the sRGB camera back, within the truncation of one code
    with pytest.raises(Exception, match="256 or 4096"):
        pcalib_lut(np.linspace(0, 1, 1000))
