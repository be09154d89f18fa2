"""Reference trajectories in another sensor frame (EuRoC, KITTI) with an extrinsic: same RTE as the left camera's."""

from __future__ import annotations

import shutil
from pathlib import Path

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from bracketry_base.errors import BracketryError
from bracketry_emulator.benchmark import BenchmarkConfig, SlamOptions, run_benchmark
from bracketry_emulator.benchmark.toyworld import ToyWorld
from bracketry_emulator.metrics import evaluate_run
from bracketry_emulator.metrics.reference import extrinsic_matrix, write_camera_reference
from bracketry_emulator.vo import read_tum, run_vo

WORLD = ToyWorld(width_px=256, height_px=192, fx_px=200.0)
N = 10
T_SC = np.eye(4)  # the left camera in the sensor (e.g. an INS) frame
T_SC[:3, :3] = Rotation.from_euler("zyx", [30.0, -10.0, 90.0], degrees=True).as_matrix()
T_SC[:3, 3] = [0.12, -0.35, 0.8]


@pytest.fixture(scope="module")
def toy(tmp_path_factory) -> tuple[Path, list[int]]:
    d = tmp_path_factory.mktemp("reference") / "traj"
    WORLD.write_calibration(d)
    times = WORLD.write_run(d, "ae50", N)
    run_vo(d / "ae50", d / "calibration", d.parent / "vo")
    WORLD.write_groundtruth(d.parent / "camera_gt.txt", times)
    return d, times


def _sensor_poses(times_ns: list[int]) -> tuple[np.ndarray, np.ndarray]:
    """The sensor's poses at 50 Hz over a span wider than the images (another rate, another frame)."""
    t = np.arange(times_ns[0] * 1e-9 - 0.3, times_ns[-1] * 1e-9 + 0.3, 0.02)
    inv = np.linalg.inv(T_SC)
    return t, np.stack([WORLD.pose_wc(x) @ inv for x in t])


def test_bench_reference_euroc_and_kitti_give_the_camera_rte(toy, tmp_path: Path) -> None:
    d, times = toy
    t, T_ws = _sensor_poses(times)
    q = Rotation.from_matrix(T_ws[:, :3, :3]).as_quat()  # x y z w
    rows = [f"{round(x * 1e9)},{p[0]},{p[1]},{p[2]},{qq[3]},{qq[0]},{qq[1]},{qq[2]}"
            for x, p, qq in zip(t, T_ws[:, :3, 3], q)]
    (d / "ins.csv").write_text("#timestamp [ns],p_x,p_y,p_z,q_w,q_x,q_y,q_z\n" + "\n".join(rows) + "\n")
    qe = Rotation.from_matrix(T_SC[:3, :3]).as_quat()
    (d / "reference.yaml").write_text(f"file: ins.csv\nformat: euroc\nextrinsic:\n  translation: {T_SC[:3, 3].tolist()}"
                                      f"\n  quaternion: {qe.tolist()}\n")
    cam = write_camera_reference(d, tmp_path / "euroc_cam.txt")
    ct, cposes = read_tum(cam)
    gt_t, gt_poses = read_tum(d.parent / "camera_gt.txt")
    assert np.allclose(ct, gt_t, atol=1e-6)
    assert np.abs(cposes[:, :3, 3] - gt_poses[:, :3, 3]).max() < 1e-3
    assert np.abs(cposes[:, :3, :3] - gt_poses[:, :3, :3]).max() < 1e-4
    m_gt = evaluate_run(d.parent / "vo", d.parent / "camera_gt.txt", (1.0,))
    m_ref = evaluate_run(d.parent / "vo", cam, (1.0,))
    assert np.isfinite(m_gt["rte_pct"]) and m_ref["rte_pct"] == pytest.approx(m_gt["rte_pct"], rel=1e-3)
    assert m_ref["rre_deg_per_m"] == pytest.approx(m_gt["rre_deg_per_m"], rel=1e-2, abs=1e-4)

    # KITTI: 3x4 rows with a times file, the extrinsic as a 4x4 matrix
    (d / "ins.kitti").write_text("".join(" ".join(f"{v:.12g}" for v in T[:3, :].ravel()) + "\n" for T in T_ws))
    (d / "ins_times.txt").write_text("".join(f"{x:.9f}\n" for x in t))
    (d / "reference.yaml").write_text(f"file: ins.kitti\ntimes: ins_times.txt\nextrinsic:\n  matrix: {T_SC.tolist()}\n")
    m_kitti = evaluate_run(d.parent / "vo", write_camera_reference(d, tmp_path / "kitti_cam.txt"), (1.0,))
    assert m_kitti["rte_pct"] == pytest.approx(m_gt["rte_pct"], rel=1e-3)

    # the benchmark uses a folder's reference.yaml (here there is no groundtruth.txt at all)
    res = run_benchmark(BenchmarkConfig([d], ["ae50"], tmp_path / "bench", windows_m=(1.0,),
                                        slam=SlamOptions.builtin()))
    assert res.results[0]["rte_pct"] == pytest.approx(m_gt["rte_pct"], rel=1e-3)
    assert res.results[0]["reference"] == "groundtruth"


