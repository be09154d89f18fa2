"""Motion-blur emulation: nothing changes on a static scene; a moving edge gets the true blur width."""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from bracketry_emulator.emulation import Emulator, EmulatorConfig
from bracketry_emulator.emulation.blur import MAX_SAMPLES, Velocity, add_motion_blur, copy_shifts_s
from emu_synthetic import BRACKETS_US, SRGB, radiance_map, render

PERIOD_NS = 45_454_545  # 22 fps, as a synthetic trajectory


def _times(exposures: tuple[int, ...]) -> dict[int, int]:
    """Mid-exposure stamps of one bracket cycle triggered PERIOD_NS apart."""
    return {e: k * PERIOD_NS + e * 500 for k, e in enumerate(exposures)}


def test_blur_emulation_of_a_static_scene_changes_nothing() -> None:
    rng = np.random.default_rng(4)
    irr = radiance_map(h=120, w=160, seed=4) * 0.05
    imgs = {e: render(irr, e, rng) for e in BRACKETS_US}
    times = _times(BRACKETS_US)
    plain = Emulator(EmulatorConfig())
    blur = Emulator(EmulatorConfig(blur=True))
    for target, source in ((16_000.0, 4000), (32_000.0, 2000), (12_000.0, 8000), (3000.0, 2000)):
        a = plain.emulate(imgs, target, source_us=source, times_ns=times)
        b = blur.emulate(imgs, target, source_us=source, times_ns=times)
        np.testing.assert_array_equal(a.image, b.image)


