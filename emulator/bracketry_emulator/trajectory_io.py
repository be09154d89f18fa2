"""TUM trajectory files: one pose per line, ``t_s tx ty tz qx qy qz qw`` (camera-to-world, metres, seconds)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
from scipy.spatial.transform import Rotation

from bracketry.errors import BracketryError


def write_tum(path: str | Path, times_s: np.ndarray | list[float], poses_wc: np.ndarray | list[np.ndarray]) -> None:
    """Write N poses (float64 Nx4x4 camera-to-world) with their times (seconds) as a TUM file."""
    lines = []
    for t, T in zip(times_s, poses_wc):
        q = Rotation.from_matrix(np.asarray(T)[:3, :3]).as_quat()  # x y z w
        p = np.asarray(T)[:3, 3]
        lines.append(f"{float(t):.9f} {p[0]:.9f} {p[1]:.9f} {p[2]:.9f} {q[0]:.9f} {q[1]:.9f} {q[2]:.9f} {q[3]:.9f}")
    Path(path).write_text("".join(line + "\n" for line in lines))


def read_tum(path: str | Path) -> tuple[np.ndarray, np.ndarray]:
    """Read a TUM file: (times_s float64 N, poses_wc float64 Nx4x4). Comment lines (#) are skipped."""
    try:
        rows = [line.split() for line in Path(path).read_text().splitlines()
                if line.strip() and not line.lstrip().startswith("#")]
        data = np.array(rows, dtype=np.float64).reshape(-1, 8) if rows else np.zeros((0, 8))
    except (OSError, ValueError) as exc:
        raise BracketryError(f"cannot read TUM trajectory {path}: {exc}") from exc
    poses = np.tile(np.eye(4), (len(data), 1, 1))
    if len(data):
        poses[:, :3, :3] = Rotation.from_quat(data[:, 4:8]).as_matrix()
        poses[:, :3, 3] = data[:, 1:4]
    return data[:, 0], poses
