"""Robustness metrics from a VO per-frame log: time before first failure, success, tracked fraction.

A frame fails when it is not tracked: LOST (tracking failed) or NO_INIT (the VO could not (re)initialise on it).
Time before failure = t(first failed frame) - t(first frame) in seconds; a run with no failed frame is successful and
its time before failure is its whole duration (t(last) - t(first)). This is the paper's "duration of each trajectory
before failure"; a successful trajectory "maintains localization without becoming lost for the whole trajectory".
"""

from __future__ import annotations

from dataclasses import dataclass

TRACKED = ("OK", "INIT")


@dataclass
class Robustness:
    """``success``: never failed; ``time_before_failure_s``; ``duration_s``; ``tracked_fraction`` in [0, 1];
    ``n_failures``: failed frames; ``n_segments``: tracked segments (1 + re-initialisations)."""

    success: bool
    time_before_failure_s: float
    duration_s: float
    tracked_fraction: float
    n_failures: int
    n_segments: int


def robustness(frames: list[dict]) -> Robustness:
    """Robustness of one run from ``frames.csv`` rows (dicts with ``t_ns``, ``state``, ``segment``)."""
    if not frames:
        return Robustness(False, 0.0, 0.0, 0.0, 0, 0)
    t0 = frames[0]["t_ns"]
    duration = (frames[-1]["t_ns"] - t0) * 1e-9
    failed = [f for f in frames if f["state"] not in TRACKED]
    tbf = (failed[0]["t_ns"] - t0) * 1e-9 if failed else duration
    segments = {f["segment"] for f in frames if f["state"] in TRACKED}
    return Robustness(not failed, tbf, duration, 1.0 - len(failed) / len(frames), len(failed), len(segments))


def tracked_distance_fraction(frames: list[dict], gt_times_s, gt_positions) -> float:
    """Fraction in [0, 1] of the reference path length travelled between consecutive frames tracked in one segment.

    RTE over tracked fragments alone favours a method that loses track on the hard stretches; this says how much of
    the way those fragments cover. ``gt_times_s`` float (M,), ``gt_positions`` float (M, 3) metres, interpolated
    linearly at the frame times (clamped at the ends). NaN when the path has no length.
    """
    import numpy as np

    if len(frames) < 2 or len(gt_times_s) < 2:
        return float("nan")
    t = np.array([f["t_ns"] for f in frames], np.float64) * 1e-9
    gt_t = np.asarray(gt_times_s, np.float64)
    gt_p = np.asarray(gt_positions, np.float64)
    p = np.stack([np.interp(t, gt_t, gt_p[:, i]) for i in range(3)], axis=1)
    step = np.linalg.norm(np.diff(p, axis=0), axis=1)
    tracked = np.array([f["state"] in TRACKED for f in frames])
    seg = np.array([f["segment"] for f in frames])
    both = tracked[1:] & tracked[:-1] & (seg[1:] == seg[:-1])
    total = float(step.sum())
    return float(step[both].sum() / total) if total > 0 else float("nan")
