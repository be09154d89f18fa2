"""All metrics of one (trajectory, method) run: features, robustness, RTE/RRE per window."""

from __future__ import annotations

import re
from pathlib import Path

import numpy as np

from bracketry_emulator.metrics.failures import robustness, tracked_distance_fraction
from bracketry_emulator.metrics.rpe import DEFAULT_WINDOWS_M, relative_errors, trajectory_rte_rre
from bracketry_emulator.vo.runner import read_frames_csv
from bracketry_emulator.vo.tum import read_tum


def read_segments(trajectory_dir: str | Path) -> list[tuple[np.ndarray, np.ndarray]]:
    """The ``CameraTrajectory*.txt`` segments of a folder (ours or ORB-SLAM2's), ordered by their number."""
    files = list(Path(trajectory_dir).glob("CameraTrajectory*.txt"))

    def key(p: Path) -> int:
        m = re.search(r"(\d+)$", p.stem)
        return int(m.group(1)) if m else -1

    return [read_tum(p) for p in sorted(files, key=key)]


#: next to a ground truth file: time stamps (ns, one per line) of frames whose pose is not known
UNKNOWN_POSES_FILE = "groundtruth_unknown.txt"


def frames_without_pose(groundtruth: str | Path, frame_times_ns: list[int]) -> int:
    """How many of ``frame_times_ns`` (or of all listed frames when the list is empty) are listed in the
    :data:`UNKNOWN_POSES_FILE` next to ``groundtruth`` (0 when there is none)."""
    path = Path(groundtruth).parent / UNKNOWN_POSES_FILE
    if not path.is_file():
        return 0
    listed = {int(line) for line in path.read_text().split() if line.strip().isdigit()}
    return len(listed & set(frame_times_ns)) if frame_times_ns else len(listed)


def evaluate_run(vo_dir: str | Path, groundtruth: str | Path | None,
                 windows_m: tuple[float, ...] = DEFAULT_WINDOWS_M) -> dict:
    """Metrics of a VO output folder (``frames.csv`` + ``CameraTrajectory<n>.txt``) against a TUM reference.

    Returns a JSON-ready dict: n_frames, success, time_before_failure_s, duration_s, tracked_fraction,
    n_segments, coverage_mean (fraction, all frames), matches_mean (matches to map, all frames),
    keypoints_mean, rte_pct, rre_deg_per_m, tracked_distance_fraction (NaN without reference), ``reference``
    ("groundtruth" or "no reference: <why>"), windows: list of {window_m, n_pairs, rte_pct, rre_deg_per_m}, and
    per-frame lists coverage, matches. When frames of the run are listed in :data:`UNKNOWN_POSES_FILE` next to the
    reference, RTE/RRE stay NaN and ``rte_refused`` (and ``reference``) say why.
    """
    frames = read_frames_csv(Path(vo_dir) / "frames.csv")
    rob = robustness(frames)
    out: dict = {
        "n_frames": len(frames),
        "success": rob.success,
        "time_before_failure_s": rob.time_before_failure_s,
        "duration_s": rob.duration_s,
        "tracked_fraction": rob.tracked_fraction,
        "n_failures": rob.n_failures,
        "n_segments": rob.n_segments,
        "coverage_mean": float(np.mean([f["coverage"] for f in frames])) if frames else float("nan"),
        "matches_mean": float(np.mean([f["n_map_matches"] for f in frames])) if frames else float("nan"),
        "keypoints_mean": float(np.mean([f["n_keypoints"] for f in frames])) if frames else float("nan"),
        "coverage": [f["coverage"] for f in frames],
        "matches": [f["n_map_matches"] for f in frames],
        "rte_pct": float("nan"),
        "rre_deg_per_m": float("nan"),
        "tracked_distance_fraction": float("nan"),
        "windows": [],
        "reference": "groundtruth",
    }
    unknown = frames_without_pose(groundtruth, [f["t_ns"] for f in frames]) if groundtruth is not None else 0
    if groundtruth is None:
        out["reference"] = "no reference: the trajectory has no groundtruth.txt (or reference file)"
    elif unknown:  # their nearest neighbours' poses would be taken for theirs: no RTE rather than a wrong one
        out["rte_refused"] = f"{unknown} frames have no known ground-truth pose ({UNKNOWN_POSES_FILE})"
        out["reference"] = f"no reference: {out['rte_refused']}"
    elif not Path(groundtruth).is_file():
        out["reference"] = f"no reference: {groundtruth} not found"
    else:
        gt_t, gt_p = read_tum(groundtruth)
        out["tracked_distance_fraction"] = tracked_distance_fraction(frames, gt_t, gt_p[:, :3, 3])
        errs = relative_errors(gt_t, gt_p, read_segments(vo_dir), windows_m)
        out["rte_pct"], out["rre_deg_per_m"] = trajectory_rte_rre(errs)
        out["windows"] = [e.__dict__ for e in errs]
    return out
