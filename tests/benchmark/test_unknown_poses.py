"""RTE/RRE are refused (NaN with a reason) when frames of a run have no known ground-truth pose."""

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


def test_rte_with_every_pose_known_and_refused_with_one_unknown(tmp_path: Path) -> None:
    vo, gt, times = _run(tmp_path)
    m = evaluate_run(vo, gt, (1.0,))
    assert math.isfinite(m["rte_pct"]) and m["rte_pct"] < 1e-6 and "rte_refused" not in m
    (tmp_path / UNKNOWN_POSES_FILE).write_text(f"{times[7]}\n")
    assert frames_without_pose(gt, times) == 1 and frames_without_pose(gt, []) == 1
    assert frames_without_pose(gt, times[:5]) == 0
    m = evaluate_run(vo, gt, (1.0,))
    assert math.isnan(m["rte_pct"]) and math.isnan(m["rre_deg_per_m"]) and "1 frames" in m["rte_refused"]
