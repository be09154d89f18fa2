"""Each frame at its own exposure interval: motion blur by reprojection, per-frame timing and ground truth."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np
import pytest

from bracketry_emulator.synth import World, blur, write_trajectory
from bracketry_emulator.synth.calibration import CameraIntrinsics
from bracketry_emulator.synth.trajectory import LoopTrajectory, matrix_from_quat
from bracketry_emulator.synth.writer import DEFAULT_T0_NS

#: variance (px^2) of bilinear interpolation between samples 2 px apart at phases spread over a pixel: 2^2 / 6
_BILINEAR_VAR_PX2 = 4.0 / 6.0


def _edge_spread_px(exposure_us: float, speed_mps: float, depth_m: float = 1.0) -> tuple[float, float]:
    """A vertical step edge on a wall ``depth_m`` in front of a camera moving sideways at ``speed_mps``, blurred over
    ``exposure_us``: (the blur length estimated from the edge's spread, pixels; the expected exposure x image speed).

    The spread: the derivative of a box blur of length L has variance L^2 / 12, added to the variance of the
    interpolation's own edge (a triangle of half-width 2 px: the plane's samples are 2 px apart)."""
    w, h, fx = 240, 8, 200.0
    intr = CameraIntrinsics(w, h, fx, fx, (w - 1) / 2, (h - 1) / 2, (0.0, 0.0, 0.0, 0.0, 0.0))
    rays = intr.pixel_rays().reshape(3, -1)
    cells = blur.CellRays.of(rays, w, h)
    range_m = (depth_m / rays[2]).reshape(h, w).astype(np.float32)  # a fronto-parallel wall
    radiance = np.where(np.arange(w)[None, :] < w // 2, 1.0, 0.1).astype(np.float32).repeat(h, 0)
    span_s = exposure_us * 1e-6
    R = np.eye(3)

    def at(t: float) -> np.ndarray:
        return np.array([speed_mps * t, 0.0, 0.0])

    def spread_var(span: float) -> float:
        s0 = blur.cell_flow(cells, range_m, intr, R, at(0.0), R, at(-span / 2))
        s1 = blur.cell_flow(cells, range_m, intr, R, at(0.0), R, at(span / 2))
        inv = np.float32(1.0 / span)
        motion = blur.Motion(0.0, None, None, (s1[0] - s0[0]) * inv, (s1[1] - s0[1]) * inv)
        times = blur.sub_instants(-span / 2, span * 1e6, motion.max_px(span), 1.0)
        img = blur.average_warps(radiance, cells, motion, times)
        row = img[0, 1::2].astype(np.float64)  # one channel plane: samples 2 px apart
        d = np.abs(np.diff(row))
        x = 2.0 * np.arange(d.size)
        mean = (d * x).sum() / d.sum()
        return float((d * (x - mean) ** 2).sum() / d.sum())

    assert spread_var(1e-9) < 1e-6  # no motion: the step itself
    length = float(np.sqrt(12.0 * max(0.0, spread_var(span_s) - _BILINEAR_VAR_PX2)))
    return length, fx * speed_mps / depth_m * span_s


@pytest.mark.parametrize(("exposure_us", "speed_mps"), [(8000, 1.4), (16000, 1.4), (32000, 0.7), (32000, 1.4),
                                                         (32000, 2.8), (16000, 2.8)])
def test_moving_edge_blur_width_is_exposure_times_image_speed(exposure_us: float, speed_mps: float) -> None:
    """Blur length = exposure x image speed within 10 % (+ 0.5 px): 1.1 .. 15.7 px here."""
    length, expected = _edge_spread_px(exposure_us, speed_mps)
    assert length == pytest.approx(expected, rel=0.10, abs=0.5), (length, expected)


def test_blur_is_a_continuous_streak() -> None:
    """A 32 ms frame at walking speed: consecutive instants move the image at most blur_px (1 px), not a few ghosts;
    a 1 ms frame is one instant."""
    world = World("forest-winter", seed=0, resolution=(160, 100), trajectory=LoopTrajectory(speed_kmh=5.0))
    times = world.blur_times_s(3.0, 32000.0)
    motion = world.motions("left", world.mid_exposure_s(3.0, 32000.0), [(3.0, 32000.0)])[0]
    moved = motion.max_px(0.032)
    assert moved > 2.0 and len(times) >= moved
    assert moved / len(times) <= 1.0
    assert world.blur_times_s(3.0, 1000.0) == [world.mid_exposure_s(3.0, 1000.0)]


def test_blur_off_is_the_instantaneous_render_at_mid_exposure() -> None:
    sharp = World("forest-winter", seed=0, resolution=(96, 60), motion_blur=False)
    t, e = 2.0, 32000.0
    assert np.array_equal(sharp.rate_e_per_us("left", t, e), sharp.rate_e_per_us("left", t + 0.016))
    assert sharp.blur_times_s(t, e) == [t + 0.016]
    blurred = World("forest-winter", seed=0, resolution=(96, 60), trajectory=LoopTrajectory(speed_kmh=5.0))
    sharp = World("forest-winter", seed=0, resolution=(96, 60), trajectory=LoopTrajectory(speed_kmh=5.0),
                  motion_blur=False)
    assert len(blurred.blur_times_s(t, 1000.0)) == 1  # under a pixel of motion: one instant, the render itself
    assert np.array_equal(blurred.rate_e_per_us("left", t, 1000.0), sharp.rate_e_per_us("left", t, 1000.0))
    assert not np.array_equal(blurred.rate_e_per_us("left", t, e), sharp.rate_e_per_us("left", t, e))


@dataclass
class _Standing(LoopTrajectory):
    """The walk's start, held."""

    def pose(self, t_s: float) -> tuple[np.ndarray, np.ndarray]:
        return super().pose(0.0)


