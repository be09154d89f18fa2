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
