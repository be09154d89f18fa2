"""All metrics of one (trajectory, method) run: features, robustness, RTE/RRE per window."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from bracketry_emulator.metrics.failures import robustness, tracked_distance_fraction
from bracketry_emulator.metrics.rpe import DEFAULT_WINDOWS_M, relative_errors, trajectory_rte_rre
from bracketry_emulator.trajectory_io import read_frames_csv, read_segments, read_tum

#: next to a ground truth file: time stamps (ns, one per line) of frames whose pose is not known
UNKNOWN_POSES_FILE = "groundtruth_unknown.txt"


#: a run with more of its frames than this without a known pose gets no RTE/RRE (its path is too broken up)
MAX_UNKNOWN_POSE_FRACTION = 0.05


def unknown_pose_times_ns(groundtruth: str | Path) -> set[int]:
    """Time stamps (ns) listed in the :data:`UNKNOWN_POSES_FILE` next to ``groundtruth`` (empty when there is none)."""
    path = Path(groundtruth).parent / UNKNOWN_POSES_FILE
    if not path.is_file():
        return set()
    return {int(line) for line in path.read_text().split() if line.strip().isdigit()}


def frames_without_pose(groundtruth: str | Path, frame_times_ns: list[int]) -> int:
    """How many of ``frame_times_ns`` (or of all listed frames when the list is empty) are listed in the
    :data:`UNKNOWN_POSES_FILE` next to ``groundtruth`` (0 when there is none)."""
    listed = unknown_pose_times_ns(groundtruth)
    return len(listed & set(frame_times_ns)) if frame_times_ns else len(listed)


def without_times(segments: list[tuple[np.ndarray, np.ndarray]], times_ns: set[int]
                  ) -> list[tuple[np.ndarray, np.ndarray]]:
    """``segments`` (each ``(times_s N, poses Nx4x4)``) without the poses stamped at ``times_ns`` (to 1 us)."""
    if not times_ns:
        return segments
    drop_us = {round(t / 1000) for t in times_ns}
    out = []
    for times_s, poses in segments:
        keep = np.array([round(float(t) * 1e6) not in drop_us for t in times_s], dtype=bool)
        if keep.sum() >= 2:
            out.append((times_s[keep], poses[keep]))
    return out


def evaluate_run(vo_dir: str | Path, groundtruth: str | Path | None,
                 windows_m: tuple[float, ...] = DEFAULT_WINDOWS_M, step_s: float | None = None) -> dict:
    """Metrics of a VO output folder (``frames.csv`` + ``CameraTrajectory<n>.txt``) against a TUM reference.

    Returns a JSON-ready dict: n_frames, success, time_before_failure_s, duration_s, tracked_fraction,
    n_segments, coverage_mean (fraction, all frames), matches_mean (matches to map, all frames),
    keypoints_mean, rte_pct, rre_deg_per_m, tracked_distance_fraction (NaN without reference), ``reference``
    ("groundtruth" or "no reference: <why>"), windows: list of {window_m, n_pairs, rte_pct, rre_deg_per_m}, and
    per-frame lists coverage, matches. Frames of the run listed in :data:`UNKNOWN_POSES_FILE` next to the reference
    (``frames_without_pose``) are left out of RTE/RRE; when they are more than :data:`MAX_UNKNOWN_POSE_FRACTION` of
    the frames, RTE/RRE stay NaN and ``rte_refused`` (and ``reference``) say why. ``step_s``: the closed loop's
    step period (s), the dataset's bracket-cycle period (:func:`~bracketry_emulator.metrics.failures.robustness`).
    """
    frames = read_frames_csv(Path(vo_dir) / "frames.csv")
    rob = robustness(frames, step_s)
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
    unknown_ns = unknown_pose_times_ns(groundtruth) & {f["t_ns"] for f in frames} if groundtruth is not None \
        else set()
    out["frames_without_pose"] = len(unknown_ns)
    if groundtruth is None:
        out["reference"] = "no reference: the trajectory has no groundtruth.txt (or reference file)"
    elif len(unknown_ns) > MAX_UNKNOWN_POSE_FRACTION * max(len(frames), 1):
        out["rte_refused"] = (f"{len(unknown_ns)} of {len(frames)} frames have no known ground-truth pose "
                              f"({UNKNOWN_POSES_FILE}; at most {MAX_UNKNOWN_POSE_FRACTION:.0%} are left out)")
        out["reference"] = f"no reference: {out['rte_refused']}"
    elif not Path(groundtruth).is_file():
        out["reference"] = f"no reference: {groundtruth} not found"
    else:
        gt_t, gt_p = read_tum(groundtruth)
        out["tracked_distance_fraction"] = tracked_distance_fraction(frames, gt_t, gt_p[:, :3, 3])
        # frames without a known pose are left out of the estimate: their neighbours' poses would be taken for theirs
        errs = relative_errors(gt_t, gt_p, without_times(read_segments(vo_dir), unknown_ns), windows_m)
        out["rte_pct"], out["rre_deg_per_m"] = trajectory_rte_rre(errs)
        out["windows"] = [e.__dict__ for e in errs]
    return out