def test_bench_no_reference_is_explicit(toy, tmp_path: Path) -> None:
    d, _ = toy
    bare = tmp_path / "bare"
    shutil.copytree(d / "calibration", bare / "calibration")
    shutil.copytree(d / "ae50", bare / "ae50")
    res = run_benchmark(BenchmarkConfig([bare], ["ae50"], tmp_path / "bench", windows_m=(1.0,)))
    r = res.results[0]
    assert np.isnan(r["rte_pct"]) and r["reference"].startswith("no reference")
    assert "RTE/RRE: no reference" in (res.out_dir / "report" / "report.md").read_text()


def test_bench_bad_extrinsic_is_one_line() -> None:
    with pytest.raises(BracketryError, match="not a rigid transform"):
        extrinsic_matrix({"matrix": [[2, 0, 0, 0], [0, 1, 0, 0], [0, 0, 1, 0], [0, 0, 0, 1]]})
    assert np.allclose(extrinsic_matrix({"translation": [1, 2, 3]})[:3, 3], [1, 2, 3])


def test_bench_reference_kitti_without_times_takes_the_left_images(toy, tmp_path: Path) -> None:
    """KITTI poses with no times file: line k is the pose at the k-th left image; a count that differs is one line."""
    from bracketry_emulator.metrics.reference import image_times_ns

    d, _ = toy
    t = np.array(image_times_ns(d), np.float64) * 1e-9
    T_ws = np.stack([WORLD.pose_wc(x) @ np.linalg.inv(T_SC) for x in t])
    (d / "poses.txt").write_text("".join(" ".join(f"{v:.12g}" for v in T[:3, :].ravel()) + "\n" for T in T_ws))
    (d / "reference.yaml").write_text(f"file: poses.txt\nformat: kitti\nextrinsic:\n  matrix: {T_SC.tolist()}\n")
    try:
        cam = write_camera_reference(d, tmp_path / "kitti_frames.txt")
        ct, cposes = read_tum(cam)
        gt_t, gt_poses = read_tum(d.parent / "camera_gt.txt")
        assert np.allclose(ct, gt_t, atol=1e-6) and np.abs(cposes[:, :3, 3] - gt_poses[:, :3, 3]).max() < 1e-6
        (d / "poses.txt").write_text("".join(" ".join(f"{v:.12g}" for v in T[:3, :].ravel()) + "\n"
                                             for T in T_ws[:-1]))
        with pytest.raises(BracketryError, match=rf"{len(t) - 1} KITTI poses for {len(t)} left images"):
            write_camera_reference(d, tmp_path / "short.txt")
    finally:
        (d / "reference.yaml").unlink()
