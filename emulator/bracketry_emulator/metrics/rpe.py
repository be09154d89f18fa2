"""Relative trajectory errors (RTE %, RRE deg/m) through evo's RPE, with the paper's equations.

For each window ``w`` (metres; default every integer 5..50 as the paper) and each tracked segment (never across a
loss): evo ``RPE(delta=w, delta_unit=meters, all_pairs=True, pairs_from_reference=True)`` on the segment associated
in time with the reference. Pairs come from the reference path, so a scale error of the estimate does not move them.
Per-pair errors ``E_T`` (m, ``translation_part``) and ``E_R`` (deg, ``rotation_angle_deg``) of all segments are
pooled, then (paper eq. rte/rre):

    RTE(t, w) = sqrt(mean_S (100 * E_T / w)^2)   [%]
    RRE(t, w) = sqrt(mean_S (E_R / w)^2)         [deg/m]

and a trajectory's RTE/RRE is the mean over the windows that hold at least one pair (the paper's average over W,
restricted to windows the trajectory is long enough for).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

DEFAULT_WINDOWS_M: tuple[float, ...] = tuple(float(w) for w in range(5, 51))


@dataclass
class WindowError:
    """Errors at one window: ``n_pairs`` pooled over segments, ``rte_pct`` and ``rre_deg_per_m`` (NaN if no pair)."""

    window_m: float
    n_pairs: int
    rte_pct: float
    rre_deg_per_m: float


def _traj(times_s: np.ndarray, poses_wc: np.ndarray):
    from evo.core.trajectory import PoseTrajectory3D

    return PoseTrajectory3D(poses_se3=[np.asarray(p, float) for p in poses_wc], timestamps=np.asarray(times_s, float))


def _pair_errors(ref, est, window_m: float, rel_delta_tol: float) -> tuple[np.ndarray, np.ndarray]:
    """Per-pair (translation error m, rotation error deg) of one evo RPE pass.

    evo's RPE with ``translation_part`` keeps the per-pair error transforms ``E``; the rotation error is the angle of
    their rotation part (what ``rotation_angle_deg`` computes), so one pass (one pair search) gives both.
    """
    from evo.core import filters, metrics

    rpe = metrics.RPE(metrics.PoseRelation.translation_part, delta=window_m, delta_unit=metrics.Unit.meters,
                      rel_delta_tol=rel_delta_tol, all_pairs=True, pairs_from_reference=True)
    try:
        rpe.process_data((ref, est))
    except (filters.FilterException, metrics.MetricsException):
        return np.zeros(0), np.zeros(0)
    E = np.asarray(rpe.E, float).reshape(-1, 4, 4)
    cos = np.clip((np.trace(E[:, :3, :3], axis1=1, axis2=2) - 1.0) / 2.0, -1.0, 1.0)
    return np.asarray(rpe.error, float), np.degrees(np.arccos(cos))


def relative_errors(gt_times_s: np.ndarray, gt_poses_wc: np.ndarray,
                    segments: list[tuple[np.ndarray, np.ndarray]], windows_m: tuple[float, ...] = DEFAULT_WINDOWS_M,
                    max_diff_s: float | None = None, rel_delta_tol: float = 0.1) -> list[WindowError]:
    """RTE/RRE per window for the estimated ``segments`` (each ``(times_s N, poses_wc Nx4x4)``) vs the reference.

    ``max_diff_s`` is the time association tolerance (default: half the median frame interval of the estimate).
    """
    from evo.core import sync

    ref_all = _traj(gt_times_s, gt_poses_wc)
    pooled_t: dict[float, list[np.ndarray]] = {w: [] for w in windows_m}
    pooled_r: dict[float, list[np.ndarray]] = {w: [] for w in windows_m}
    for times_s, poses in segments:
        if len(times_s) < 2:
            continue
        tol = max_diff_s if max_diff_s is not None else 0.5 * float(np.median(np.diff(times_s)))
        try:
            ref, est = sync.associate_trajectories(ref_all, _traj(times_s, poses), max_diff=tol)
        except sync.SyncException:
            continue
        if ref.num_poses < 2:
            continue
        for w in windows_m:
            e_t, e_r = _pair_errors(ref, est, w, rel_delta_tol)
            pooled_t[w].append(e_t)
            pooled_r[w].append(e_r)
    out = []
    for w in windows_m:
        e_t = np.concatenate(pooled_t[w]) if pooled_t[w] else np.zeros(0)
        e_r = np.concatenate(pooled_r[w]) if pooled_r[w] else np.zeros(0)
        if len(e_t) == 0:
            out.append(WindowError(w, 0, float("nan"), float("nan")))
        else:
            out.append(WindowError(w, len(e_t), float(np.sqrt(np.mean((100.0 * e_t / w) ** 2))),
                                   float(np.sqrt(np.mean((e_r / w) ** 2)))))
    return out


def trajectory_rte_rre(errors: list[WindowError]) -> tuple[float, float]:
    """(RTE %, RRE deg/m) of one trajectory: means over the windows with pairs (NaN when none has)."""
    have = [e for e in errors if e.n_pairs > 0]
    if not have:
        return float("nan"), float("nan")
    return float(np.mean([e.rte_pct for e in have])), float(np.mean([e.rre_deg_per_m for e in have]))
