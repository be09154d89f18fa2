"""External SLAM path: ORB-SLAM stereo-example export, and import of CameraTrajectory<n>.txt segments."""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np
import pytest

from bracketry_emulator.benchmark.toyworld import ToyWorld
from bracketry_emulator.metrics import evaluate_run
from bracketry_emulator.vo import read_frames_csv, read_tum, run_vo
from bracketry_emulator.vo.orbslam import export_orbslam, import_orbslam


@pytest.fixture(scope="module")
def toy(tmp_path_factory) -> Path:
    d = tmp_path_factory.mktemp("orbslam_toy")
    w = ToyWorld(width_px=256, height_px=192, fx_px=200.0)
    w.write_calibration(d)
    times = w.write_run(d, "ae50", 8)
    w.write_groundtruth(d / "groundtruth.txt", times)
    return d


def test_bench_export_orbslam_layout(toy: Path, tmp_path: Path) -> None:
    out = export_orbslam(toy / "ae50", toy / "calibration", tmp_path / "orb")
    times = (out / "times.txt").read_text().split()
    assert len(times) == 8
    for cam in ("cam0", "cam1"):
        names = sorted(p.stem for p in (out / "mav0" / cam / "data").glob("*.png"))
        assert names == sorted(times)
        img = cv2.imread(str(out / "mav0" / cam / "data" / f"{times[0]}.png"), cv2.IMREAD_UNCHANGED)
        assert img.dtype == np.uint8 and img.shape == (192, 256)
    fs = cv2.FileStorage(str(out / "settings.yaml"), cv2.FILE_STORAGE_READ)  # what ORB-SLAM parses it with
    assert fs.getNode("ORBextractor.nFeatures").real() == 3000
    assert fs.getNode("ORBextractor.nLevels").real() == 13
    assert fs.getNode("ORBextractor.iniThFAST").real() == 15 and fs.getNode("ORBextractor.minThFAST").real() == 5
    assert fs.getNode("Camera.bf").real() == pytest.approx(200.0 * 0.18, rel=1e-6)
    assert fs.getNode("Camera.fps").real() == pytest.approx(ToyWorld().fps, rel=1e-3)
    assert np.allclose(fs.getNode("RIGHT.P").mat()[0, 3], -36.0)
    fs.release()
    assert "stereo_euroc" in (out / "run_orbslam.sh").read_text()


def test_bench_import_orbslam_segments(toy: Path, tmp_path: Path) -> None:
    # stand-in for ORB-SLAM's output: our own VO trajectory split in two maps with a lost frame in between
    run_vo(toy / "ae50", toy / "calibration", tmp_path / "ours")
    t, poses = read_tum(tmp_path / "ours" / "CameraTrajectory0.txt")
    slam = tmp_path / "slam"
    slam.mkdir()
    from bracketry_emulator.vo import write_tum

    write_tum(slam / "CameraTrajectory0.txt", t[:4], poses[:4])
    write_tum(slam / "CameraTrajectory1.txt", t[5:], poses[5:])
    times = tmp_path / "times.txt"
    times.write_text("".join(f"{round(x * 1e9)}\n" for x in t))
    vo_dir = import_orbslam(slam, times, tmp_path / "imported")
    states = [r["state"] for r in read_frames_csv(vo_dir / "frames.csv")]
    assert states == ["INIT", "OK", "OK", "OK", "LOST", "INIT", "OK", "OK"]
    m = evaluate_run(vo_dir, toy / "groundtruth.txt", (1.0,))
    assert not m["success"] and m["n_segments"] == 2
    assert m["time_before_failure_s"] == pytest.approx(4 / ToyWorld().fps, abs=1e-3)
    assert m["windows"][0]["n_pairs"] > 0 and np.isfinite(m["rte_pct"])
    assert np.isnan(m["matches_mean"])  # ORB-SLAM's trajectories carry no per-frame feature counts


def test_bench_cli_export_and_external_trajectories(toy: Path, tmp_path: Path) -> None:
    import json
    import shutil

    from bracketry.cli import main as cli_main

    name = toy.name
    assert cli_main(["benchmark", str(toy), "--methods", "ae50", "--out", str(tmp_path / "a"), "--windows", "1",
                     "--export-orbslam"]) == 0
    assert (tmp_path / "a" / "orbslam" / name / "ae50" / "settings.yaml").is_file()
    # stand-in for ORB-SLAM run on that export: our own trajectory file
    slam = tmp_path / "slam" / name / "ae50"
    slam.mkdir(parents=True)
    shutil.copy(tmp_path / "a" / "vo" / name / "ae50" / "CameraTrajectory0.txt", slam)
    assert cli_main(["benchmark", str(toy), "--methods", "ae50", "--out", str(tmp_path / "b"), "--windows", "1",
                     "--slam-trajectories", str(tmp_path / "slam")]) == 0
    a = json.loads((tmp_path / "a" / "report" / "results.json").read_text())[0]
    b = json.loads((tmp_path / "b" / "report" / "results.json").read_text())[0]
    assert b["success"] and b["rte_pct"] == pytest.approx(a["rte_pct"], rel=1e-6)
    assert cli_main(["benchmark", str(toy), "--methods", "ae50", "--out", str(tmp_path / "c"),
                     "--slam-trajectories", str(tmp_path / "nowhere")]) == 2
