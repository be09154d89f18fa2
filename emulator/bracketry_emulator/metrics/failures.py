"""Robustness metrics from a VO per-frame log: time before first failure, success, tracked fraction.

A frame fails when it is not tracked: LOST (tracking failed) or NO_INIT (the VO could not (re)initialise on it).
Time before failure = the time of the first failed frame since the first frame, in seconds; a run with no failed frame
is successful and its time before failure is its whole duration. This is the paper's "duration of each trajectory
before failure"; a successful trajectory "maintains localization without becoming lost for the whole trajectory".

Times are counted in steps of the closed loop (one per bracket sequence): step k is at k x the step period, the
dataset's bracket-cycle period given by the caller (the same for every method on a trajectory; without it, the
run's median stamp spacing, rounded to 0.1 ms). A frame's own stamp is the instant of the bracket its image was
emulated from (brackets of one sequence are ~45 ms apart, and a synthetic frame is stamped at mid-exposure), so two
methods that both never fail would otherwise get durations that differ by which bracket each used, and a paired
test would call that a difference in robustness.
"""

from __future__ import annotations

import itertools
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


def step_period_s(times_ns: list[int]) -> float:
    """The median spacing of consecutive frame stamps ``times_ns`` (ns), in seconds rounded to 0.1 ms; 0 for fewer
    than two frames."""
    if len(times_ns) < 2:
        return 0.0
    gaps = sorted(b - a for a, b in itertools.pairwise(times_ns))
    mid = len(gaps) // 2
    median_ns = gaps[mid] if len(gaps) % 2 else (gaps[mid - 1] + gaps[mid]) / 2
    return round(median_ns * 1e-5) * 1e-4


def robustness(frames: list[dict], step_s: float | None = None) -> Robustness:
    """Robustness of one run from ``frames.csv`` rows (dicts with ``t_ns``, ``state``, ``segment``), one per
    closed-loop step; ``step_s``: the step period (s; None: :func:`step_period_s` of the frames' stamps)."""
    if not frames:
        return Robustness(False, 0.0, 0.0, 0.0, 0, 0)
    if step_s is None:
        step_s = step_period_s([f["t_ns"] for f in frames])
    duration = (len(frames) - 1) * step_s
    first_failed = next((k for k, f in enumerate(frames) if f["state"] not in TRACKED), None)
    failed = [f for f in frames if f["state"] not in TRACKED]
    tbf = duration if first_failed is None else first_failed * step_s
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
