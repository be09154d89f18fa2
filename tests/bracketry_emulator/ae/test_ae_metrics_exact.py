"""Exact checks of the AE methods' maths: Zhang's metric and derivative, Wang's refinement and search, the GP, DRL.

Expected values are computed in the tests with independent arithmetic (hand-derived gradients, numpy Sobel with a
reflect-101 border, closed-form GP posterior), never with the functions' own helpers.
"""

from __future__ import annotations

import math
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from ae_scenes import RESPONSE, irradiance, render

from bracketry_emulator.ae import wang
from bracketry_emulator.ae.base import bayer_gray
from bracketry_emulator.ae.gp import GaussianProcess1D
from bracketry_emulator.ae.wang import WangAE, wang_refinement
from bracketry_emulator.ae.zhang import soft_percentile_metric, zhang_metric_and_derivative
from bracketry_testkit import missing_component

# --- Zhang -----------------------------------------------------------------------------------------------------------


def _soft_weights(n: int, p: float = 0.8, k: float = 5.0) -> np.ndarray:
    t = math.floor(p * n)
    raw = [math.sin(math.pi * i / (2 * t)) ** k if i < t
           else math.sin(math.pi / 2 - math.pi * (i - t) / (2 * (n - t))) ** k for i in range(n)]
    return np.array(raw) / sum(raw)


def test_zhang_metric_exact_on_stripes() -> None:
    """Vertical stripes 0,0,1,3,3 (4 rows): Scharr/32 x = (I[x+1] - I[x-1]) / 2 -> G = 0, 1/4, 9/4, 1, 0 per row."""
    img = np.tile(np.array([0, 0, 1, 3, 3], dtype=np.float32), (4, 1))
    g_sorted = np.array([0.0] * 8 + [0.25] * 4 + [1.0] * 4 + [2.25] * 4)
    expected = float(_soft_weights(20) @ g_sorted)
    assert soft_percentile_metric(img) == pytest.approx(expected, rel=1e-12)
    assert expected == pytest.approx(1.161296953, rel=1e-9)
    # the weights peak at the 80th percentile (i = 16, a 2.25), so M lies between 1 and 2.25, nearer 2.25 than a mean
    assert 1.0 < expected < 2.25 and expected > float(g_sorted.mean())


CODES = np.arange(4096, dtype=np.float64)
K12 = 4095.0
#: g = ln f^-1 for the CRF I = K X / (X + 1) (X = exposure x irradiance): g = ln I - ln(K - I), g' = 1/I + 1/(K - I)
SLOPE_RATIONAL = 1.0 / np.maximum(CODES, 0.5) + 1.0 / np.maximum(K12 - CODES, 0.5)
#: linear CRF I = X: g = ln I, g' = 1/I (code 0 floored)
SLOPE_LINEAR = 1.0 / np.maximum(CODES, 1.0)


def _codes(seed: int = 0, shape: tuple[int, int] = (12, 12)) -> np.ndarray:
    return np.random.default_rng(seed).integers(200, 3800, size=shape).astype(np.float64)


def test_zhang_derivative_exact_for_a_linear_crf() -> None:
    """Linear CRF: dI/dt = I / t, every G scales as t^2 (same sort order), so dM/dt = 2 M / t exactly."""
    img = _codes()
    t_us = 5000.0
    m, dm = zhang_metric_and_derivative(img, t_us, SLOPE_LINEAR)
    assert m == pytest.approx(soft_percentile_metric(img), rel=1e-12)
    assert dm == pytest.approx(2.0 * m / t_us, rel=1e-6)
    assert dm > 0


def test_zhang_derivative_matches_a_finite_difference_of_the_metric() -> None:
    """Non-linear CRF I = K X/(X+1): dM/dt equals the central difference of M(image at t (1 +- eps)) / (2 t eps)."""
    i0 = _codes(1)
    x0 = i0 / (K12 - i0)
    t_us, eps = 5000.0, 1e-3

    def image_at(scale: float) -> np.ndarray:
        x = x0 * scale
        return K12 * x / (x + 1.0)

    m, dm = zhang_metric_and_derivative(image_at(1.0), t_us, SLOPE_RATIONAL)
    fd = (soft_percentile_metric(image_at(1 + eps)) - soft_percentile_metric(image_at(1 - eps))) / (2 * t_us * eps)
    assert dm == pytest.approx(fd, rel=1e-3)
    # this CRF compresses: G grows slower than t^2 (the linear-CRF value 2 M / t is well off)
    assert 0 < dm < 0.5 * (2.0 * m / t_us)


