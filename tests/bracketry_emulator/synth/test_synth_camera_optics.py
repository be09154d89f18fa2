"""The camera's sensor and optics against their formulas: noise with dark current, veiling glare, blooming, the blur
a turning walker gives, and the real-sample measures of ``synth.realism``."""

from __future__ import annotations

import math

import numpy as np
import pytest

from bracketry_emulator.synth import CameraModel, World
from bracketry_emulator.synth.realism import dark_noise_floor, model_noise_dn, shares
from bracketry_emulator.synth.scenario import load_scenario, shipped_scenarios, sky_lighting
from bracketry_emulator.synth.trajectory import LoopTrajectory
from bracketry_emulator.synth.world import world_from_scenario


def test_synth_noise_with_dark_current_follows_the_formula() -> None:
    # a flat field, linear response: mean and variance of the levels are (rate + dark) t / g and
    # ((rate + dark) t + read^2) / g^2 + 1/12 (quantisation)
    cam = CameraModel(response="linear", dark_current_e_per_s=2.0e5, read_noise_e=2.3, blooming=0.0)
    g = cam.gain_e_per_dn
    for rate, exposure_us in ((0.05, 4000.0), (0.4, 8000.0), (0.0, 16000.0)):
        img = cam.expose(np.full((400, 400), rate, np.float32), exposure_us, np.random.default_rng(1))
        mean_e = (rate + 0.2) * exposure_us  # 2e5 e-/s = 0.2 e-/us
        assert img.mean() == pytest.approx(mean_e / g, rel=0.01, abs=0.05)
        var_pred = (mean_e + cam.read_noise_e ** 2) / g ** 2 + 1 / 12
        assert img.astype(np.float64).var() == pytest.approx(var_pred, rel=0.05)


def test_synth_model_noise_dn_is_the_formula() -> None:
    cam = CameraModel()
    level = 75.0
    assert model_noise_dn(level, cam.gain_e_per_dn, cam.read_noise_e) == pytest.approx(
        math.sqrt(level / cam.gain_e_per_dn + (cam.read_noise_e / cam.gain_e_per_dn) ** 2 + 1 / 12))


def test_synth_dark_noise_floor_measures_the_models_noise() -> None:
    # a flat, dark field through the default camera: the estimator finds the formula's noise at its level
    cam = CameraModel()
    rate = np.full((400, 640), 0.01, np.float32)
    codes = cam.expose(rate, 8000.0, np.random.default_rng(3))
    level, noise = dark_noise_floor(codes)
    assert level == pytest.approx(0.01 * 8000.0 / cam.gain_e_per_dn, rel=0.05)
    assert noise == pytest.approx(model_noise_dn(level, cam.gain_e_per_dn, cam.read_noise_e), rel=0.15)


def _sun_on_dark(h: int = 200, w: int = 320) -> np.ndarray:
    """A dark scene (0.01 e-/us) with a small, very bright disk (a sun: 2000 e-/us) at (60, 100)."""
    rate = np.full((h, w), 0.01, np.float32)
    v, u = np.mgrid[0:h, 0:w]
    rate[(u - 100) ** 2 + (v - 60) ** 2 <= 9] = 2000.0
    return rate


def test_synth_veiling_glare_lifts_the_dark_near_a_sun_and_keeps_the_light() -> None:
    rate = _sun_on_dark()
    veiled = CameraModel(veiling_glare=0.03).veil(rate)
    assert np.array_equal(CameraModel(veiling_glare=0.0).veil(rate), rate)
    # energy is kept (the spread light is taken from the image; within 1 %: the blur replicates the borders)
    assert float(veiled.astype(np.float64).sum()) == pytest.approx(float(rate.astype(np.float64).sum()), rel=0.01)
    near, far = veiled[60, 130], veiled[190, 310]  # 30 px and ~250 px from the sun
    assert near > 5 * 0.01 and far > 0.01  # the dark is lifted everywhere ...
    assert near > 1.5 * far  # ... most around the sun
    # contrast flattens: a 2x texture step in the dark becomes less than 2x
    step = rate.copy()
    step[150:, :160] *= 2.0
    vs = CameraModel(veiling_glare=0.03).veil(step)
    assert vs[175, 80] / vs[175, 240] < 1.8


