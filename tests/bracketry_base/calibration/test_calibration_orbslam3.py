"""A solved calibration carries a benchmark (#35): a board session rendered with the toy corridor's camera (an
ideal pinhole, 0.18 m baseline) is solved by ``bracketry calibrate solve``; the benchmark runs ORB-SLAM3 stereo on
the corridor walk with that calibration folder as the dataset's ``calibration`` and tracks it as well as with the
true one (the bound of ``test_bench_orbslam3_tracks_in_every_repeat``: RTE under 5 %)."""

from __future__ import annotations

from pathlib import Path

import pytest

from bracketry.cli import main as cli_main
from bracketry_base.calibration.board import BoardSpec
from bracketry_emulator.benchmark import BenchmarkConfig, run_benchmark
from bracketry_emulator.benchmark.slam import slam_options
from bracketry_emulator.benchmark.toyworld import ToyWorld
from bracketry_emulator.synth.board_session import write_board_session
from bracketry_emulator.synth.calibration import CameraIntrinsics, StereoCalibration
from bracketry_emulator.vo.calibration import StereoRectifier

pytestmark = [pytest.mark.orbslam3, pytest.mark.slow]

DENSE = ToyWorld(width_px=320, height_px=240, fx_px=240.0, fps=2 * 3.6667)


def test_benchmark_runs_orbslam3_on_a_solved_calibration(tmp_path: Path) -> None:
    # the toy's camera at twice its resolution (a board needs the pixels; the benchmark scales K and P to the images)
    cam = CameraIntrinsics(640, 480, 480.0, 480.0, 319.5, 239.5, (0.0, 0.0, 0.0, 0.0, 0.0))
    session = tmp_path / "board"
    session.mkdir()
    write_board_session(session, BoardSpec(), StereoCalibration(cam, cam, DENSE.baseline_m), 5, 30)
    cal = tmp_path / "cal"
    assert cli_main(["calibrate", "solve", str(session), "--out", str(cal), "-q"]) == 0
    assert StereoRectifier.from_dir(cal, 320, 240).baseline_m == pytest.approx(DENSE.baseline_m, rel=0.01)

    ds = tmp_path / "ds"
    ds.mkdir()
    DENSE.write_groundtruth(ds / "groundtruth.txt", DENSE.write_run(ds, "ae50", 48))
    (ds / "calibration").symlink_to(cal)
    train = tmp_path / "train"
    ToyWorld(width_px=320, height_px=240, fx_px=240.0, seed=99).write_run(train, "x", 6, t0_ns=90 * 10**9)
    voc = tmp_path / "voc.txt"
    images = sorted(str(p) for p in (train / "x" / "images_left").glob("*.png"))
    assert cli_main(["slam", "vocabulary", *images, "--out", str(voc), "--k", "8", "--levels", "4",
                     "--seed", "3"]) == 0
    seen: list[dict] = []
    run_benchmark(BenchmarkConfig([ds], ["ae50"], tmp_path / "out", reference="ae50", windows_m=(1.0, 2.0, 4.0),
                                  workers=1, slam=slam_options("orbslam3", voc, pace=0.0, repeats=1)),
                  on_done=lambda r: seen.append(r.to_json()))
    (r,) = seen
    assert not r.get("error") and r["slam"] == "orbslam3", r.get("error")
    assert r["tracked_fraction"] >= 0.9 and 0 < r["rte_pct"] < 5.0, (r["tracked_fraction"], r["rte_pct"])
