"""How far a camera turns over each bracket cycle, and how much that turn changes from one cycle to the next.

A localisation fed once per bracket cycle predicts the next pose from the last two (ORB-SLAM's constant-velocity
model): what it gets wrong is the change between consecutive cycles' turns. Both figures come from a gyro (the real
sample's ``imu/imu.csv``) or from poses (a synthetic walk's ``groundtruth.txt``), so the suite's gait can be set
against the real backpack's motion (emulator/DATASET.md, the gait paragraph).
"""

from __future__ import annotations

import numpy as np
from scipy.spatial.transform import Rotation, Slerp

#: the rig's bracket cycle: six brackets at 22 frames/s (s)
BRACKET_CYCLE_S = 6.0 / 22.0


def cycle_turns_from_gyro(times_s: np.ndarray, gyro_rad_s: np.ndarray,
                          cycle_s: float = BRACKET_CYCLE_S) -> np.ndarray:
    """Rotation vectors (rad) of each whole cycle of ``cycle_s`` from a gyro's samples.

    Args:
        times_s: float (N,) sample times, increasing, seconds.
        gyro_rad_s: float (N, 3) angular rates, rad/s, in the body frame.
        cycle_s: the cycle's length, s.
    Returns:
        float64 (K, 3): the rate integrated over each cycle (each sample held until the next, the integral read
        between samples linearly at the cycle's edges); K whole cycles from the first sample. It is the cycle's
        rotation vector when the axis keeps still over the cycle, and differs from it by second-order terms in the
        angle otherwise.
    """
    t = np.asarray(times_s, np.float64)
    g = np.asarray(gyro_rad_s, np.float64)
    if t.ndim != 1 or g.shape != (len(t), 3) or len(t) < 2:
        raise ValueError("times_s (N,) and gyro_rad_s (N, 3) with N >= 2 required")
    t = t - t[0]
    # the integral up to each sample time (each rate held until the next sample), read at the cycles' edges
    cum = np.concatenate([np.zeros((1, 3)), np.cumsum(g[:-1] * np.diff(t)[:, None], axis=0)])
    edges = np.arange(0.0, t[-1] + 1e-12, cycle_s)
    at_edges = np.stack([np.interp(edges, t, cum[:, k]) for k in range(3)], axis=1)
    return np.diff(at_edges, axis=0)


def cycle_turns_from_poses(times_s: np.ndarray, poses_wc: np.ndarray,
                           cycle_s: float = BRACKET_CYCLE_S) -> np.ndarray:
    """Rotation vectors (rad, in the body frame at each cycle's start) of each whole cycle from poses.

    Args:
        times_s: float (M,) pose times, increasing, seconds (M >= 2).
        poses_wc: float (M, 4, 4) body-to-world poses (as :func:`~bracketry_emulator.trajectory_io.read_tum` reads
            them); only their rotations are used.
        cycle_s: the cycle's length, s.
    Returns:
        float64 (K, 3): the rotation from each cycle's start to its end, orientations interpolated (slerp).
    """
    t = np.asarray(times_s, np.float64)
    if t.ndim != 1 or len(t) < 2:
        raise ValueError("times_s (M,) with M >= 2 required")
    t = t - t[0]
    return turns_between(t, poses_wc, np.arange(0.0, t[-1] + 1e-12, cycle_s))


def turns_between(times_s: np.ndarray, poses_wc: np.ndarray, sample_times_s: np.ndarray) -> np.ndarray:
    """Rotation vectors (rad, in the body frame at each step's start) from each sample time to the next.

    Args:
        times_s: float (M,) pose times, increasing, seconds (M >= 2); poses_wc: float (M, 4, 4) body-to-world poses.
        sample_times_s: float (K,) times within ``times_s``'s span, seconds.
    Returns:
        float64 (K - 1, 3), orientations interpolated (slerp).
    """
    slerp = Slerp(np.asarray(times_s, np.float64), Rotation.from_matrix(np.asarray(poses_wc, np.float64)[:, :3, :3]))
    r = slerp(np.asarray(sample_times_s, np.float64))
    return np.asarray((r[:-1].inv() * r[1:]).as_rotvec(), np.float64)


def turn_and_change_deg(turns_rad: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(turn, change), degrees: each cycle's rotation angle, float64 (K,), and the angle of the difference between
    consecutive cycles' rotation vectors, float64 (K - 1,) (what a constant-velocity prediction misses).

    Args:
        turns_rad: float (K, 3) rotation vectors of consecutive cycles, rad.
    """
    v = np.asarray(turns_rad, np.float64)
    return np.degrees(np.linalg.norm(v, axis=1)), np.degrees(np.linalg.norm(np.diff(v, axis=0), axis=1))


def frame_turn_change_deg(gt_times_s: np.ndarray, gt_poses_wc: np.ndarray, frame_times_s: np.ndarray) -> np.ndarray:
    """Per frame of a localisation fed once per cycle, what its constant-velocity prediction misses: the change from
    the camera's turn over the step before to its turn into this frame (:func:`turn_and_change_deg`'s change, over
    the frames' own steps), degrees.

    Args:
        gt_times_s: float (M,) reference times, increasing, seconds (M >= 2); gt_poses_wc: float (M, 4, 4)
            camera-to-world poses.
        frame_times_s: float (N,) the frames' stamps, seconds.
    Returns:
        float (N,) degrees; NaN for the first two frames and where a frame of the three lies outside the reference.
    """
    t = np.asarray(frame_times_s, np.float64)
    out = np.full(t.shape, np.nan)
    gt_t = np.asarray(gt_times_s, np.float64)
    inside = (t >= gt_t[0]) & (t <= gt_t[-1]) if len(gt_t) >= 2 else np.zeros(t.shape, bool)
    if np.count_nonzero(inside) < 3:
        return out
    samples = np.where(inside, t, gt_t[0]) - gt_t[0]  # times from the reference's start: stamps in ns keep digits
    _, change = turn_and_change_deg(turns_between(gt_t - gt_t[0], gt_poses_wc, samples))
    ok = inside[:-2] & inside[1:-1] & inside[2:]
    out[2:][ok] = change[ok]
    return out
