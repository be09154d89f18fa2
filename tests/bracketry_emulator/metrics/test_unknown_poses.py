"""Frames without a known ground-truth pose are left out of RTE/RRE; too many of them and RTE/RRE are refused."""

from __future__ import annotations

import math
from pathlib import Path

from bracketry_emulator.metrics.evaluate import UNKNOWN_POSES_FILE, evaluate_run, frames_without_pose


def _run(tmp_path: Path, n: int = 40) -> tuple[Path, Path, list[int]]:
    times = [1_000_000_000 + k * 100_000_000 for k in range(n)]
    vo = tmp_path / "vo"
    vo.mkdir()
    rows = ["t_ns,state,segment,n_keypoints,coverage,n_stereo,n_ref_matches,n_map_matches,reason"]
    rows += [f"{t},OK,0,500,0.8,300,200,200," for t in times]
    (vo / "frames.csv").write_text("\n".join(rows) + "\n")
    traj = [f"{t / 1e9:.9f} {0.1 * k:.6f} 0 0 0 0 0 1" for k, t in enumerate(times)]
    (vo / "CameraTrajectory0.txt").write_text("\n".join(traj) + "\n")
    gt = tmp_path / "groundtruth.txt"
    gt.write_text("\n".join(f"{t / 1e9:.9f} {0.1 * k:.6f} 0 0 0 0 0 1" for k, t in enumerate(times)) + "\n")
    return vo, gt, times


def test_rte_leaves_out_a_frame_without_pose_and_refuses_with_too_many(tmp_path: Path) -> None:
    vo, gt, times = _run(tmp_path)
    m = evaluate_run(vo, gt, (1.0,))
    assert math.isfinite(m["rte_pct"]) and m["rte_pct"] < 1e-6 and "rte_refused" not in m
    assert m["frames_without_pose"] == 0
    # frame 7 shows another world time than its stamp says: no ground-truth line, listed as unknown, and the
    # estimate there is far off; taking a neighbour's pose for it would give a large RTE
    traj = (vo / "CameraTrajectory0.txt").read_text().splitlines()
    traj[7] = f"{times[7] / 1e9:.9f} 50.0 0 0 0 0 0 1"
    (vo / "CameraTrajectory0.txt").write_text("\n".join(traj) + "\n")
    # the reference is denser than the estimate (every camera frame vs one per bracket cycle), frame 7's own line gone
    dense = [(t + q * 25_000_000, 0.1 * k + 0.025 * q) for k, t in enumerate(times) for q in range(4)]
    gt.write_text("\n".join(f"{t / 1e9:.9f} {x:.6f} 0 0 0 0 0 1" for t, x in dense if t != times[7]) + "\n")
    m = evaluate_run(vo, gt, (1.0,))
    assert m["rte_pct"] > 100, "without the unknown list the wrong pose is evaluated"
    (tmp_path / UNKNOWN_POSES_FILE).write_text(f"{times[7]}\n")
    assert frames_without_pose(gt, times) == 1 and frames_without_pose(gt, []) == 1
    assert frames_without_pose(gt, times[:5]) == 0
    m = evaluate_run(vo, gt, (1.0,))
    assert m["frames_without_pose"] == 1 and "rte_refused" not in m
    assert math.isfinite(m["rte_pct"]) and m["rte_pct"] < 1e-6
    # more than 5 % of the frames without a pose: refused
    (tmp_path / UNKNOWN_POSES_FILE).write_text("".join(f"{t}\n" for t in times[7:10]))
    m = evaluate_run(vo, gt, (1.0,))
    assert math.isnan(m["rte_pct"]) and math.isnan(m["rre_deg_per_m"]) and "3 of 40 frames" in m["rte_refused"]