def test_static_camera_blur_changes_nothing() -> None:
    kw = {"resolution": (96, 60), "trajectory": _Standing()}
    blurred, sharp = World("campus-summer", seed=1, **kw), World("campus-summer", seed=1, motion_blur=False, **kw)
    for e in (1000.0, 32000.0):
        assert len(blurred.blur_times_s(1.0, e)) == 1
        assert np.array_equal(blurred.render("left", 1.0, e), sharp.render("left", 1.0, e))


def test_reprojection_follows_the_full_render() -> None:
    """The render moved 100 ms along a 5 km/h walk is far closer to the full render there than the unmoved one
    (mean |log radiance| error), and its error stays near that of a move of a few pixels (aliasing, occlusions)."""
    world = World("forest-winter", seed=0, resolution=(320, 200), trajectory=LoopTrajectory(speed_kmh=5.0))
    ref_t = 3.0
    ref = world.radiance("left", ref_t).radiance

    def log_err(a: np.ndarray, b: np.ndarray) -> float:
        return float(np.abs(np.log(a + 1e-3) - np.log(b + 1e-3)).mean())

    errs = {}
    for dt in (0.016, 0.1):
        m = world.motions("left", ref_t, [(ref_t + dt, 1.0)])[0]
        moved = blur.average_warps(ref, world._cells("left"), m, [m.t_s])
        true = world.radiance("left", m.t_s).radiance
        errs[dt] = (log_err(moved, true), log_err(ref, true))
    assert errs[0.1][0] < 0.5 * errs[0.1][1]
    assert errs[0.1][0] < 1.5 * errs[0.016][0]


def _tum(path: Path) -> list[tuple[int, np.ndarray]]:
    rows = []
    for line in path.read_text().splitlines():
        if line.startswith("#"):
            continue
        v = line.split()
        sec, _, frac = v[0].partition(".")
        T = np.eye(4)
        T[:3, :3] = matrix_from_quat(np.array([float(x) for x in v[4:8]]))
        T[:3, 3] = [float(x) for x in v[1:4]]
        rows.append((int(sec) * 1_000_000_000 + int(frac), T))
    return rows


def test_brackets_of_one_cycle_are_each_at_their_own_instant(tmp_path: Path) -> None:
    """write_trajectory: frame k triggered at k / fps, stamped and posed at its mid-exposure; its pixels are the
    world's frame over its own interval (not the cycle's first instant)."""
    world = World("forest-winter", seed=2, resolution=(64, 40), trajectory=LoopTrajectory(speed_kmh=4.0))
    brackets_ms = (1.0, 2.0, 4.0, 8.0, 16.0, 32.0)
    write_trajectory(world, tmp_path, seconds=0.27, brackets_ms=brackets_ms, fps=22.0, sides=("left",))
    gt = _tum(tmp_path / "groundtruth.txt")
    assert len(gt) == 6
    poses = []
    for k, (stamp_ns, T) in enumerate(gt):
        e_us = brackets_ms[k] * 1000.0
        assert stamp_ns == DEFAULT_T0_NS + round((k / 22.0 + e_us * 0.5e-6) * 1e9)
        assert np.allclose(T, world.pose(k / 22.0 + e_us * 0.5e-6), atol=1e-8)
        poses.append(T[:3, 3])
        img = cv2.imread(str(tmp_path / "camera_left" / str(brackets_ms[k]) / f"{stamp_ns}.png"), cv2.IMREAD_UNCHANGED)
        assert np.array_equal(img, world.render("left", k / 22.0, e_us))
        if k:
            assert not np.array_equal(world.render("left", 0.0, e_us, noise=False),
                                      world.render("left", k / 22.0, e_us, noise=False))
    steps = np.linalg.norm(np.diff(np.array(poses), axis=0), axis=1)
    assert (steps > 0.01).all()  # 4 km/h: ~5 cm between brackets


def test_one_render_per_instant_is_the_dense_integral() -> None:
    """blur_renders >= the number of instants: every instant ray cast, i.e. the mean of full renders ("render")."""
    kw = {"resolution": (96, 60), "trajectory": LoopTrajectory(speed_kmh=5.0)}
    dense = World("forest-winter", seed=0, blur_method="render", **kw)
    many = World("forest-winter", seed=0, blur_renders=64, **kw)
    t, e = 3.0, 32000.0
    assert len(dense.blur_times_s(t, e)) >= 2
    assert np.allclose(many.rate_e_per_us("left", t, e), dense.rate_e_per_us("left", t, e), rtol=1e-5, atol=1e-7)
    two = World("forest-winter", seed=0, blur_renders=2, **kw).rate_e_per_us("left", t, e)
    one = World("forest-winter", seed=0, **kw).rate_e_per_us("left", t, e)
    assert not np.array_equal(two, one) and float(two.mean()) == pytest.approx(float(one.mean()), rel=0.05)