def test_zhang_derivative_treats_saturated_pixels_as_constant() -> None:
    """A clipped block (linear CRF, I = min(X, 4094)) does not brighten with t: the derivative with dI/dt = 0 there
    matches the finite difference; without the saturation rule (dI/dt = I/t there) it is far off."""
    i0 = _codes(2)
    i0[3:6, 3:7] = 6000.0  # beyond the saturated code
    t_us, eps = 5000.0, 1e-3

    def image_at(scale: float) -> np.ndarray:
        return np.minimum(i0 * scale, 4094.0)

    _, dm = zhang_metric_and_derivative(image_at(1.0), t_us, SLOPE_LINEAR, saturated_dn=4094.0)
    _, dm_unclipped = zhang_metric_and_derivative(image_at(1.0), t_us, SLOPE_LINEAR, saturated_dn=1e9)
    fd = (soft_percentile_metric(image_at(1 + eps)) - soft_percentile_metric(image_at(1 - eps))) / (2 * t_us * eps)
    assert dm == pytest.approx(fd, rel=5e-3)
    assert dm_unclipped > 1.5 * fd


# --- Wang ------------------------------------------------------------------------------------------------------------


def _sobel_reflect101(a: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """3x3 Sobel x and y with OpenCV's default border (numpy's "reflect" is reflect-101), in float64."""
    p = np.pad(np.asarray(a, dtype=np.float64), 1, mode="reflect")
    h, w = a.shape
    smooth = (1.0, 2.0, 1.0)
    gx, gy = np.zeros((h, w)), np.zeros((h, w))
    for dy in range(3):
        for dx in range(3):
            win = p[dy:dy + h, dx:dx + w]
            gx += smooth[dy] * (dx - 1) * win
            gy += smooth[dx] * (dy - 1) * win
    return gx, gy


def _wang_w(i: float, a: float = 0.25, b: float = 0.2) -> float:
    if i <= 127:
        return 1.0 / (1.0 + a * math.exp(b * (63.5 - i))) - 0.001
    return 1.0 / (1.0 + a * math.exp(b * (i - 191.5))) - 0.001


WANG_IMG = np.array([[10, 40, 80, 120, 160],
                     [20, 60, 100, 140, 200],
                     [25, 90, 130, 170, 230],
                     [35, 110, 150, 210, 250]], dtype=np.float64)  # 3 pixels < 30, 3 pixels > 225


def test_wang_refinement_matches_an_independent_computation() -> None:
    t_ms = 4.0
    slope8 = 1.0 / (np.arange(256) + 8.0)  # g'(i) = 1/(i + 8) -> 1/(t g'(I)) = (I + 8) / t
    gx, gy = _sobel_reflect101(WANG_IMG)
    jx, jy = _sobel_reflect101((WANG_IMG + 8.0) / t_ms)
    term = 2.0 * (gx * jx + gy * jy)
    w = np.abs(np.vectorize(_wang_w)(WANG_IMG))  # the refinement averages with |W| (quirk fixed)
    with_overrides = np.where(WANG_IMG < 30, 2.0, np.where(WANG_IMG > 225, -2.0, term))
    expected = float(np.sum(w * with_overrides) / np.sum(w))
    assert wang_refinement(WANG_IMG, t_ms, slope8) == pytest.approx(expected, rel=1e-9)
    assert expected == pytest.approx(71161.7772598, rel=1e-9)
    # no override (thresholds out of range): the plain weighted mean of the gradient terms, a different value
    plain = float(np.sum(w * term) / np.sum(w))
    assert wang_refinement(WANG_IMG, t_ms, slope8, low=-1.0, high=1e9) == pytest.approx(plain, rel=1e-9)
    assert abs(plain - expected) > 1.0


def test_wang_refinement_saturation_overrides_exact() -> None:
    """Constant g' -> 1/(t g') is flat, every gradient term is 0: d = (2 sum W[I<30] - 2 sum W[I>225]) / sum W."""
    slope8 = np.full(256, 0.01)
    w = np.abs(np.vectorize(_wang_w)(WANG_IMG))
    low, high = WANG_IMG < 30, WANG_IMG > 225
    expected = (2.0 * w[low].sum() - 2.0 * w[high].sum()) / w.sum()
    assert wang_refinement(WANG_IMG, 4.0, slope8) == pytest.approx(expected, rel=1e-9)
    # the thresholds are strict: 30 and 225 themselves keep their (zero) gradient term
    edge = np.array([[30.0, 225.0], [100.0, 100.0]])
    assert wang_refinement(edge, 4.0, slope8) == 0.0
    # all pixels dark (but with positive weight) -> +2; all bright -> -2, whatever t
    assert wang_refinement(np.full((3, 3), 28.0), 2.0, slope8) == pytest.approx(2.0)
    assert wang_refinement(np.full((3, 3), 228.0), 9.0, slope8) == pytest.approx(-2.0)
    # very dark pixels (W < 0 as published) still push towards a longer exposure, very bright ones shorter
    dark = np.array([[5.0, 5.0], [40.0, 40.0]])
    assert wang_refinement(dark, 4.0, slope8) > 0
    assert wang_refinement(np.array([[250.0, 250.0], [200.0, 200.0]]), 4.0, slope8) < 0


def _wang_gray(t_us: float) -> np.ndarray:
    return bayer_gray(render(irradiance(96, 128), t_us)).astype(np.float64)


def test_wang_search_gamma_direction() -> None:
    dark, bright = _wang_gray(500.0), _wang_gray(30_000.0)
    assert dark.mean() < 0.2 * 4095 and bright.mean() > 0.9 * 4095
    assert WangAE().search_gamma(dark, RESPONSE) > 1.0
    assert WangAE().search_gamma(bright, RESPONSE) < 1.0
    # a flat image has no gradient: every quality is 0, no side beats 1.1 x 0, gamma stays 1
    assert WangAE().search_gamma(np.full((16, 16), 2000.0), RESPONSE) == 1.0


@pytest.mark.parametrize(("peak", "factors", "gamma"), [
    # q(1)=0.745; q(.5)=0.285, q(2)=0.853 > 1.1 q(1) -> gamma 2, alpha .75; q(1.5)=1 > 1.1*0.853 -> gamma 1.5, beta 1.5;
    # q(1.125)=0.853, q(2.25)=0.745 < 1.1 -> shrink both
    (1.5, [0.5, 2.0, 1.5, 4.0, 1.125, 2.25], 1.5),
    # q(1) is the best each time: both factors shrink towards 1 ((1 + x) / 2) and gamma stays 1
    (1.05, [0.5, 2.0, 0.75, 1.5, 0.875, 1.25], 1.0),
])
def test_wang_search_gamma_trace(monkeypatch: pytest.MonkeyPatch, peak: float, factors: list[float],
                                 gamma: float) -> None:
    """The search on a stand-in quality q(f) = 1 / (1 + log2(f / peak)^2) of the exposure factor f."""
    asked: list[float] = []

    def fake_synthesise(gray12: np.ndarray, factor: float, response: Any) -> np.ndarray:
        asked.append(factor)
        return np.full(gray12.shape, 16.0 * factor)  # / 16 in search_gamma -> the factor itself

    def fake_quality(i8: np.ndarray, a: float, b: float) -> float:
        return 1.0 / (1.0 + math.log2(float(np.asarray(i8).flat[0]) / peak) ** 2)

    monkeypatch.setattr(wang, "synthesise", fake_synthesise)
    monkeypatch.setattr(wang, "wang_quality", fake_quality)
    got = WangAE().search_gamma(np.full((2, 2), 16.0), RESPONSE)  # the original image: factor 1
    assert asked == pytest.approx(factors)
    assert got == pytest.approx(gamma)


# --- GP --------------------------------------------------------------------------------------------------------------

GP_X = np.array([0.5, 4.0, 9.0, 15.0, 22.0])
GP_Y = np.array([1.0, 3.0, 2.0, -1.0, 0.5])


def _lml(log_theta: np.ndarray, noise: float) -> float:
    c, length = np.exp(log_theta)
    k = c * np.exp(-0.5 * (GP_X[:, None] - GP_X[None, :]) ** 2 / length**2) + noise * np.eye(len(GP_X))
    _, logdet = np.linalg.slogdet(k)
    return float(-0.5 * GP_Y @ np.linalg.solve(k, GP_Y) - 0.5 * logdet - 0.5 * len(GP_X) * math.log(2 * math.pi))


def test_gp_interpolates_with_tiny_noise() -> None:
    noise = 1e-8
    gp = GaussianProcess1D(noise_var=noise, n_restarts=5, rng=np.random.default_rng(3)).fit(GP_X, GP_Y)
    c, length = (float(v) for v in np.exp(gp.log_theta))
    mu, sd = gp.predict(GP_X)
    np.testing.assert_allclose(mu, GP_Y, atol=1e-6)
    assert np.all(sd < 1e-3)  # ~ sqrt(noise)
    _, mid_sd = gp.predict((GP_X[:-1] + GP_X[1:]) / 2)
    assert np.all(mid_sd > 100 * sd.max())
    _, far_sd = gp.predict(np.array([200.0]))
    assert far_sd[0] == pytest.approx(math.sqrt(c), rel=1e-9)  # the prior sd far from the data
    assert np.all(far_sd[0] > mid_sd)
    # the posterior is the closed form k*^T (K + noise I)^-1 y, c - k*^T (K + noise I)^-1 k* (fitted hyper-parameters)
    kern = c * np.exp(-0.5 * (GP_X[:, None] - GP_X[None, :]) ** 2 / length**2)
    xq = np.array([2.0, 12.0, 30.0])
    ks = c * np.exp(-0.5 * (xq[:, None] - GP_X[None, :]) ** 2 / length**2)
    sol = np.linalg.solve(kern + noise * np.eye(len(GP_X)), np.column_stack([GP_Y, ks.T]))
    q_mu, q_sd = gp.predict(xq)
    np.testing.assert_allclose(q_mu, ks @ sol[:, 0], rtol=1e-6, atol=1e-9)
    np.testing.assert_allclose(q_sd**2, c - np.sum(ks * sol[:, 1:].T, axis=1), rtol=1e-6, atol=1e-9)


def test_gp_hyperparameters_maximise_the_marginal_likelihood() -> None:
    """The fitted (log c, log l) is a local maximum of an independently computed log marginal likelihood."""
    for noise in (1e-8, 0.2):
        gp = GaussianProcess1D(noise_var=noise, n_restarts=10, rng=np.random.default_rng(0)).fit(GP_X, GP_Y)
        best = _lml(gp.log_theta, noise)
        h = 1e-5  # stationary: the central-difference gradient of the LML vanishes there
        for d in (np.array([h, 0.0]), np.array([0.0, h])):
            assert abs(_lml(gp.log_theta + d, noise) - _lml(gp.log_theta - d, noise)) / (2 * h) < 1e-4, (noise, d)
        for step in ([0.05, 0.0], [-0.05, 0.0], [0.0, 0.05], [0.0, -0.05]):
            assert _lml(gp.log_theta + np.array(step), noise) < best, (noise, step)


def test_gp_is_deterministic_for_a_seeded_rng() -> None:
    fits = [GaussianProcess1D(0.2, 10, np.random.default_rng(11)).fit(GP_X, GP_Y) for _ in range(2)]
    np.testing.assert_array_equal(fits[0].log_theta, fits[1].log_theta)
    xq = np.linspace(0.0, 25.0, 7)
    for a, b in zip(fits[0].predict(xq), fits[1].predict(xq), strict=True):
        np.testing.assert_array_equal(a, b)
    # before fit: the prior (mean 0, sd sqrt(c) with c = 1)
    mu, sd = GaussianProcess1D().predict(xq)
    assert np.all(mu == 0.0) and np.all(sd == 1.0)


# --- DRL (constructed actor) -----------------------------------------------------------------------------------------


def _averaging_actor(path: Path, gain: float) -> Path:
    """An actor whose every layer averages its inputs (all weights positive, biases 0, so the ReLUs pass), with a mean
    head gain (0.5 - m): a = tanh(gain (0.5 - m)) for a uniform state of value m."""
    try:
        import torch
    except ImportError:
        missing_component("torch is not installed (pip install -e '.[drl]')")
        raise
    from bracketry_emulator.ae import drl

    actor = drl.build_actor()
    with torch.no_grad():
        for p in actor.parameters():
            p.zero_()
        for layer in (actor.cnn.conv1, actor.cnn.conv2, actor.cnn.conv3, actor.l1, actor.l2):
            layer.weight.fill_(1.0 / layer.weight[0].numel())
        actor.mean_layer.weight.fill_(-gain / actor.mean_layer.weight.numel())
        actor.mean_layer.bias.fill_(0.5 * gain)
    torch.save(actor.state_dict(), path)
    return path


def test_drl_constructed_actor_direction(tmp_path: Path) -> None:
    from bracketry_emulator.ae import get_method
    from bracketry_emulator.ae.drl import DrlAE

    weights = _averaging_actor(tmp_path / "avg.pth", gain=4.0)
    m = get_method("drl", drl_weights=str(weights))
    assert isinstance(m, DrlAE)
    value = 1024.0  # uniform frames -> state 0.25 -> a = tanh(4 (0.5 - 0.25)) = tanh(1)
    assert m.action(np.full((4, 84, 84), value / 4096.0, np.float32)) == pytest.approx(math.tanh(1.0), rel=1e-5)
    scene = irradiance(96, 128)
    for t_us, sign in ((500.0, 1.0), (30_000.0, -1.0)):  # too dark -> a > 0 (longer); too bright -> a < 0
        img = render(scene, t_us)
        m.reset(t_us)
        for k in range(4):  # the classical-50 warm-up while the 4-frame stack fills
            m.next_exposure_us(img, t_us, {"step": k})
        assert m.last_action is None
        nxt = m.next_exposure_us(img, t_us, {"step": 4})
        a = m.last_action
        assert a is not None and sign * a > 0.5, (t_us, a)
        assert nxt == pytest.approx(t_us * 2 ** (2 * a))
