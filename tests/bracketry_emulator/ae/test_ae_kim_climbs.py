"""Kim's default mode climbs toward its metric's peak on static scenes (dark, mid, bright), 8 steps from 4 ms.

The scenes are the AE tests' textured irradiance (other seeds and dynamic ranges than the other tests) scaled so the
metric peaks at the longest exposure (dark), inside the range (mid) or at the shortest (bright); the peak is found by
sweeping the metric over 25 log-spaced exposures.
"""

from __future__ import annotations

import itertools

import numpy as np
import pytest
from ae_scenes import closed_loop, irradiance, render

from bracketry_emulator.ae import get_method
from bracketry_emulator.ae.kim import KimAE

GRID_US = np.geomspace(500.0, 35_000.0, 25)
META = {"side": "left"}


def _metric_curve(irr: np.ndarray) -> np.ndarray:
    kim = KimAE()
    return np.array([kim.metric(render(irr, t), META) for t in GRID_US])


@pytest.mark.parametrize("seed,dynamic_range", [(5, 8.0), (6, 64.0)])
@pytest.mark.parametrize("scale,where", [(1 / 30, "dark"), (1.0, "mid"), (40.0, "bright")])
def test_kim_climbs_to_the_metric_peak(seed: int, dynamic_range: float, scale: float, where: str) -> None:
    irr = irradiance(seed=seed, dynamic_range=dynamic_range) * scale
    curve = _metric_curve(irr)
    informative = np.where(curve != 0.0, curve, -np.inf)  # 0: clipped or flat everywhere, nothing to climb
    peak_us = float(GRID_US[int(np.argmax(informative))])
    peak = float(informative.max())
    if where == "dark":
        assert peak_us == GRID_US[-1]
    elif where == "bright":
        # or clipped in part at every exposure (the metric negative everywhere): Kim steps out by its mean, down
        assert peak_us == GRID_US[0] or peak < 0
        peak_us, peak = float(GRID_US[0]), float(curve[0])
    else:
        assert GRID_US[3] < peak_us < GRID_US[-4]
    traj = closed_loop(get_method("kim"), irr, 4000.0, 8)
    settled_us = float(np.median(traj[-3:]))
    # toward the peak from 4 ms, and close to it in ln(exposure): within 2x, the GP's length scale, as the metric
    # has a spike narrower than that at the onset of saturation
    assert abs(np.log(settled_us / peak_us)) < min(np.log(2.0), abs(np.log(4000.0 / peak_us))) + 1e-9, traj
    kim = KimAE()
    settled, start = kim.metric(render(irr, settled_us), META), kim.metric(render(irr, 4000.0), META)
    assert settled >= peak - 0.5 * abs(peak), traj
    if abs(np.log(4000.0 / peak_us)) > np.log(1.5) and peak > 0:
        assert settled > start, traj


def test_kim_leaves_a_saturated_scene_for_the_shortest_exposure() -> None:
    """400x too bright: saturated at every exposure, metric 0 everywhere; it must end at the shortest exposure."""
    irr = irradiance(seed=7) * 400.0
    assert _metric_curve(irr).max() == 0.0
    traj = closed_loop(get_method("kim"), irr, 4000.0, 8)
    assert traj[-1] == pytest.approx(500.0) and all(b <= a for a, b in itertools.pairwise(traj)), traj


def test_kim_leaves_a_black_scene_for_longer_exposures() -> None:
    irr = irradiance(seed=7) * 1e-5
    traj = closed_loop(get_method("kim"), irr, 4000.0, 3)
    assert traj[1] > traj[0] and traj[-1] == pytest.approx(35_000.0), traj


def _snow_scene(scale: float) -> np.ndarray:
    """A static view that is 70 % faintly textured snow (3 % contrast) beside a strip of dark forest texture
    (1/20 of the AE tests' textured irradiance): ``scale`` 30 is a bright sunlit view (AE50 settles near 0.2 ms),
    1/30 a dark one."""
    h, w = 240, 320
    rng = np.random.default_rng(3)
    import cv2

    snow = 1.0 + 0.03 * cv2.GaussianBlur(rng.standard_normal((h, w)), (0, 0), 2)
    strip = np.zeros((h, w))
    strip[:, : int(w * 0.3)] = 1.0
    forest = irradiance(seed=4, dynamic_range=8.0) / 20.0
    return scale * (strip * forest + (1 - strip) * snow * 30.0 * 2047.0 / 8000.0)


@pytest.mark.parametrize("scale,where", [(1.0, "bright"), (1 / 300, "dark")])
def test_kim_moves_the_way_ae50_does_on_snow(scale: float, where: str) -> None:
    """Kim ends on AE50's side of its 4 ms start, and on the bright view never explores above its start: saturated
    snow is not rewarded by the metric (kim.py, "Clipped pixels")."""
    irr = _snow_scene(scale)
    ae50 = closed_loop(get_method("ae50"), irr, 4000.0, 10)
    kim = closed_loop(get_method("kim"), irr, 4000.0, 10)
    settled_us = float(np.median(kim[-3:]))
    if where == "bright":
        assert ae50[-1] < 1000.0, ae50
        assert settled_us < 4000.0 and max(kim[1:]) <= 4000.0, kim
    else:
        assert ae50[-1] > 16_000.0, ae50
        assert settled_us > 4000.0, kim
