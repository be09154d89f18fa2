"""Metrics: evo wiring of RTE/RRE (paper equations), per-segment evaluation, robustness, manifests."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from bracketry_emulator.metrics import (
    DEFAULT_WINDOWS_M,
    expand_datasets,
    relative_errors,
    robustness,
    success_counts,
    trajectory_rte_rre,
)
from bracketry_emulator.trajectory_io import read_segments, read_tum, write_tum


def _line(n: int = 601, step_m: float = 0.1) -> tuple[np.ndarray, np.ndarray]:
    t = np.arange(n) * 0.1
    poses = np.tile(np.eye(4), (n, 1, 1))
    poses[:, 0, 3] = np.arange(n) * step_m
    return t, poses


def test_bench_scale_error_gives_one_percent_at_every_window() -> None:
    t, gt = _line(1001)  # 100 m straight line, a pose every 0.1 m
    est = gt.copy()
    est[:, :3, 3] *= 1.01
    errs = relative_errors(t, gt, [(t, est)], DEFAULT_WINDOWS_M)
    assert [e.window_m for e in errs] == list(range(5, 51))
    for e in errs:
        assert e.n_pairs > 0
        assert round(e.rte_pct, 1) == 1.0  # evo pairs within 10 % of w at the end of the path: 0.9955..1.0
        assert abs(e.rte_pct - 1.0) < 0.005
        assert e.rre_deg_per_m == pytest.approx(0.0, abs=1e-9)
    rte, rre = trajectory_rte_rre(errs)
    assert rte == pytest.approx(1.0, abs=0.01) and rre == pytest.approx(0.0, abs=1e-9)


def test_bench_rotation_error_per_metre() -> None:
    t, gt = _line(501)
    est = gt.copy()
    # a constant yaw drift of 0.1 deg per metre travelled (rotations about the travel axis keep positions)
    for i in range(len(est)):
        a = np.radians(0.1 * gt[i, 0, 3])
        est[i, :3, :3] = np.array([[1, 0, 0], [0, np.cos(a), -np.sin(a)], [0, np.sin(a), np.cos(a)]])
    errs = relative_errors(t, gt, [(t, est)], (5.0, 10.0))
    for e in errs:
        assert e.rre_deg_per_m == pytest.approx(0.1, rel=0.01)
        assert e.rte_pct == pytest.approx(0.0, abs=1e-6)


def test_bench_segments_never_span_a_loss() -> None:
    t, gt = _line(401)
    # two segments, each in its own arbitrary frame (re-initialised at identity); a jump between them
    seg_a = (t[:200], gt[:200].copy())
    seg_b_poses = gt[220:].copy()
    seg_b_poses[:, 0, 3] -= seg_b_poses[0, 0, 3]
    seg_b = (t[220:], seg_b_poses)
    errs = relative_errors(t, gt, [seg_a, seg_b], (5.0, 10.0))
    assert all(e.n_pairs > 0 and e.rte_pct == pytest.approx(0.0, abs=1e-6) for e in errs)
    # the same poses as ONE trajectory would carry the jump into the pairs that straddle the gap
    joined = (np.r_[seg_a[0], seg_b[0]], np.concatenate([seg_a[1], seg_b[1]]))
    assert relative_errors(t, gt, [joined], (5.0,))[0].rte_pct > 10.0


def test_bench_too_short_gives_nan() -> None:
    t, gt = _line(21)  # 2 m
    errs = relative_errors(t, gt, [(t, gt)], (5.0,))
    assert errs[0].n_pairs == 0 and np.isnan(errs[0].rte_pct)
    assert np.isnan(trajectory_rte_rre(errs)[0])


def test_bench_tum_roundtrip_and_segment_order(tmp_path: Path) -> None:
    t, gt = _line(12)
    for n in (10, 2, 0):
        write_tum(tmp_path / f"CameraTrajectory{n}.txt", t + n, gt)
    times, poses = read_tum(tmp_path / "CameraTrajectory2.txt")
    assert np.allclose(times, t + 2) and np.allclose(poses, gt)
    assert [s[0][0] for s in read_segments(tmp_path)] == pytest.approx([0.0, 2.0, 10.0])


def test_bench_robustness() -> None:
    frames = [{"t_ns": k * 250_000_000, "state": s, "segment": g}
              for k, (s, g) in enumerate([("INIT", 0), ("OK", 0), ("OK", 0), ("LOST", -1), ("INIT", 1), ("OK", 1)])]
    r = robustness(frames)
    assert not r.success and r.time_before_failure_s == pytest.approx(0.75)
    assert r.duration_s == pytest.approx(1.25) and r.n_segments == 2 and r.n_failures == 1
    ok = robustness([dict(f, state="OK", segment=0) for f in frames])
    assert ok.success and ok.time_before_failure_s == pytest.approx(1.25) and ok.tracked_fraction == 1.0


def test_bench_robustness_counts_steps_not_the_stamps_of_the_brackets_used() -> None:
    """Two methods that never fail have the same duration whichever bracket of a sequence (45.5 ms apart) each
    emulated its first and last images from; a failure at step k is at k sequence periods."""
    cycle_ns, bracket_ns = 273_000_000, 45_500_000
    brackets_a = [0, 0, 1, 1, 1, 1, 1, 0]
    brackets_b = [5, 4, 4, 4, 3, 3, 3, 5]
    frames_a = [{"t_ns": k * cycle_ns + j * bracket_ns, "state": "OK", "segment": 0} for k, j in enumerate(brackets_a)]
    frames_b = [{"t_ns": k * cycle_ns + j * bracket_ns, "state": "OK", "segment": 0} for k, j in enumerate(brackets_b)]
    a, b = robustness(frames_a), robustness(frames_b)
    assert a.success and b.success
    assert a.time_before_failure_s == b.time_before_failure_s == pytest.approx(7 * 0.273)
    frames_b[5]["state"] = "LOST"
    assert robustness(frames_b).time_before_failure_s == pytest.approx(5 * 0.273)


def test_bench_manifest_and_success_counts(tmp_path: Path) -> None:
    for name in ("f1", "f2", "c1"):
        (tmp_path / name).mkdir()
    (tmp_path / "m.yaml").write_text(
        "trajectories:\n  - {path: f1, subset: Forest}\n  - {path: f2, subset: Forest}\n"
        "  - {path: c1, subset: Campus1, name: campus}\n")
    specs = expand_datasets([tmp_path / "m.yaml", tmp_path / "f1"])
    assert [(s.name, s.subset) for s in specs] == [("f1", "Forest"), ("f2", "Forest"), ("campus", "Campus1"),
                                                   ("f1_2", "all")]
    rows = [{"subset": "Forest", "method": "ae50", "success": True}, {"subset": "Forest", "method": "ae50",
            "success": False}, {"subset": "Campus1", "method": "ae50", "success": False}]
    counts = success_counts(rows)
    assert counts["Forest"]["ae50"] == (1, 2) and counts["Campus1"]["ae50"] == (0, 1)
    assert counts["Total"]["ae50"] == (1, 3)


def test_bench_rotation_errors_equal_evo_rotation_angle() -> None:
    from evo.core import metrics as evo_metrics

    from bracketry_emulator.metrics.rpe import _pair_errors, _traj

    rng = np.random.default_rng(4)
    t, gt = _line(121)
    est = gt.copy()
    for i in range(len(est)):
        a = rng.normal(0, 0.02, 3)
        est[i, :3, :3] = cv2_rodrigues(a)
        est[i, :3, 3] += rng.normal(0, 0.05, 3)
    ref_t, est_t = _traj(t, gt), _traj(t, est)
    _e_t, e_r = _pair_errors(ref_t, est_t, 5.0, 0.1)
    rpe = evo_metrics.RPE(evo_metrics.PoseRelation.rotation_angle_deg, delta=5.0, delta_unit=evo_metrics.Unit.meters,
                          all_pairs=True, pairs_from_reference=True)
    rpe.process_data((ref_t, est_t))
    assert np.allclose(e_r, rpe.error, atol=1e-6)


def cv2_rodrigues(rvec: np.ndarray) -> np.ndarray:
    import cv2

    return cv2.Rodrigues(np.asarray(rvec, float))[0]


def test_bench_robustness_with_the_cycle_period_given_ignores_every_stamp_offset() -> None:
    """A method whose exposure grows at every step has mid-exposure stamps whose spacing is never the cycle (the
    median of its own spacing is off): with the dataset's cycle period given, its duration is the cycle's."""
    cycle_ns = 273_000_000
    growing = [{"t_ns": k * cycle_ns + k * k * 2_000_000, "state": "OK", "segment": 0} for k in range(11)]
    steady = [{"t_ns": k * cycle_ns, "state": "OK", "segment": 0} for k in range(11)]
    assert robustness(growing).duration_s != pytest.approx(10 * 0.273)  # the stamps alone mislead
    assert robustness(growing, 0.273).duration_s == robustness(steady, 0.273).duration_s == pytest.approx(2.73)
    growing[4]["state"] = "LOST"
    assert robustness(growing, 0.273).time_before_failure_s == pytest.approx(4 * 0.273)
