"""Trajectory files, below every module that writes or reads them (VO, the SLAM backends, metrics, the report).

- TUM files: one pose per line, ``t_s tx ty tz qx qy qz qw`` (camera-to-world, metres, seconds);
- a localisation folder's segments: ``CameraTrajectory<n>.txt`` (TUM, one per tracked segment, ``n`` from 0 as the
  ORB-SLAM forks number their maps);
- its per-frame log ``frames.csv`` (:data:`FRAME_FIELDS`).
"""

from __future__ import annotations

import csv
import re
from collections.abc import Iterable
from pathlib import Path
from typing import Any

import numpy as np
from scipy.spatial.transform import Rotation

from bracketry_base.errors import BracketryError

#: the columns of ``frames.csv``, one row per frame fed to the localisation. ``n_keypoints`` and ``coverage``: ORB
#: keypoints at the paper's settings (the same extractor whatever the localisation); ``n_slam_keypoints``: the
#: localisation's own keypoints in the frame (ORB-SLAM3's, whose stereo start needs more than 500; the built-in VO's
#: are its ``n_keypoints``; NaN when unknown)
FRAME_FIELDS = ("t_ns", "state", "segment", "n_keypoints", "coverage", "n_stereo", "n_ref_matches", "n_map_matches",
                "n_slam_keypoints", "reason")


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


def read_segments(trajectory_dir: str | Path) -> list[tuple[np.ndarray, np.ndarray]]:
    """The ``CameraTrajectory*.txt`` segments of a folder (ours or ORB-SLAM2's), ordered by their number."""
    files = list(Path(trajectory_dir).glob("CameraTrajectory*.txt"))

    def key(p: Path) -> int:
        m = re.search(r"(\d+)$", p.stem)
        return int(m.group(1)) if m else -1

    return [read_tum(p) for p in sorted(files, key=key)]


def write_frames_csv(path: Path, frames: Iterable[Any]) -> None:
    """Write ``frames.csv``: one row per frame, each an object with the attributes :data:`FRAME_FIELDS` (the VO's
    ``FrameResult``)."""
    with path.open("w", newline="") as fh:
        w = csv.writer(fh)
        w.writerow(FRAME_FIELDS)
        for f in frames:
            w.writerow([f.t_ns, f.state, f.segment, f.n_keypoints, f"{f.coverage:.6f}", f.n_stereo, f.n_ref_matches,
                        f.n_map_matches, f.n_keypoints, f.reason])


def _count(text: str) -> int | float:
    """A count column: int, or NaN when unknown (imported ORB-SLAM runs)."""
    v = float(text)
    return int(v) if np.isfinite(v) else float("nan")


def read_frames_csv(path: str | Path) -> list[dict]:
    """Rows of a ``frames.csv`` with numeric fields converted (unknown counts are NaN, a file without the
    ``n_slam_keypoints`` column too)."""
    rows = []
    with Path(path).open(newline="") as fh:
        for r in csv.DictReader(fh):
            rows.append({"t_ns": int(r["t_ns"]), "state": r["state"], "segment": int(r["segment"]),
                         "n_keypoints": _count(r["n_keypoints"]), "coverage": float(r["coverage"]),
                         "n_stereo": _count(r["n_stereo"]), "n_ref_matches": _count(r["n_ref_matches"]),
                         "n_map_matches": _count(r["n_map_matches"]),
                         "n_slam_keypoints": _count(r.get("n_slam_keypoints") or "nan"),
                         "reason": r.get("reason") or ""})
    return rows