def test_synth_glare_raises_the_dark_level_around_a_sun_in_view() -> None:
    # the frozen lake walked towards a 5-degree sun: the lens veil and the sun's glare lift the darkest parts
    sc = load_scenario(shipped_scenarios()["frozen-lake"])
    lit = world_from_scenario(sc, resolution=(160, 100), detail=0.25, motion_blur=False)
    plain = world_from_scenario(sc, resolution=(160, 100), detail=0.25, motion_blur=False,
                                camera=CameraModel(veiling_glare=0.0))
    R, _p = lit.world_pose(0.0)
    # the sun within 25 degrees of the optical axis: in the view's top rows (the rig pitches 18 degrees down)
    sun_cam = R.T @ lit.scene.lighting.sun_dir
    assert sun_cam[2] > math.cos(math.radians(25.0))
    assert sun_cam[1] / sun_cam[2] * lit.calibration.left.fy > -lit.calibration.left.cy
    a, b = lit.rate_e_per_us("left", 0.0), plain.rate_e_per_us("left", 0.0)
    dark = b <= np.percentile(b, 10)
    assert float(np.median(a[dark] / b[dark])) > 1.2
    # the dynamic range of the view shrinks (contrast flattens)
    assert np.percentile(a, 99) / np.percentile(a, 5) < np.percentile(b, 99) / np.percentile(b, 5)


def test_synth_the_sun_disk_casts_the_direct_light() -> None:
    # an albedo-1 surface facing the sun has radiance sun_rgb: irradiance pi * sun_rgb, which the disk of radiance L
    # delivers over its solid angle pi * r^2; the glare veil keeps its own scale, 0.092 of that irradiance
    for elev_deg, overcast in ((1.0, 0.0), (3.0, 0.0), (8.0, 0.3), (30.0, 0.0), (60.0, 0.0)):
        lt = sky_lighting(elev_deg, 200.0, overcast)
        e_sun = lt.disk_radiance * math.pi * lt.disk_rad ** 2
        assert e_sun == pytest.approx(math.pi * lt.sun_rgb[1], rel=1e-9)
        assert lt.veil_radiance is not None
        assert lt.veil_radiance * math.pi * lt.disk_rad ** 2 == pytest.approx(0.0923 * e_sun, rel=1e-3)
    # no sun below the horizon: the disk's pixels are sky
    night = sky_lighting(-4.0, 200.0)
    assert night.sun_rgb[1] == 0.0 and night.disk_radiance == night.horizon_rgb[1]


def test_synth_blooming_grows_saturated_areas_with_the_overexposure() -> None:
    rate = np.full((100, 100), 0.01, np.float32)
    rate[45:55, 45:55] = 50.0  # a bright patch
    cam = CameraModel(blooming=0.3, bloom_sigma_px=48.0)  # 48 px at 1920: 2.5 px at 100 px across
    plain = CameraModel(blooming=0.0)
    saturated = []
    for exposure_us in (1000.0, 4000.0, 16000.0):
        codes = cam.expose(rate, exposure_us, None)
        assert not np.any(plain.expose(rate, exposure_us, None)[rate < 1] == 4094)
        saturated.append(int((codes == 4094).sum()))
    assert saturated[0] >= 100 and saturated[0] < saturated[1] < saturated[2]
    # the charge is moved, not made: the charge rate sums to the input's (away from the borders)
    moved = cam.charge_rate(rate, 16000.0).astype(np.float64)
    assert moved.sum() == pytest.approx(rate.astype(np.float64).sum() + 3e-6 * rate.size, rel=1e-4)
    # nothing blooms below the full well
    assert np.array_equal(cam.charge_rate(rate, 100.0), plain.charge_rate(rate, 100.0))


def test_synth_blur_length_from_rotation() -> None:
    # a walker who stands (no pace, no gait) and turns: 15 degrees every 8 s -> 11.8 deg/s at t = 0; a frame of
    # exposure E smears the image centre by fx * omega * E pixels
    turn = LoopTrajectory(speed_kmh=1e-9, bounce_m=0.0, roll_deg=0.0, sway_m=0.0, yaw_deg=0.0, nod_deg=0.0,
                          turn_deg=15.0, turn_period_s=8.0)
    world = World("forest-winter", seed=1, resolution=(320, 200), trajectory=turn, detail=0.25)
    omega = math.radians(15.0) * 2 * math.pi / 8.0
    fx = world.calibration.side("left").fx
    for exposure_us in (8000.0, 32000.0):
        t0 = -exposure_us * 0.5e-6  # centred on t = 0, where the turn is fastest
        motion = world.motions("left", 0.0, [(t0, exposure_us)])[0]
        cy, cx = motion.vu.shape[0] // 2, motion.vu.shape[1] // 2
        centre_px = float(math.hypot(motion.vu[cy, cx], motion.vv[cy, cx])) * exposure_us * 1e-6
        assert centre_px == pytest.approx(fx * omega * exposure_us * 1e-6, rel=0.05)
        assert motion.max_px(exposure_us * 1e-6) >= centre_px


def test_synth_shares_count_saturated_and_dark_pixels() -> None:
    codes = np.zeros((10, 10), np.uint16)
    codes[:2] = 4094
    codes[2:5] = 15 * 16 + 15  # 8-bit 15: dark
    codes[5:] = 16 * 16  # 8-bit 16: not dark
    assert shares(codes) == (pytest.approx(0.2), pytest.approx(0.3))