def _moving_scene(exposure_us: int, trigger_s: float, v_px_s: float, h: int = 128, w: int = 384) -> np.ndarray:
    """Irradiance (DN/us) of a scene moving right at ``v_px_s``, integrated over the exposure: float64 HxW. Two
    vertical step edges (dark 0.02, bright 0.20 DN/us: unsaturated up to 16 ms) on a smooth random texture (+-10 %),
    so the optical flow has texture to follow; sampled at 1/8 px steps of the motion."""
    rng = np.random.default_rng(7)
    over = 8  # sub-pixel grid of the pattern
    n_x = (w + 2048) * over
    tex = np.cumsum(rng.standard_normal((h, n_x // over)), axis=1)
    tex = np.repeat(tex - tex.mean(axis=1, keepdims=True), over, axis=1)
    tex = 0.1 * tex / np.abs(tex).max()
    xs = np.arange(n_x) / over
    step = ((xs % 256.0) < 128.0).astype(np.float64)
    pattern = (0.02 + 0.18 * step)[None, :] * (1.0 + tex)
    x_idx = np.arange(w) * over + 1024 * over
    n = max(1, round(v_px_s * exposure_us * 1e-6 * over))
    acc = np.zeros((h, w))
    for k in range(n):
        shift_px = v_px_s * (trigger_s + (k + 0.5) / n * exposure_us * 1e-6)
        acc += pattern[:, x_idx - round(shift_px * over)]
    return acc / n


def _rise_width_px(row: np.ndarray) -> float:
    """10-90 % width (px) of the first rising edge of a 1-D profile (linear levels)."""
    lo, hi = float(np.percentile(row, 2)), float(np.percentile(row, 98))
    a, b = lo + 0.1 * (hi - lo), lo + 0.9 * (hi - lo)
    start = int(np.argmax(row < a))
    i10 = start + int(np.argmax(row[start:] >= a))
    i90 = i10 + int(np.argmax(row[i10:] >= b))

    def cross(i: int, level: float) -> float:  # linear interpolation between i - 1 and i
        return i - 1 + (level - row[i - 1]) / (row[i] - row[i - 1])

    return cross(i90, b) - cross(i10, a)


def test_emulated_blur_of_a_moving_edge_has_the_true_width() -> None:
    """Bars moving 500 px/s: the 16 ms target has a ramp of 8 px (10-90 %: 6.4 px), the 2 ms source one of 1 px.
    Emulated from the 2 ms bracket with the flow to the 4 ms bracket one frame later, the width is within 8 % of the
    true one (8 copies 2 ms apart: the true 8 px box, up to the flow's error; measured 5 %); without blur emulation
    it is 1 px."""
    v = 500.0
    s_us, n_us, t_us = 2000, 4000, 16_000
    imgs = {s_us: render(_moving_scene(s_us, 0.0, v), s_us),
            n_us: render(_moving_scene(n_us, PERIOD_NS * 1e-9, v), n_us)}
    times = {s_us: s_us * 500, n_us: PERIOD_NS + n_us * 500}
    truth = SRGB.icrf[render(_moving_scene(t_us, 0.0, v), t_us)][64, :].astype(np.float64)
    out = Emulator(EmulatorConfig(blur=True, beyond="extrapolate")).emulate(imgs, t_us, source_us=s_us, times_ns=times)
    plain = Emulator(EmulatorConfig(beyond="extrapolate")).emulate(imgs, t_us, source_us=s_us, times_ns=times)
    true_w = _rise_width_px(truth)
    assert true_w == pytest.approx(6.4, abs=0.6)
    emulated_w = _rise_width_px(SRGB.icrf[out.image][64, :].astype(np.float64))
    plain_w = _rise_width_px(SRGB.icrf[plain.image][64, :].astype(np.float64))
    assert emulated_w == pytest.approx(true_w, rel=0.08), (emulated_w, true_w, plain_w)
    assert plain_w < 0.4 * true_w


def test_copies_are_at_most_one_source_exposure_apart() -> None:
    """T a whole multiple of S: T / S copies exactly S apart (the true box); otherwise ceil(T / S) copies spread over
    the path, closer than S; copies closer than STEP_PX along the path: fewer, at most STEP_PX apart."""
    np.testing.assert_allclose(copy_shifts_s(0.014, 0.002, 20.0), np.arange(8) * 0.002, atol=1e-12)
    odd = copy_shifts_s(0.010, 0.003, 20.0)  # T = 13 ms: 5 copies 2.5 ms apart
    assert len(odd) == 5 and odd[0] == 0.0 and odd[-1] == pytest.approx(0.010)
    assert np.diff(odd).max() < 0.003
    assert len(copy_shifts_s(0.031, 0.001, 3.0)) == 7  # 32 copies would be 0.1 px apart: 7, 0.5 px apart
    assert len(copy_shifts_s(0.031, 0.0001, 100.0)) == MAX_SAMPLES
    assert len(copy_shifts_s(0.004, None, 3.0)) == 7  # no source exposure: one per STEP_PX of the longest path
    assert len(copy_shifts_s(0.004, 0.004, 0.6)) == 2


def _mosaic(gray: np.ndarray, gains: tuple[float, float, float, float]) -> np.ndarray:
    """An RGGB mosaic float32 (H, W) of a scene of one colour (plane gains, order (0, 0), (0, 1), (1, 0), (1, 1))."""
    out = gray.astype(np.float32)
    for (dy, dx), g in zip(((0, 0), (0, 1), (1, 0), (1, 1)), gains, strict=True):
        out[dy::2, dx::2] *= np.float32(g)
    return out


def _planes_moved_alone(mosaic: np.ndarray, shift_px: float) -> np.ndarray:
    """The mean of ``mosaic`` and its copy moved ``shift_px`` full-resolution pixels right, each colour plane moved
    on its own grid (bilinear): what the emulator did before it moved the luminance at full resolution."""
    out = mosaic.copy()
    for dy in (0, 1):
        for dx in (0, 1):
            plane = np.ascontiguousarray(mosaic[dy::2, dx::2])
            m = np.float32([[1, 0, -shift_px / 2], [0, 1, 0]])
            moved = cv2.warpAffine(plane, m, plane.shape[::-1], flags=cv2.INTER_LINEAR | cv2.WARP_INVERSE_MAP,
                                   borderMode=cv2.BORDER_REPLICATE)
            out[dy::2, dx::2] = 0.5 * (plane + moved)
    return out


def test_a_uniform_colour_keeps_its_colour_and_fine_detail_moves_at_full_resolution() -> None:
    """A scene of one colour (red twice green, blue half) moving 1 full-resolution pixel to the right over the
    missing time (T = 2 S: two copies): a flat patch comes out unchanged (no colour from the ratios). An edge
    centred between the two columns of a 2x2 cell (detail no colour plane resolves alone) lands where the truth has
    it: a 2 px ramp (what a lens and the pixels' area make of an edge) within a fifth of the error of moving each
    plane on its own grid; a hard step (aliased: each plane sees it a pixel apart, so its colour ratio is off there)
    still closer than that."""
    gains = (2.0, 1.0, 1.0, 0.5)
    h, w = 64, 96
    flat = _mosaic(np.full((h, w), 500.0), gains)
    v = Velocity(np.full((h // 2, w // 2), 50.0, np.float32), np.zeros((h // 2, w // 2), np.float32))  # 0.5 px / 10 ms
    np.testing.assert_allclose(add_motion_blur(flat, v, 0.010, 0.010), flat, rtol=1e-5)
    x = np.arange(w, dtype=np.float64)[None, :].repeat(h, axis=0)
    for ramp_px, ratio in ((2.0, 0.2), (1e-6, 0.75)):
        def scene(xs: np.ndarray, ramp: float = ramp_px) -> np.ndarray:
            return _mosaic(np.clip((xs - 46.5) / ramp + 0.5, 0.0, 1.0) * 900.0 + 100.0, gains)

        source, truth = scene(x), 0.5 * (scene(x) + scene(x - 1.0))

        def err(a: np.ndarray, t: np.ndarray = truth) -> float:
            return float(np.sqrt(np.mean((a - t)[8:-8, 8:-8] ** 2)))

        emulated, planes_alone = add_motion_blur(source, v, 0.010, 0.010), _planes_moved_alone(source, 1.0)
        assert err(planes_alone) > 0.3 * err(source)  # the old way: far from the truth
        assert err(emulated) < ratio * err(planes_alone), (ramp_px, err(emulated), err(planes_alone), err(source))


def test_blur_is_a_closed_loop_setting_in_the_cache_key() -> None:
    from bracketry_emulator.ae import LoopConfig

    on = LoopConfig(emulator=EmulatorConfig(blur=True))
    assert on.to_json()["blur"] is True and on.round_trips()
    assert "blur" not in LoopConfig().to_json()  # keys of runs without it are unchanged
