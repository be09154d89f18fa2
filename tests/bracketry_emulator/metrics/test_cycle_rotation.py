"""Turn per bracket cycle and its change, from a gyro and from poses, against motions whose figures are known."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from bracketry_emulator.metrics.cycle_rotation import (
    BRACKET_CYCLE_S,
    cycle_turns_from_gyro,
    cycle_turns_from_poses,
    turn_and_change_deg,
)

RATE_HZ = 1000.0
DURATION_S = 6.0


def _poses(rotations: Rotation) -> np.ndarray:
    """float64 (M, 4, 4) poses of those orientations (at the origin)."""
    poses = np.tile(np.eye(4), (len(rotations), 1, 1))
    poses[:, :3, :3] = rotations.as_matrix()
    return poses


def _yaw_motion(amplitude_rad: float, freq_hz: float, steady_rad_s: float) -> tuple[np.ndarray, ...]:
    """A turn about the body's z axis: yaw(t) = steady t - A cos(2 pi f t) (rate steady + A 2 pi f sin(2 pi f t)).
    Returns (t (N,), gyro (N, 3), poses (N, 4, 4), yaw (N,))."""
    t = np.arange(0.0, DURATION_S, 1.0 / RATE_HZ)
    w = 2 * np.pi * freq_hz
    yaw = steady_rad_s * t - amplitude_rad * np.cos(w * t)
    rate = steady_rad_s + amplitude_rad * w * np.sin(w * t)
    gyro = np.stack([np.zeros_like(t), np.zeros_like(t), rate], axis=1)
    return t, gyro, _poses(Rotation.from_euler("z", yaw[:, None])), yaw


def test_a_steady_turn_has_no_change() -> None:
    t, gyro, poses, _ = _yaw_motion(0.0, 1.0, np.radians(10.0))
    for turns in (cycle_turns_from_gyro(t, gyro), cycle_turns_from_poses(t, poses)):
        turn, change = turn_and_change_deg(turns)
        assert len(turn) == int((DURATION_S - 1.0 / RATE_HZ) / BRACKET_CYCLE_S)  # whole cycles within the samples
        np.testing.assert_allclose(turn, 10.0 * BRACKET_CYCLE_S, rtol=2e-3)
        np.testing.assert_allclose(change, 0.0, atol=0.02)


def test_a_gait_near_half_the_cycle_rate_changes_more_than_it_turns() -> None:
    """A 1.7-Hz oscillation sampled every 0.27 s: the cycle's turn is the yaw's difference over the cycle and the
    change its second difference, which at 0.46 oscillations a cycle is nearly twice the turn."""
    amp = np.radians(1.0)
    t, gyro, poses, yaw = _yaw_motion(amp, 1.7, 0.0)
    edges = np.round(np.arange(0.0, t[-1], BRACKET_CYCLE_S) * RATE_HZ).astype(int)
    expected_turn = np.diff(yaw[edges])
    expected = np.degrees(np.abs(expected_turn)), np.degrees(np.abs(np.diff(expected_turn)))
    for turns in (cycle_turns_from_gyro(t, gyro), cycle_turns_from_poses(t, poses)):
        turn, change = turn_and_change_deg(turns)
        n = min(len(turn), len(expected[0]))
        np.testing.assert_allclose(turn[:n], expected[0][:n], atol=0.02)
        np.testing.assert_allclose(change[: n - 1], expected[1][: n - 1], atol=0.03)
    assert np.median(change) > 1.5 * np.median(turn)


def test_gyro_and_poses_agree_on_a_tilted_axis() -> None:
    t = np.arange(0.0, 3.0, 1.0 / RATE_HZ)
    axis = np.array([0.3, -0.5, 0.8]) / np.linalg.norm([0.3, -0.5, 0.8])
    rate = np.radians(12.0) * (1.0 + 0.5 * np.sin(2 * np.pi * 0.9 * t))
    angle = np.concatenate([[0.0], np.cumsum(rate[:-1] / RATE_HZ)])
    poses = _poses(Rotation.from_rotvec(angle[:, None] * axis))
    a = cycle_turns_from_gyro(t, rate[:, None] * axis)
    b = cycle_turns_from_poses(t, poses)
    n = min(len(a), len(b))
    np.testing.assert_allclose(a[:n], b[:n], atol=np.radians(0.01))


def test_bad_shapes_are_refused() -> None:
    with pytest.raises(ValueError):
        cycle_turns_from_gyro(np.zeros(5), np.zeros((5, 2)))
    with pytest.raises(ValueError):
        cycle_turns_from_poses(np.zeros(1), np.tile(np.eye(4), (1, 1, 1)))


def test_a_frames_turn_change_is_what_a_constant_rate_turn_does_not_have() -> None:
    """Frames every 0.25 s: a steady yaw at 0.4 rad/s misses nothing; a yaw rate stepping from 0.4 to 0.8 rad/s at
    t = 1 s misses 0.1 rad (5.73 degrees) once; frames outside the reference and the first two are NaN."""
    from bracketry_emulator.metrics.cycle_rotation import frame_turn_change_deg

    t = np.linspace(0.0, 2.0, 401)
    poses = np.tile(np.eye(4), (len(t), 1, 1))
    poses[:, :3, :3] = Rotation.from_euler("z", 0.4 * t[:, None]).as_matrix()
    frames = np.array([0.0, 0.25, 0.5, 0.75, 1.0, 1.25, 2.5])
    steady = frame_turn_change_deg(t, poses, frames)
    assert np.isnan(steady[:2]).all() and np.isnan(steady[-1])
    np.testing.assert_allclose(steady[2:-1], 0.0, atol=1e-9)
    yaw = np.where(t <= 1.0, 0.4 * t, 0.4 + 0.8 * (t - 1.0))
    poses[:, :3, :3] = Rotation.from_euler("z", yaw[:, None]).as_matrix()
    stepped = frame_turn_change_deg(t, poses, frames[:-1])
    np.testing.assert_allclose(stepped[2:], [0.0, 0.0, 0.0, np.degrees(0.1)], atol=1e-6)
